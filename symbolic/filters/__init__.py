"""Symbolic filter algebra: whole filter steps as CasADi Functions of any Model.

One module per family, one generated C file (codegen.Unit) per family:

    ekf.py        unit "ekf":    <m>_ekf_predict, <m>_ekf_update (Joseph form)
    unscented.py  unit "ukf":    <m>_ukf_predict, <m>_ukf_update (alpha, beta, kappa at run time)
                  unit "ckf":    <m>_ckf_predict, <m>_ckf_update (third-degree cubature)
    robust.py     unit "robust": <m>_mcukf_update (maximum correntropy), <m>_huber_ukf_update
    ekf.py, unscented.py  unit "steps": <m>_ekf_step, <m>_ckf_step (predict + update fused, one call
                  per step for the runtime; a file of its own so the compiler builds it in parallel)

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


def filter_units(model: Model) -> list[Unit]:
    """The generated filter units of a model, one C file each."""
    families = {
        "ekf": ekf_functions(model),
        "ukf": ukf_functions(model),
        "ckf": ckf_functions(model),
        "robust": robust_functions(model),
        "steps": (ekf_step_function(model), ckf_step_function(model)),  # own file: compiles in parallel
    }
    return [Unit(name, tuple(share_reciprocals(fn) for fn in functions)) for name, functions in families.items()]


__all__ = ["filter_units"]
