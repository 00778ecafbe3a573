"""State estimators on the C runtime and the models' generated C: kalman/ (one engine, thin classes), particle/ (SIR),
mixture/ (Gaussian sums).

Importing this package imports every family, so each filter class registers itself with the
contract (``abyssal.runtime.contract.registered_filters``).
"""
from . import kalman, mixture, particle  # noqa: F401

__all__ = ["kalman", "mixture", "particle"]
