"""Symbolic filter algebra: whole filter steps as CasADi Functions of any Model.

One module per family, one generated C file (codegen.Unit) per family:

    ekf.py        unit "ekf":          <m>_ekf_predict, <m>_ekf_update (Joseph form), <m>_ekf_step
    unscented.py  unit "sigma_points": family "ukf": <m>_ukf_predict, <m>_ukf_update (alpha, beta,
                                       kappa at run time); family "ckf": <m>_ckf_predict,
                                       <m>_ckf_update (third-degree cubature), <m>_ckf_step
    robust.py     unit "sigma_points": family "robust": <m>_mcukf_update (maximum correntropy),
                                       <m>_huber_ukf_update (on the UKF's points)

The sigma-point families share one file: the model's step and measurement, the Kalman gain and
the other leaves that no rule changes are emitted once for all of them.

The fused steps (<m>_ekf_step, <m>_ckf_step: one C call per step for the runtime) call their
family's predict and update, so they live in that family's file. Every step is built from leaves
(common.py): the model's f and h are emitted once per file and called per sigma point.

Which families a model gets is a choice (``filter_units(model, families)``): the built-ins declare
theirs in ``abyssal.symbolic.models.FILTER_FAMILIES`` (default: all), a user passes
``abyssal.generate(model, out_dir, filters=("ckf",))``. The particle filters need no family: they
run on the model's own f/h kernels, which every model gets.

Shared pieces: sigma_points.py (rules as data), measurement.py (masks, angle residuals, gain),
linalg.py (guarded Cholesky: a non-PD matrix gives ok = 0, never NaN), reciprocals.py (every
leaf has its divisions by a shared divisor turned into one reciprocal + products).
"""
from __future__ import annotations

from ..codegen import Unit
from ..model import Model
from .ekf import ekf_functions
from .robust import robust_functions
from .unscented import SharedLeaves, ckf_functions, ukf_functions, unscented_family

from .families import FAMILIES, FUNCTIONS, REQUIRES  # noqa: F401 (the names' one home, re-exported)


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
    """The generated filter units of a model for the chosen families: "ekf", and "sigma_points" for the
    UKF, CKF and robust updates together (one file: they share the model's step, measurement, moments'
    and Kalman gain leaves, SharedLeaves)."""
    families = check_families(families)
    units = []
    if "ekf" in families:
        units.append(Unit("ekf", ekf_functions(model)))
    if not {"ukf", "ckf"} & set(families):
        return units
    sigma_points: tuple = ()
    shared = SharedLeaves(model)
    if "ukf" in families:
        family = unscented_family(model, shared)
        sigma_points += ukf_functions(model, family)
        if "robust" in families:
            sigma_points += robust_functions(model, family)
    if "ckf" in families:
        sigma_points += ckf_functions(model, shared)
    return [*units, Unit("sigma_points", sigma_points)]


__all__ = ["FAMILIES", "check_families", "filter_units"]
