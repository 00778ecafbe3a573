"""The results of `abyssal verify`: a Check (one named comparison with its measured error and
tolerance, or a skip with its reason) and the Report of a run (a table or JSON).

A check that cannot run is reported as skipped with its reason (a status of its own, shown in the
table and the summary), never as a silent pass; ``strict`` makes skips fail.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field


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
