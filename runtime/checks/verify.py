"""`abyssal verify`: every generated function against reference numerics it was not produced by.

A check is a named comparison with a measured error and a tolerance. Sections register
checks per model; `run_all` runs them and returns a Report (printed as a table or JSON).

Sections (modules exposing ``checks(bundle) -> Iterable[Check]``):
    abyssal.runtime.checks.verify_models   compiled C vs CasADi, Jacobians vs an independent NumPy model,
                                    RK4 vs scipy solve_ivp (order), f_batch vs f
    abyssal.runtime.checks.verify_filters  generated filter steps vs filterpy and the exact Kalman filter
"""
from __future__ import annotations

import importlib
import math
import traceback
from dataclasses import asdict, dataclass, field

SECTIONS = ("abyssal.runtime.checks.verify_models", "abyssal.runtime.checks.verify_filters")


@dataclass
class Check:
    model: str
    name: str
    reference: str
    error: float
    tolerance: float
    detail: str = ""

    @property
    def ok(self) -> bool:
        return math.isfinite(self.error) and self.error <= self.tolerance


@dataclass
class Report:
    checks: list[Check] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)  # sections that raised

    @property
    def ok(self) -> bool:
        return not self.failures and all(c.ok for c in self.checks)

    def as_dict(self) -> dict:
        return {
            "ok": self.ok,
            "checks": [dict(asdict(c), ok=c.ok) for c in self.checks],
            "errors": self.failures,
        }

    def table(self) -> str:
        rows = [("model", "check", "reference", "error", "tolerance", "")]
        for c in self.checks:
            rows.append((c.model, c.name, c.reference, f"{c.error:.2e}", f"{c.tolerance:.0e}", "ok" if c.ok else "FAIL"))
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        lines = ["  ".join(cell.ljust(w) for cell, w in zip(r, widths)).rstrip() for r in rows]
        lines.insert(1, "  ".join("-" * w for w in widths))
        for c in self.checks:
            if not c.ok and c.detail:
                lines.append(f"FAIL {c.model} {c.name}: {c.detail}")
        lines.extend(f"ERROR {msg}" for msg in self.failures)
        passed = sum(c.ok for c in self.checks)
        lines.append(f"{passed} of {len(self.checks)} checks passed" + ("" if self.ok else " -- verification FAILED"))
        return "\n".join(lines)


def run_all(models: list[str] | None = None) -> Report:
    from abyssal import generated

    names = models or generated.available()
    report = Report()
    for name in names:
        bundle = generated.load(name)
        for section in SECTIONS:
            try:
                module = importlib.import_module(section)
            except ModuleNotFoundError as exc:
                if exc.name == section:
                    continue  # section not built yet
                raise
            try:
                report.checks.extend(module.checks(bundle))
            except Exception:  # a crashing check is a failure, reported, never hidden
                report.failures.append(f"{section} on {name}:\n{traceback.format_exc()}")
    return report
