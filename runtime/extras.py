"""abyssal's optional dependencies: the experiments and replay extras, and one message when one is missing.

The core install (casadi, numpy, scipy) builds, loads, verifies and runs every filter; what a vehicle
computer runs needs nothing else. `abyssal reproduce` and the experiments need one extra, `abyssal replay` another:

    pip install 'abyssal[experiments]'     Dask (campaigns), tqdm (progress), scikit-learn (GP models),
                                           matplotlib (figures); part of '.[test]'
    pip install 'abyssal[replay]'          rosbags (rosbag2 / MCAP without ROS), pymap3d (geodesy), tqdm,
                                           matplotlib; part of '.[test]'

Modules that need one of them import it through ``require`` at the point of use, never at import
time, so ``import abyssal`` works without the extra.
"""
from __future__ import annotations

import importlib
from types import ModuleType

EXTRA = "experiments"
INSTALL = f"pip install 'abyssal[{EXTRA}]'"
#: top-level module -> the package that provides it
PROVIDERS = {"dask": "dask", "distributed": "dask[distributed]", "tqdm": "tqdm", "sklearn": "scikit-learn",
             "matplotlib": "matplotlib", "rosbags": "rosbags", "pymap3d": "pymap3d"}
#: top-level module -> the extra that brings it, when it is not the experiments extra
EXTRA_OF = {"rosbags": "replay", "pymap3d": "replay"}
#: the independent references of `abyssal verify` that come with '.[test]' (beside the experiments extra's
#: scikit-learn, and matplotlib's offline bathymetry sample)
ORACLES = {"filterpy": "filterpy", "skfuzzy": "scikit-fuzzy", **PROVIDERS}


class MissingExtraError(ImportError):
    """A feature needs a package of an extra (experiments, replay) that is not installed."""


def missing_optional(exc: BaseException) -> str | None:
    """The optional package (experiments extra or a verify reference) whose absence raised exc, else None."""
    if isinstance(exc, MissingExtraError):
        return str(exc)
    if isinstance(exc, ModuleNotFoundError) and exc.name and exc.name.split(".")[0] in ORACLES:
        return f"{ORACLES[exc.name.split('.')[0]]} is not installed (pip install 'abyssal[test]')"
    return None


def require(module: str, purpose: str, extra: str | None = None) -> ModuleType:
    """`module`, imported; MissingExtraError (one line: what needs it and the pip command) if it is absent.
    extra: the extra to name (default: the one that brings the module; tqdm and matplotlib are in both)."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        top = (exc.name or module).split(".")[0]
        if top not in PROVIDERS:
            raise
        name = extra or EXTRA_OF.get(top, EXTRA)
        raise MissingExtraError(f"{purpose} needs {PROVIDERS[top]}, part of abyssal's {name} extra: "
                                f"pip install 'abyssal[{name}]'") from None
