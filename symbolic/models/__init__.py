"""Registered vehicle models: one file per vehicle, each a plain function returning a Model."""
from .cn2d import cn2d
from .linear_cv import linear_cv
from .remus100 import remus100
from .rov4dof import rov4dof
from .tan3dof import tan3dof

#: name -> model function; `abyssal regenerate` generates C for each of these.
REGISTRY = {"rov4dof": rov4dof, "cn2d": cn2d, "linear_cv": linear_cv, "remus100": remus100, "tan3dof": tan3dof}

#: name -> the filter families generated for it (abyssal.symbolic.filters.FAMILIES); a model not
#: listed here gets every family.
FILTER_FAMILIES: dict[str, tuple[str, ...]] = {
    # 12-state 6-DOF with 2 RK4 substeps: all families are ~8 MB of C and ~66 s of compile on 2 cores;
    # seed 004 needs the UKF only (the ideal UKF of Tables 3-4).
    "remus100": ("ukf",),
    # seed 003's filters are particle filters on the model's own f kernel: no Kalman family needed
    "tan3dof": (),
}

__all__ = ["FILTER_FAMILIES", "REGISTRY", "cn2d", "linear_cv", "remus100", "rov4dof", "tan3dof"]
