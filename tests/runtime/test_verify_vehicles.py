"""`abyssal verify` judges the code, and says what it found about the model apart: the audit's two users' vehicles
without an envelope (tests/vehicles: a BlueROV2-like ROV with one RK4 step per call, an Otter-like USV with a
0.1 s propeller lag) pass, sampled where RK4 is unstable too; a wrong generated function still fails."""
from __future__ import annotations

import importlib
import re
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from abyssal.verify import driver as verify
from abyssal.verify import models as verify_models
from abyssal.verify.report import Report

VEHICLES = Path(__file__).resolve().parents[1] / "vehicles"


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """gen/bluerov2_bare and gen/otter, written by the CLI."""
    from abyssal.runtime import cli

    out = tmp_path_factory.mktemp("vehicles") / "gen"
    for spec in ("bluerov2_bare.py:bluerov2_bare", "otter.py:otter"):
        assert cli.main(["regenerate", "--model", str(VEHICLES / spec), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def rov(generated):
    return verify.folder_target(generated / "bluerov2_bare")


@pytest.fixture(scope="module")
def otter(generated):
    return verify.folder_target(generated / "otter")


class WithEnvelope:
    """The same compiled bundle with another manifest envelope (what verify samples from)."""

    def __init__(self, bundle, envelope):
        self._bundle, self.envelope = bundle, envelope

    def __getattr__(self, name):
        return getattr(self._bundle, name)


class Perturbed:
    """A bundle whose chosen methods are off by a relative eps: stands in for a wrongly generated function."""

    def __init__(self, bundle, eps, methods):
        self._bundle, self._eps, self._methods = bundle, eps, methods

    def __getattr__(self, name):
        attr = getattr(self._bundle, name)
        if name in self._methods:
            return lambda *args, **kwargs: attr(*args, **kwargs) * (1 + self._eps)
        return attr


def note_of(checks) -> str:
    notes = [c.note for c in checks if c.note]
    assert len(notes) == 1, notes
    return notes[0]


@pytest.mark.parametrize("name", ["bluerov2_bare", "otter"])
def test_both_vehicles_pass_verify_without_an_envelope(generated, capsys, name):
    from abyssal.runtime import cli

    assert cli.main(["verify", str(generated / name)]) == 0
    out = capsys.readouterr().out
    assert "verification FAILED" not in out and "checks passed" in out
    # the default box is derived from the model and stated once: the rest state, a dt its RK4 is stable at
    (note,) = [line for line in out.splitlines() if line.startswith(f"NOTE {name}:")]
    assert "no envelope declared: states and inputs sampled in [-1, 1] about the rest state" in note
    stable = float(re.search(r"rk4 \(1 substep\) is stable up to dt = ([0-9.e-]+) s across the box", note).group(1))
    top = float(re.search(r"dt in \[[0-9.e-]+, ([0-9.e-]+)\] s", note).group(1))
    assert top == pytest.approx(stable, rel=1e-2) and 0.05 < stable < 0.2


def test_the_otters_rk4_error_is_judged_by_its_own_estimate(otter):
    """One RK4 step over the 0.1 s propeller lag errs by ~1e-3 (ordinary RK4 error, ~1000x the old fixed 1e-6): it
    passes because it is within 2x its step-doubling estimate; the order check reads 16 where it has settled."""
    checks = {c.name: c for c in verify_models.checks(otter.bundle, target=otter)}
    one = checks["f (rk4) one step vs solve_ivp, within its own error estimate"]
    assert one.ok and one.error > 1e-4 and one.tolerance < 1e-2
    estimate = float(re.search(r"step-doubling estimate ([0-9.e-]+)", one.detail).group(1))
    assert 0.5 < one.error / estimate < 2.0
    order = checks["f (rk4) order 4: |error ratio halving dt - 16|"]
    assert order.ok and 12 <= float(re.search(r"ratio ([0-9.]+)", order.reference).group(1)) <= 20


def test_sampled_where_rk4_is_unstable_the_code_still_passes_and_the_model_gets_a_note(rov):
    """The audit's sampling (states in [-1, 1], dt up to 0.5 s, where one RK4 step of the quadratic sway damping is
    unstable: |f| up to ~1e2 in one step) judges the code pointwise: every check passes, and the unstable dt is a
    NOTE about the model, not a FAIL."""
    bundle = rov.bundle
    unit = {"declared": True, "states": {n: [-1.0, 1.0] for n in bundle.state_names},
            "inputs": {n: [-1.0, 1.0] for n in bundle.input_names}, "max_dt": 0.5, "min_dt": 0.01,
            "default_range": [-1.0, 1.0]}
    wide = WithEnvelope(bundle, unit)
    biggest = max(np.max(np.abs(bundle.f(np.ones(12) * s, np.zeros(8), None, 0.47))) for s in (-1.0, 1.0))
    assert biggest > 10  # the step the audit saw called "diverged"
    checks = verify_models.checks(wide, target=rov)
    assert [c.name for c in checks if not c.ok] == []
    note = note_of(checks)
    assert note.startswith("a finding about the model, not its code: rk4 (1 substep) is stable up to dt = ")
    assert "below its declared max_dt = 0.5 s" in note
    table = Report(checks).table()
    assert "diverged" not in table and "FAIL" not in table


@pytest.mark.parametrize("where", ["derived box", "unstable box"])
def test_a_wrong_generated_function_still_fails(rov, where):
    """The same judging fails a function that computes the wrong thing, inside the derived box and where RK4 is
    unstable alike: a symbolic xdot 1e-9 off its C, an f 1e-9 off its scheme, an F 1e-4 off its differences."""
    bundle = rov.bundle
    if where == "unstable box":
        bundle = WithEnvelope(bundle, {"declared": True, "states": {n: [-1.0, 1.0] for n in bundle.state_names},
                                       "inputs": {n: [-1.0, 1.0] for n in bundle.input_names}, "max_dt": 0.5,
                                       "min_dt": 0.01, "default_range": [-1.0, 1.0]})
    symbolic = verify_models.symbolic_functions(rov.model)
    xdot = symbolic["xdot"]
    args = [ca.SX.sym(xdot.name_in(i), xdot.sparsity_in(i)) for i in range(xdot.n_in())]
    symbolic["xdot"] = ca.Function(xdot.name(), args, [xdot(*args) * (1 + 1e-9)])
    bad = {c.name for c in verify_models.checks(bundle, target=rov, symbolic=symbolic) if not c.ok}
    assert bad == {"xdot: compiled C vs CasADi"}
    bad = {c.name for c in verify_models.checks(Perturbed(bundle, 1e-9, {"f"}), target=rov) if not c.ok}
    assert "f vs rk4 of compiled xdot" in bad
    bad = {c.name for c in verify_models.checks(Perturbed(bundle, 1e-4, {"F"}), target=rov) if not c.ok}
    assert bad == {"F vs central differences (compiled f in x)"}


def test_verify_reuses_the_loaded_build_and_compiles_nothing_of_its_own(generated, otter, monkeypatch, capsys):
    """Compile once: a user's model is compiled when it is loaded; `abyssal verify` then generates and compiles nothing
    (its filter checks' oracle is a NumPy sigma-point filter over the loaded build, where it once generated and
    compiled a linearised copy of the model, 1.3-1.7 MB of C a second time)."""
    from abyssal.generated import regenerate
    from abyssal.runtime import cli

    build = importlib.import_module("abyssal.generated.build")
    calls = []
    real_compile, real_generate = build._compile, regenerate.generate
    monkeypatch.setattr(build, "_compile", lambda *a, **k: calls.append("compile") or real_compile(*a, **k))
    monkeypatch.setattr(regenerate, "generate", lambda *a, **k: calls.append("generate") or real_generate(*a, **k))
    assert cli.main(["verify", str(generated / "otter")]) == 0
    assert calls == [] and "abyssal: compiling" not in capsys.readouterr().err
