"""`abyssal verify`: every generated function against reference numerics it was not produced by.

A check is a named comparison with a measured error and a tolerance. Sections register
checks per model; `run_all` runs them and returns a Report (printed as a table or JSON).

Sections (modules exposing ``checks(bundle, target) -> Iterable[Check]``):
    abyssal.runtime.checks.verify_models   compiled C vs CasADi, Jacobians vs central differences,
                                    RK4/Euler vs scipy solve_ivp (order), f_batch vs f
    abyssal.runtime.checks.verify_filters  generated filter steps vs filterpy and the exact Kalman filter

What is verified: the built-in models by name, or any model folder written by abyssal.generate
(``abyssal verify DIR...``), or a model function (``abyssal verify --model FILE.py:FUNCTION``). A
built-in has a hand-written NumPy twin (reference_models.py) whose checks run too; a user's model
is checked against its own compiled functions by different computations (central differences of
f and h, solve_ivp of xdot) and against CasADi's evaluation of the Model, which is found again
through the manifest. A check that cannot run is reported as skipped with its reason (a status of
its own, shown in the table and the summary), never as a silent pass; ``strict`` makes skips fail.
"""
from __future__ import annotations

import importlib
import math
import traceback
from pathlib import Path
from dataclasses import asdict, dataclass, field

from ..extras import missing_optional

SECTIONS = ("abyssal.runtime.checks.verify_models", "abyssal.runtime.checks.verify_filters",
            "abyssal.runtime.checks.verify_remus", "abyssal.runtime.checks.verify_tan",
            "abyssal.runtime.checks.verify_cn")


@dataclass
class Check:
    model: str
    name: str
    reference: str
    error: float
    tolerance: float
    detail: str = ""
    #: why the check could not run ("" when it ran); a skipped check is neither passed nor failed
    skipped: str = ""
    #: where it was worst: the point (x, u, p, dt), the entry (e.g. F[3,7]), both values and the tolerance,
    #: or "diverged at <point>: ..." for a step that blew up (printed on its FAIL line)
    worst: str = ""
    #: something the report says once about how the check ran (e.g. that no envelope was declared)
    note: str = ""

    @classmethod
    def skip(cls, model: str, name: str, reference: str, because: str) -> "Check":
        return cls(model, name, reference, math.nan, math.nan, skipped=because)

    @property
    def ok(self) -> bool:
        return bool(self.skipped) or (math.isfinite(self.error) and self.error <= self.tolerance)

    @property
    def status(self) -> str:
        if self.skipped:
            return "skipped"
        return "ok" if self.ok else "FAIL"


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


@dataclass
class Report:
    checks: list[Check] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)  # sections that raised
    strict: bool = False  # skipped checks count as failures

    @property
    def ok(self) -> bool:
        return not self.failures and all(c.ok and not (self.strict and c.skipped) for c in self.checks)

    def as_dict(self) -> dict:
        return {
            "ok": self.ok,
            "checks": [dict(asdict(c), ok=c.ok, status=c.status) for c in self.checks],
            "errors": self.failures,
        }

    def table(self) -> str:
        rows = [("model", "check", "reference", "error", "tolerance", "")]
        for c in self.checks:
            if c.skipped:
                rows.append((c.model, c.name, c.reference, "-", "-", "skipped"))
            else:
                rows.append((c.model, c.name, c.reference, f"{c.error:.2e}", f"{c.tolerance:.0e}", c.status))
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        lines = ["  ".join(cell.ljust(w) for cell, w in zip(r, widths)).rstrip() for r in rows]
        lines.insert(1, "  ".join("-" * w for w in widths))
        for c in self.checks:
            if c.note:
                lines.append(f"NOTE {c.model}: {c.note}")
        for c in self.checks:
            if c.skipped:
                lines.append(f"SKIPPED {c.model} {c.name}: skipped, because {c.skipped}")
        for c in self.checks:
            if not c.ok and (c.worst or c.detail):
                lines.append(f"FAIL {c.model} {c.name}: " + "; ".join(t for t in (c.worst, c.detail) if t))
        lines.extend(f"ERROR {msg}" for msg in self.failures)
        ran = [c for c in self.checks if not c.skipped]
        skipped = len(self.checks) - len(ran)
        lines.append(f"{sum(c.ok for c in ran)} of {len(ran)} checks passed"
                     + (f", {skipped} skipped" if skipped else "")
                     + ("" if self.ok else " -- verification FAILED"))
        return "\n".join(lines)


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
                if missing:  # an absent optional reference: the section is reported as skipped, with why
                    report.checks.append(Check.skip(name, f"{section.rsplit('.', 1)[-1]} checks", "optional reference",
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
