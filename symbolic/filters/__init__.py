"""Symbolic filter algebra: whole filter steps as CasADi Functions of a Model."""


def filter_units(model):
    """The generated filter units of a model (none yet)."""
    return []
