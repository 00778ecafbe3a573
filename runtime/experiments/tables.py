"""Statistics over the runs of a campaign, as every experiment's tables print them.

A table cell over runs says which statistic it is. Two are in use, and they differ:

* ``over_runs(values)`` -- a per-run number (one run's RMSE, APE, ANEES ...) summarised over the runs: the
  mean, the sample standard deviation (ddof = 1: the spread of one run's value) and the half-width of the 95 %
  Student-t confidence interval of the mean (``sd * t(0.975, n - 1) / sqrt(n)``). Header: ``MEAN_SD``.
* ``pooled_rms(mean_squares)`` -- one RMSE over every step of every run (the square root of the mean of the
  per-run mean squares; runs of equal length). It is at least the mean of the per-run RMSEs (Jensen), so it is
  never printed beside a per-run mean as if they were the same thing. Header: ``POOLED``.

NaN values (a run where a filter refused a step, a metric a filter does not have) are left out and counted in
``OverRuns.missing``; inf (a diverged filter) is kept, so the mean is inf rather than a number that hides it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable

import numpy as np

#: the words a table header uses for each statistic (keep them identical across experiments)
MEAN_SD = "mean of the per-run values ± sample sd over runs (ddof = 1)"
MEAN_CI = "mean of the per-run values ± half-width of its 95 % t confidence interval"
POOLED = "pooled over runs: sqrt of the mean of the per-run mean squares"


@dataclass(frozen=True)
class OverRuns:
    """One per-run metric summarised over n runs (NaN runs left out; ``missing`` counts them)."""

    n: int
    mean: float
    sd: float        # sample sd, ddof = 1 (NaN when n < 2)
    ci95: float      # half-width of the 95 % t interval of the mean (NaN when n < 2)
    median: float
    low: float       # smallest value
    high: float      # largest value
    missing: int = 0

    def cell(self, spec: str = ".2f", spread: str = "sd") -> str:
        """"mean ± sd" (spread="sd"), "mean ± ci" (spread="ci95"), or the mean alone when n < 2 or nothing to
        show ("-" when there is no value at all)."""
        if self.n == 0:
            return "-"
        value = self.sd if spread == "sd" else self.ci95
        if not math.isfinite(value) or not math.isfinite(self.mean):
            return f"{self.mean:{spec}}"
        return f"{self.mean:{spec}} ± {value:{spec}}"


def over_runs(values: Iterable[float]) -> OverRuns:
    """Mean, sample sd (ddof = 1), 95 % t half-width, median and range of per-run values (see the module)."""
    from scipy.stats import t

    v = np.asarray(list(values), dtype=np.float64).ravel()
    missing = int(np.isnan(v).sum())
    v = v[~np.isnan(v)]
    n = int(v.size)
    if n == 0:
        return OverRuns(0, math.nan, math.nan, math.nan, math.nan, math.nan, math.nan, missing)
    mean = math.fsum(v) / n if np.all(np.isfinite(v)) else float(np.mean(v))
    if n < 2 or not np.all(np.isfinite(v)):
        sd = ci = math.nan
    else:
        with np.errstate(over="ignore"):  # finite but huge values (a collapsed filter's NEES): sd inf
            sd = float(np.std(v, ddof=1))
        ci = float(sd * t.ppf(0.975, n - 1) / math.sqrt(n))
    return OverRuns(n, float(mean), sd, ci, float(np.median(v)), float(v.min()), float(v.max()), missing)


def pooled_rms(mean_squares: Iterable[float]) -> float:
    """sqrt(mean of the per-run mean squares): the RMSE over every step of every run (equal-length runs); NaN
    runs left out, NaN if none."""
    v = np.asarray(list(mean_squares), dtype=np.float64).ravel()
    v = v[~np.isnan(v)]
    return math.sqrt(math.fsum(v) / v.size) if v.size and np.all(np.isfinite(v)) else (math.inf if v.size else math.nan)


def fraction(flags: Iterable[bool]) -> tuple[int, int]:
    """(how many are true, how many there are): print as "k/n runs", never as a bare percentage."""
    f = [bool(x) for x in flags]
    return sum(f), len(f)
