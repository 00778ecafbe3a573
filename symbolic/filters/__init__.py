"""Symbolic filter algebra: whole filter steps as CasADi Functions of any Model.

One module per family, one generated C file (codegen.Unit) per family:

    ekf.py        unit "ekf":    <m>_ekf_predict, <m>_ekf_update (Joseph form)
    unscented.py  unit "ukf":    <m>_ukf_predict, <m>_ukf_update (alpha, beta, kappa at run time)
                  unit "ckf":    <m>_ckf_predict, <m>_ckf_update (third-degree cubature)
    robust.py     unit "robust": <m>_mcukf_update (maximum correntropy), <m>_huber_ukf_update
    ekf.py, unscented.py  unit "steps": <m>_ekf_step, <m>_ckf_step (predict + update fused, one call
                  per step for the runtime; a file of its own so the compiler builds it in parallel)

Which families a model gets is a choice (``filter_units(model, families)``): the built-ins declare
theirs in ``abyssal.symbolic.models.FILTER_FAMILIES`` (default: all), a user passes
``abyssal.generate(model, out_dir, filters=("ckf",))``. The particle filters need no family: they
run on the model's own f/h kernels, which every model gets.

Shared pieces: sigma_points.py (rules as data), measurement.py (masks, angle residuals, gain),
linalg.py (guarded Cholesky: a non-PD matrix gives ok = 0, never NaN), reciprocals.py (every
generated step has its divisions by a shared divisor turned into one reciprocal + products).
"""
from __future__ import annotations

from ..codegen import Unit
from ..model import Model
from .ekf import ekf_functions, ekf_step_function
from .reciprocals import share_reciprocals
from .robust import robust_functions
from .unscented import ckf_functions, ckf_step_function, ukf_functions

#: every filter family, in the order of the generated units
FAMILIES = ("ekf", "ukf", "ckf", "robust")
#: family -> families it builds on (the robust filters predict with the UKF step)
REQUIRES = {"robust": ("ukf",)}


def check_families(families) -> tuple[str, ...]:
    """The requested families in canonical order; unknown names and missing prerequisites are errors."""
    if isinstance(families, str):
        families = (families,)
    requested = tuple(families)
    unknown = [f for f in requested if f not in FAMILIES]
    if unknown:
        raise ValueError(f"unknown filter famil{'y' if len(unknown) == 1 else 'ies'} {unknown}; choose from {list(FAMILIES)}")
    for family in requested:
        missing = [r for r in REQUIRES.get(family, ()) if r not in requested]
        if missing:
            raise ValueError(f"filter family {family!r} needs {missing} too (its filters predict with that step)")
    return tuple(f for f in FAMILIES if f in requested)


def filter_units(model: Model, families=FAMILIES) -> list[Unit]:
    """The generated filter units of a model for the chosen families, one C file each."""
    families = check_families(families)
    builders = {"ekf": ekf_functions, "ukf": ukf_functions, "ckf": ckf_functions, "robust": robust_functions}
    units = {family: builders[family](model) for family in families}
    fused = tuple(make(model) for family, make in (("ekf", ekf_step_function), ("ckf", ckf_step_function))
                  if family in families)
    if fused:
        units["steps"] = fused  # own file: compiles in parallel
    return [Unit(name, tuple(share_reciprocals(fn) for fn in functions)) for name, functions in units.items()]


__all__ = ["FAMILIES", "check_families", "filter_units"]
