"""A BlueROV2-like ROV as a new user writes it first: examples/bluerov2's 6-DOF vehicle (12 states, 8 thrusters)
without an operating envelope and with one RK4 step per call (the example takes two). Its quadratic sway damping
makes RK4 unstable beyond dt ~ 0.14 s at 1 m/s: the audit's case, where verify once called one step at dt = 0.47 s
(|f| = 11.8) "diverged" and failed the model's correct code."""
import dataclasses
import importlib.util
from pathlib import Path

_EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "bluerov2" / "bluerov2.py"


def bluerov2_bare():
    spec = importlib.util.spec_from_file_location("abyssal_example_bluerov2", _EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    return dataclasses.replace(example.bluerov2(), name="bluerov2_bare", envelope=None, substeps=1)
