"""abyssal: CasADi models of underwater vehicles generated to C, and fast verified state estimators.

The public surface in one import; the layers stay where the design card puts them:

    abyssal.symbolic    CasADi only: Model, Fossen blocks, discretisations, filter algebra, codegen
    abyssal.generated   committed C, compile cache, loader
    abyssal.runtime     filters, particles, noise models, experiments, checks, CLI
"""
from abyssal.generated import load
from abyssal.runtime import CKF, EKF, MCUKF, UKF, FilterResult, HuberUKF
from abyssal.symbolic import Model, Parameter, Quantity, fossen

__all__ = ["CKF", "EKF", "FilterResult", "HuberUKF", "MCUKF", "Model", "Parameter", "Quantity", "UKF", "fossen", "load"]
