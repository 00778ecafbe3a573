"""Statistics over runs for the TAN tables (a local stand-in: swap for the experiments' shared table helper when it
lands; the names follow it).

* ``over_runs(values)``: a per-run number summarised over the runs -- mean, sample sd (ddof = 1), n; NaN runs left
  out (a filter that has no such metric).
* ``aligned(header, rows)``: the lines of a plain-text table.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable

import numpy as np

#: the words a table header uses for a per-run value summarised over runs
MEAN_SD = "mean of the per-run values ± sample sd over runs (ddof = 1)"


@dataclass(frozen=True)
class OverRuns:
    n: int
    mean: float
    sd: float        # ddof = 1; NaN when n < 2
    median: float

    def cell(self, spec: str = ".0f") -> str:
        if self.n == 0:
            return "-"
        if not math.isfinite(self.sd):
            return f"{self.mean:{spec}}"
        return f"{self.mean:{spec}} ± {self.sd:{spec}}"


def over_runs(values: Iterable[float]) -> OverRuns:
    v = np.asarray(list(values), dtype=np.float64).ravel()
    v = v[~np.isnan(v)]
    if v.size == 0:
        return OverRuns(0, math.nan, math.nan, math.nan)
    sd = float(np.std(v, ddof=1)) if v.size > 1 else math.nan
    return OverRuns(int(v.size), float(np.mean(v)), sd, float(np.median(v)))


def aligned(header: list[str], rows: list[list[str]], left: int = 1) -> list[str]:
    """Text table lines: the first ``left`` columns left-aligned, the rest right-aligned, two spaces apart."""
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]

    def line(cells):
        return "  ".join(c.ljust(w) if i < left else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))).rstrip()

    return [line(header), *(line(r) for r in rows)]
