"""`abyssal verify`: every generated function against reference numerics it was not produced by.

Sections register checks per model; `run_all` (built-ins by name, model folders) and
`verify_targets` run them and return a Report (report.py; printed as a table or JSON).

Sections (modules exposing ``checks(bundle, target) -> Iterable[Check]``), in SECTIONS:
    abyssal.verify.models   compiled C vs CasADi, Jacobians vs central differences,
                            RK4/Euler vs scipy solve_ivp (order), f_batch vs f
    abyssal.verify.filters  generated filter steps vs filterpy and the exact Kalman filter
    abyssal.verify.remus    the GP export (abyssal.symbolic.gp) vs scikit-learn (remus100)
    abyssal.verify.tan      fuzzy_sigma vs scikit-fuzzy, the bathymetry lookup vs scipy, the step at omega = 0
    abyssal.verify.cn       batched proposal steps, MCC/Huber limits, IVBCKF, KLD sample sizes (cn2d)

What is verified: the built-in models by name, or any model folder written by abyssal.generate
(``abyssal verify DIR...``), or a model function (``abyssal verify --model FILE.py:FUNCTION``). A
built-in has a hand-written NumPy twin (reference_models.py) whose checks run too; a user's model
is checked against its own compiled functions by different computations (central differences of
f and h, solve_ivp of xdot) and against CasADi's evaluation of the Model, which is found again
through the manifest.
"""
from __future__ import annotations

import importlib
import math
import traceback
from dataclasses import dataclass
from pathlib import Path

from abyssal.runtime.extras import missing_optional

from .report import Check, Report

SECTIONS = ("abyssal.verify.models", "abyssal.verify.filters", "abyssal.verify.remus", "abyssal.verify.tan",
            "abyssal.verify.cn")


@dataclass
class Target:
    """One model to verify: its bundle and the oracles found for it.

    model: the symbolic Model the folder was generated from (None when it cannot be found, with the
    reason in `model_missing`); reference: the NumPy twin of a built-in (None for user models).
    """

    bundle: object
    model: object = None
    model_missing: str = ""
    reference: object = None
    builtin: bool = False


def _sections():
    for section in SECTIONS:
        yield section, importlib.import_module(section)  # a missing or renamed section is an error, never skipped


def builtin_target(name: str) -> Target:
    from abyssal import generated
    from abyssal.symbolic.models import REGISTRY

    from .reference_models import REFERENCES

    model = REGISTRY[name]() if name in REGISTRY else None
    return Target(generated.load(name), model, "" if model else f"{name!r} is not in the model registry",
                  REFERENCES.get(name), builtin=True)


def folder_target(folder) -> Target:
    """A folder written by abyssal.generate; its Model is found through the manifest's generated_by."""
    from abyssal import generated
    from abyssal.generated import regenerate

    bundle = generated.load(folder)
    origin = bundle.manifest.get("generated_by", {}).get("model_function", {})
    if "function" not in origin:
        return Target(bundle, None, "the manifest records no model function (generated from a Model object): verify "
                      "with `abyssal verify --model FILE.py:FUNCTION` or generate from the function")
    spec = (str(bundle.folder / origin["file"]) if "file" in origin else origin["module"]) + ":" + origin["function"]
    try:
        model, _ = regenerate.load_model_spec(spec)
    except Exception as exc:  # the folder moved away from its model file, or the file no longer builds
        return Target(bundle, None, f"its model {spec} could not be loaded ({type(exc).__name__}: {exc})")
    return Target(bundle, model)


def model_target(model, folder) -> Target:
    """A Model (from --model) and the folder it was generated into."""
    from abyssal import generated

    return Target(generated.load(folder), model)


def verify_targets(targets, strict: bool = False) -> Report:
    report = Report(strict=strict)
    for target in targets:
        name = target.bundle.name
        if target.model is not None and target.model.equations_hash() != target.bundle.manifest["equations_sha256"]:
            command = target.bundle.manifest.get("generated_by", {}).get("command", "abyssal regenerate")
            report.checks.append(Check(name, "generated folder matches its model's equations", "equations sha256",
                                       math.inf, 0.0, f"the model changed since {target.bundle.folder} was generated: "
                                       f"run `{command}`"))
            target = Target(target.bundle, None, "the model's equations changed since generation", target.reference,
                            target.builtin)
        for section, module in _sections():
            try:
                report.checks.extend(module.checks(target.bundle, target=target))
            except Exception as exc:  # a crashing check is a failure, reported, never hidden
                missing = missing_optional(exc)
                if missing:  # an absent optional reference: the section is reported as skipped, with why (named
                    # verify_<section>, as the report always has)
                    report.checks.append(Check.skip(name, f"verify_{section.rsplit('.', 1)[-1]} checks", "optional reference",
                                                    missing))
                else:
                    report.failures.append(f"{section} on {name}:\n{traceback.format_exc()}")
    return report


def run_all(models: list[str] | None = None, folders=(), strict: bool = False) -> Report:
    """Verify built-ins by name (all when neither models nor folders are given) and model folders."""
    from abyssal import generated

    names = models or ([] if folders else generated.available())
    targets = []
    report = Report(strict=strict)
    for name in names:
        targets.append(builtin_target(name))
    for folder in folders:
        inside = sorted(Path(folder).glob("*/manifest.json"))
        if not (Path(folder) / "manifest.json").is_file() and inside:  # an --out folder: every model in it
            targets += [folder_target(m.parent) for m in inside]
        else:
            targets.append(folder_target(folder))
    result = verify_targets(targets, strict)
    report.checks, report.failures = result.checks, result.failures
    return report
