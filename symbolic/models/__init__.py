"""Registered vehicle models: one file per vehicle, each a plain function returning a Model."""
from .cn2d import cn2d
from .linear_cv import linear_cv
from .rov4dof import rov4dof

#: name -> model function; `abyssal regenerate` generates C for each of these.
REGISTRY = {"rov4dof": rov4dof, "cn2d": cn2d, "linear_cv": linear_cv}

__all__ = ["REGISTRY", "cn2d", "linear_cv", "rov4dof"]
