"""Statistics of the remus tables: the statistic is named wherever it is printed.

A local helper until the experiments share one table helper (it will replace this module).

* ``over_runs(values)``: mean and sample standard deviation (ddof = 1) of per-run values, with n.
* ``over_draws(per_draw)``: the mean and sample sd (ddof = 1) *between training draws* of the per-draw
  means (each the mean of that draw's runs), with the number of draws and their min and max.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Summary:
    mean: float
    sd: float      # sample standard deviation (ddof = 1); NaN for one value
    n: int
    low: float = math.nan
    high: float = math.nan

    def text(self, digits: int = 3) -> str:
        if not math.isfinite(self.mean):
            return "-"
        if self.n < 2 or not math.isfinite(self.sd):
            return f"{self.mean:.{digits}g}"
        return f"{self.mean:.{digits}g} ± {self.sd:.2g}"


def over_runs(values) -> Summary:
    v = np.asarray([x for x in values if math.isfinite(x)], dtype=float)
    if v.size == 0:
        return Summary(math.nan, math.nan, 0)
    sd = float(np.std(v, ddof=1)) if v.size > 1 else math.nan
    return Summary(float(np.mean(v)), sd, int(v.size), float(v.min()), float(v.max()))


def over_draws(per_draw: dict) -> Summary:
    """per_draw: {draw: Summary over that draw's runs}."""
    means = [s.mean for s in per_draw.values() if math.isfinite(s.mean)]
    return over_runs(means)
