"""Scores of a track against the truth (the truth only scores: no filter sees it).

    row = score(track, truth, surfaced)       # one tidy row: RMSE, NEES, NIS per sensor

RMSE: horizontal position (north, east) over the whole dive and over its submerged part (no GNSS there).
NEES: e^T P^-1 e of the full state (heading error wrapped) and of the horizontal position, each divided by its
dimension, averaged over the clock: 1 for a consistent filter (ANEES once averaged over the seeds too).
NIS per sensor: nu^T S^-1 nu of every accepted update, divided by its degrees of freedom (mean 1 when consistent),
and the share of updates whose NIS lies inside the two-sided 95 % chi-square interval of its dof (95 % expected).
"""
from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from abyssal.runtime.numerics import wrap_to_pi

HORIZONTAL = [6, 7]
ANGLES = slice(9, 12)


def errors(x: np.ndarray, truth: np.ndarray) -> np.ndarray:
    e = x - truth
    e[:, ANGLES] = wrap_to_pi(e[:, ANGLES])
    return e


def nees(e: np.ndarray, P: np.ndarray, states=None) -> np.ndarray:
    """Per row: e^T P^-1 e over the given states (all by default), divided by their number."""
    if states is not None:
        e, P = e[:, states], P[:, states][:, :, states]
    return np.einsum("ti,ti->t", e, np.linalg.solve(P, e[..., None])[..., 0]) / e.shape[1]


def nis_summary(nis: np.ndarray) -> tuple[float, float, int]:
    """(mean NIS / dof, share inside the 95 % chi-square interval, count) of (NIS, dof) rows."""
    if len(nis) == 0:
        return float("nan"), float("nan"), 0
    value, dof = nis[:, 0], nis[:, 1]
    low, high = chi2.ppf(0.025, dof), chi2.ppf(0.975, dof)
    return float(np.mean(value / dof)), float(np.mean((value >= low) & (value <= high))), len(nis)


def score(x: np.ndarray, P: np.ndarray, truth: np.ndarray, surfaced: np.ndarray, nis: dict | None = None) -> dict:
    e = errors(x, truth)
    horizontal = np.hypot(e[:, 6], e[:, 7])
    row = {"rmse_xy": float(np.sqrt(np.mean(horizontal**2))),
           "rmse_xy_submerged": float(np.sqrt(np.mean(horizontal[~surfaced] ** 2))),
           "nees": float(np.mean(nees(e, P))), "nees_xy": float(np.mean(nees(e, P, HORIZONTAL)))}
    for sensor, rows in (nis or {}).items():
        mean, inside, count = nis_summary(rows)
        row.update({f"nis_{sensor}": mean, f"nis_{sensor}_in95": inside, f"n_{sensor}": count})
    return row
