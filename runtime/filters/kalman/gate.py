"""The innovation gate of every Kalman-type filter (the engine's EKF/UKF/CKF/robust UKFs, GP-UKF, IVBCKF).

    gate = InnovationGate(R, probability=1e-10, patience=5, inflation=4.0)
    accepted, gated = gate.select(evaluate, present)   # evaluate(present) -> (nu, S) of that update
    if gate.note(gated, present):                        # an entry gated `patience` times in a row
        P *= gate.inflation

After an update, the NIS of the present entries is compared with the chi-square quantile of tail
probability ``probability`` (1e-10: a consistent filter gates a measurement once in 10^10 updates;
0 turns the gate off). When it fails, the entries whose own normalised innovation nu_i^2 / S_ii
exceeds the one-degree quantile are left out and the update is redone with the rest (which must
pass too); when no single entry is to blame, the whole measurement is left out. An entry gated in
``patience`` consecutive updates means the filter, not the sensor, is probably wrong (a jump it
cannot follow): each further update that gates it asks for P to be multiplied by ``inflation``
until the entry passes (inflation, not a reset: a reset returns to the state the filter could not
follow). ``gated`` counts the entries left out, ``inflations`` the inflations.

Conventions of the generated updates: nu is (m,) with 0 on unused entries and S (m, m) with
identity rows there, so a NIS over all rows is the NIS of the present ones.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

from ...contract import Stateful

__all__ = ["InnovationGate"]

_INF = math.inf


class InnovationGate(Stateful):
    """Chi-square innovation gate with entry-wise outlier rejection and recovery by inflation (module docstring).

    S_dominates_R: S = (predicted measurement covariance) + R with a positive semi-definite first term,
    so nu^T R^-1 nu bounds the NIS from above (the EKF, the CKF, a UKF with non-negative weights): a
    complete measurement is then passed on that bound before any exact NIS is computed.
    """

    def __init__(self, R: np.ndarray, *, probability: float = 1e-10, patience: int = 5, inflation: float = 4.0,
                 S_dominates_R: bool = False):
        if not 0.0 <= probability < 1.0:
            raise ValueError(f"gate_probability must be in [0, 1) (0: no gate), got {probability!r}")
        if not (inflation >= 1.0 and int(patience) >= 1):
            raise ValueError(f"gate_inflation >= 1 and gate_patience >= 1 are required, got {inflation!r}, {patience!r}")
        m = R.shape[0]
        self.probability, self.patience, self.inflation = float(probability), int(patience), float(inflation)
        self.S_dominates_R = S_dominates_R
        # chi-square quantiles, index = degrees of freedom (inf: gate off)
        self.thresholds = np.full(m + 1, _INF) if probability == 0 else np.concatenate(
            [[_INF], chi2.isf(probability, np.arange(1, m + 1))])
        self._m = m
        #: measurement entries left out so far
        self.gated = 0
        #: covariance inflations asked for after `patience` consecutive gated updates of an entry
        self.inflations = 0
        self._streak = np.zeros(m, dtype=int)  # consecutive gated updates of each entry
        #: any streak > 0 (a bool: the hot path reads it before calling accepted_all)
        self.streaking = False
        self.set_R(R)

    def set_R(self, R: np.ndarray) -> None:
        """The measurement covariance behind the cheap bounds (R must be positive definite)."""
        self._R_inv = np.linalg.inv(R)
        self._R_inv_norm = 1.0 / float(np.linalg.eigvalsh(R)[0])  # 1 / lambda_min(R)

    # the counters are the gate's state; a tuple (not the generic dict) keeps an update's snapshot cheap
    def checkpoint(self):
        return self.gated, self.inflations, self._streak.copy() if self.streaking else None

    def restore(self, state) -> None:
        self.gated, self.inflations, streak = state
        self._streak[:] = 0 if streak is None else streak
        self.streaking = streak is not None

    def passes(self, nu: np.ndarray, S: np.ndarray, dof: int) -> bool:
        """Whether an update with innovation nu and covariance S over dof entries passes. Cheap bounds first
        (S >= R): NIS <= |nu|^2 / lambda_min(R), then NIS <= nu^T R^-1 nu, then the exact NIS."""
        threshold = self.thresholds[dof]
        if threshold == _INF:
            return True
        if self.S_dominates_R and dof == self._m:
            bound = nu.dot(nu) * self._R_inv_norm  # >= nu^T R^-1 nu, so the next line cannot overflow below 1e300
            if bound <= threshold or (bound < 1e300 and nu.dot(self._R_inv).dot(nu) <= threshold):
                return True
        with np.errstate(over="ignore", invalid="ignore"):  # a huge innovation: inf/NaN fail the gate
            nis = float(nu @ np.linalg.solve(S, nu))
        return math.isfinite(nis) and nis <= threshold

    def select(self, evaluate, present: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
        """(the entries of the accepted update or None, the entries gated), trying the update with the present
        entries and then at most once without the entries to blame. evaluate(entries) runs the update with
        those entries and returns its (nu, S); the last call is the accepted update when one is returned."""
        gated = np.zeros_like(present)
        for _ in range(2):
            nu, S = evaluate(present)
            if self.passes(nu, S, int(present.sum())):
                return present, gated
            with np.errstate(over="ignore", invalid="ignore"):
                outliers = present & ~(nu * nu <= self.thresholds[1] * np.diag(S))  # NaN/inf count as outliers
            if not outliers.any() or outliers.sum() == present.sum():
                break
            gated = gated | outliers
            present = present & ~outliers
        return None, gated | present  # nothing usable is left: the whole measurement is gated

    def note(self, gated: np.ndarray, present: np.ndarray) -> bool:
        """Count the gated entries of an update over `present`; True when P is to be inflated."""
        self.gated += int(gated.sum())
        streak = self._streak
        streak[present & ~gated] = 0
        streak[gated] += 1
        self.streaking = bool(streak.any())
        if gated.any() and streak.max() >= self.patience:
            self.inflations += 1
            return True
        return False

    def accepted_all(self) -> None:
        """A complete measurement passed: every streak ends."""
        if self.streaking:
            self._streak[:] = 0
            self.streaking = False

