"""abyssal: CasADi models of underwater vehicles generated to C, and fast verified state estimators.

The public surface in one import; the layers stay where the design card puts them:

    abyssal.symbolic    CasADi only: Model, Fossen blocks, discretisations, filter algebra, codegen
    abyssal.generated   committed C, compile cache, loader
    abyssal.runtime     filters, particles, noise models, experiments, CLI
    abyssal.verify      `abyssal verify`: checks all three layers against independent references

Your own vehicle, from equations to a verified filter:

    import abyssal
    folder = abyssal.generate(myvessel, "gen")          # gen/myvessel/: C, SoA kernels, manifest
    vessel = abyssal.load(folder)                        # compiled through the shared cache
    assert abyssal.verify(folder).ok                     # compiled C vs CasADi, Jacobians, steps, filters
    ckf = abyssal.CKF(vessel, x0, P0, Q, R)
    abyssal.export(folder, filter="ckf", out="myvessel_ckf")   # a C99 project of that filter for the vehicle
    abyssal.replay("dive.mcap", folder, filter="ckf", sensors="map.toml", out="replayed", smooth=True)   # a recorded log
"""
import importlib

from abyssal.generated import load
from abyssal.generated.regenerate import check_folder as check_generated
from abyssal.generated.regenerate import generate
from abyssal.runtime import CKF, EKF, MCUKF, UKF, FilterResult, HuberUKF
from abyssal.runtime.filters.particle import CubatureParticleFilter, ParticleFilter
from abyssal.runtime.noise import GaussianMixture
from abyssal.runtime.replay import replay
from abyssal.symbolic import Envelope, Model, Parameter, Quantity, Sensor, discretise, fossen, symbols

# The package abyssal.verify is loaded before the function of the same name is defined below, so the
# function stays the attribute `abyssal.verify` (loading a submodule later would overwrite it).
importlib.import_module("abyssal.verify")
from abyssal.export import export  # noqa: E402 (the function is the attribute `abyssal.export`, as verify's)


def verify(target, *, strict: bool = False):
    """The `abyssal verify` report of a built-in name, a generated model folder, or a Model function.

    A Model or a function returning one is generated into a temporary folder first. ``report.ok``
    says whether everything that ran passed (``strict=True``: and nothing was skipped);
    ``print(report.table())`` shows each check.
    """
    import os
    import tempfile

    from abyssal.verify import driver

    if isinstance(target, (str, os.PathLike)):
        folders = [target] if (isinstance(target, os.PathLike) or "/" in target or os.sep in target) else []
        return driver.run_all(models=None if folders else [target], folders=folders, strict=strict)
    folder = generate(target, tempfile.mkdtemp(prefix="abyssal-verify-"))
    model = target if isinstance(target, Model) else target()
    return driver.verify_targets([driver.model_target(model, folder)], strict=strict)


__all__ = [
    "CKF", "CubatureParticleFilter", "EKF", "Envelope", "FilterResult", "GaussianMixture", "HuberUKF", "MCUKF", "Model",
    "Parameter", "ParticleFilter", "Quantity", "Sensor", "UKF", "check_generated", "discretise", "export", "fossen", "generate", "load",
    "replay", "symbols", "verify",
]
