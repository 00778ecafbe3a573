"""Registered vehicle models: one file per vehicle, each a plain function returning a Model."""
from .cn2d import cn2d
from .linear_cv import linear_cv
from .remus100 import remus100
from .rov4dof import rov4dof
from .tan3dof import tan3dof

#: name -> model function; `abyssal regenerate` generates C for each of these.
REGISTRY = {"rov4dof": rov4dof, "cn2d": cn2d, "linear_cv": linear_cv, "remus100": remus100, "tan3dof": tan3dof}

__all__ = ["REGISTRY", "cn2d", "linear_cv", "remus100", "rov4dof", "tan3dof"]
