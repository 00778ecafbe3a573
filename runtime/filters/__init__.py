"""State estimators on generated C: kalman/ (one engine, thin families), particle/ (SIR), mixture/ (Gaussian sums).

Importing this package imports every family, so each filter class registers itself with the
contract (``abyssal.runtime.contract.registered_filters``).
"""
from . import kalman, mixture, particle  # noqa: F401

__all__ = ["kalman", "mixture", "particle"]
