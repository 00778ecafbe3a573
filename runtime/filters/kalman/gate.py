"""The innovation gate of every Kalman-type filter (the engine's EKF/UKF/CKF/robust UKFs, GP-UKF, IVBCKF).

    gate = InnovationGate(R, probability=1e-10, patience=5, inflation=4.0, max_inflations=10)
    accepted, gated = gate.select(evaluate, present)   # evaluate(present) -> (nu, S) of that update
    P = gate.inflated(P, gated, present, accepted, reduction)   # reduction(entries) -> P_prior - P_post over them

After an update, the NIS of the present entries is compared with the chi-square quantile of tail
probability ``probability`` (1e-10: a consistent filter gates a measurement once in 10^10 updates;
0 turns the gate off). When it fails, the entries whose own normalised innovation nu_i^2 / S_ii
exceeds the one-degree quantile are left out and the update is redone with the rest (which must
pass too); when no single entry is to blame, the whole measurement is left out. An entry gated in
``patience`` consecutive updates means the filter, not the sensor, is probably wrong (a jump it
cannot follow): each further update that gates it inflates P, at most ``max_inflations`` times per
streak (beyond that the entry is held as rejected: gated and counted, P left alone, until it passes;
inflation, not a reset: a reset returns to the state the filter could not follow). Which P is inflated
is the Kalman runtime's rule (abyssal_kalman.h): when entries were accepted while the streak ran, the
filter follows them and the gated entries are stuck or lost, so P grows only along what they measure,
P += (inflation - 1) Pxz Pzz^-1 Pxz^T over the gated entries at the prior, which is P_prior - P_post of
the update with those entries alone (the filter's ``reduction``: no cross-covariance needed from it);
when nothing was accepted during the streak the filter itself is probably wrong and the whole P is
multiplied by ``inflation``. (Inflating the whole P for one stuck entry was the rule here before: on
rov4dof after a 100-step outage, an x fix 2 m off a 0.08 m standard deviation inflated the heading with
it to tens of radians, beyond what a wrapped compass can pull back, and the IVBCKF never recovered.)
A filter whose predict forgets P (``along=False``: the GP-UKF, whose learned prediction reverts to the GPs'
own variance away from their training data, so P grown along one entry is gone by the next predict)
always inflates the whole P. ``gated`` counts the entries left out, ``inflations`` the inflations done,
``held`` the ones refused by the cap.

One implementation: the rule is C (runtime/c/abyssal_kalman_gate.c: the quantiles, the NIS by a Cholesky
factor of S, the selection's rounds, the streaks); this class holds a gate object in a NumPy buffer and calls
it, as the Kalman runtime does from C inside every EKF/UKF/CKF step. The NIS is computed exactly (a guarded
Cholesky factor of S, +inf when S is not positive definite or the value overflows): in C it costs less than
any bound. The inflation's choice (``inflated``: the cap, along or whole) is written twice: here per gate for
the filters that call this class, and in abyssal_kalman.c per sensor (its records); tests/runtime/test_gate.py
holds every Kalman filter to the same outcome on a stuck entry.

Conventions of the generated updates: nu is (m,) with 0 on unused entries and S (m, m) with
identity rows there, so a NIS over all rows is the NIS of the present ones.
"""
from __future__ import annotations

import numpy as np

from abyssal.runtime.compiled import kalman as kr

from ...contract import Stateful

__all__ = ["InnovationGate"]

_ACCEPT, _RETRY, _REJECT = 0, 1, 2


class InnovationGate(Stateful):
    """Chi-square innovation gate with entry-wise outlier rejection and recovery by inflation (module docstring).

    R: the measurement covariance (its size m is the gate's; the gate needs no more of it).
    """

    _state = ("_block", "_streak_inflations", "_accepted_in_streak", "held")

    def __init__(self, R: np.ndarray, *, probability: float = 1e-10, patience: int = 5, inflation: float = 4.0,
                 max_inflations: int = 10, along: bool = True):
        runtime = kr.KalmanRuntime.standalone()
        m = int(np.shape(R)[0])
        size = runtime.gate_size(m)
        memory = np.zeros(size // 8)
        code = runtime.gate_init(memory.ctypes.data, size, m, float(probability), int(patience), float(inflation), None)
        if code != 0 or type(max_inflations) is not int or max_inflations < 0:
            raise ValueError(f"gate_probability must be in [0, 1) (0: no gate), gate_patience >= 1, 1 <= gate_inflation "
                             f"< inf and an integer gate_max_inflations >= 0 are required, got gate_probability="
                             f"{probability!r}, gate_patience={patience!r}, gate_inflation={inflation!r}, "
                             f"gate_max_inflations={max_inflations!r}")
        self._attach(runtime, memory, 0)
        self.max_inflations, self.along = max_inflations, bool(along)

    @classmethod
    def over(cls, memory: np.ndarray, offset: int) -> "InnovationGate":
        """The gate object at byte `offset` of `memory` (a Kalman filter's), without copying it."""
        gate = cls.__new__(cls)
        gate._attach(kr.KalmanRuntime.standalone(), memory, offset)
        return gate

    def _attach(self, runtime, memory: np.ndarray, offset: int) -> None:
        header = kr.GateHeader.from_buffer(memory, offset)
        self._runtime, self._memory, self._address = runtime, memory, memory.ctypes.data + offset
        self._m = header.m
        self.probability, self.patience, self.inflation = header.probability, header.patience, header.inflation
        self._block = np.frombuffer(memory, np.float64, header.bytes // 8, offset)
        #: chi-square quantiles, index = degrees of freedom (inf: gate off); a view of the C gate's
        self.thresholds = np.frombuffer(memory, np.float64, self._m + 1, offset + header.thresholds)
        self._counters = {name: np.frombuffer(memory, np.int64, 1, offset + getattr(kr.GateHeader, name).offset)
                          for name in ("gated", "inflations", "streaking")}
        self._scratch = np.zeros(self._m * self._m + self._m)
        self._nis = np.zeros(1)
        self.max_inflations, self.along = 10, True
        self._streak_inflations = 0        # inflations since the entries' streak began
        self._accepted_in_streak = False   # whether some entry was accepted since then
        #: inflations the cap refused (entries held as rejected)
        self.held = 0

    @property
    def gated(self) -> int:
        """Measurement entries left out so far."""
        return int(self._counters["gated"][0])

    @property
    def inflations(self) -> int:
        """Covariance inflations after `patience` consecutive gated updates of an entry (those done: asked for less
        held)."""
        return int(self._counters["inflations"][0]) - self.held

    @property
    def streaking(self) -> bool:
        """Whether some entry has been gated in its last update(s)."""
        return bool(self._counters["streaking"][0])

    def _vectors(self, nu, S):
        nu = np.ascontiguousarray(nu, dtype=np.float64)
        S = np.asfortranarray(S, dtype=np.float64)
        if nu.shape != (self._m,) or S.shape != (self._m, self._m):
            raise ValueError(f"nu must be ({self._m},) and S ({self._m}, {self._m}), got {nu.shape} and {S.shape}")
        return nu, S

    def nis(self, nu: np.ndarray, S: np.ndarray) -> float:
        """nu^T S^-1 nu by a Cholesky factor of S (+inf when S is not positive definite or it overflows)."""
        nu, S = self._vectors(nu, S)
        return float(self._runtime.nis(self._m, nu.ctypes.data, S.ctypes.data, self._scratch.ctypes.data))

    def passes(self, nu: np.ndarray, S: np.ndarray, dof: int) -> bool:
        """Whether an update with innovation nu and covariance S over dof entries passes."""
        threshold = self.thresholds[dof]
        return bool(threshold == np.inf or self.nis(nu, S) <= threshold)

    def select(self, evaluate, present: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
        """(the entries of the accepted update or None, the entries gated), trying the update with the present
        entries and then at most once without the entries to blame. evaluate(entries) runs the update with
        those entries and returns its (nu, S); the last call is the accepted update when one is returned."""
        present = np.array(present, dtype=bool)
        gated = np.zeros(self._m, dtype=bool)
        for round_ in range(2):
            nu, S = self._vectors(*evaluate(present.copy()))
            verdict = self._runtime.gate_judge(self._address, round_, nu.ctypes.data, S.ctypes.data, present.ctypes.data,
                                               gated.ctypes.data, self._nis.ctypes.data, self._scratch.ctypes.data)
            if verdict == _ACCEPT:
                return present, gated
            if verdict == _REJECT:
                break
        return None, gated

    def note(self, gated: np.ndarray, present: np.ndarray) -> bool:
        """Count the gated entries of an update over `present`; True when P is to be inflated."""
        gated = np.ascontiguousarray(gated, dtype=bool)
        present = np.ascontiguousarray(present, dtype=bool)
        return bool(self._runtime.gate_note(self._address, gated.ctypes.data, present.ctypes.data))

    def inflated(self, P: np.ndarray, gated: np.ndarray, present: np.ndarray, accepted: np.ndarray | None,
                 reduction) -> np.ndarray:
        """Count an update's gated entries (note) and return P after the rule's inflation (module docstring): P
        itself when there is none. `accepted`: the entries the update used (None: none); reduction(entries) ->
        P_prior - P_post of the update over those entries alone at the prior (called only to inflate along them).
        An inflation whose result is not finite is not done."""
        gated = np.ascontiguousarray(gated, dtype=bool)
        present = np.ascontiguousarray(present, dtype=bool)
        if not self.streaking:  # a streak begins with this update (if any entry is gated)
            self._accepted_in_streak = False
        self._accepted_in_streak |= accepted is not None and bool(accepted.any())
        ask = self.note(gated, present)
        if not self.streaking:  # every entry's streak has ended: so has the count of its inflations
            self._streak_inflations = 0
        if not ask:
            return P
        if self._streak_inflations >= self.max_inflations:
            self.held += 1
            return P
        self._streak_inflations += 1
        if self._accepted_in_streak and self.along:
            grown = P + (self.inflation - 1.0) * np.asarray(reduction(gated & present))
            grown = 0.5 * (grown + grown.T)
        else:
            grown = P * self.inflation
        if not np.all(np.isfinite(grown)):
            self.held += 1
            return P
        return grown

    def accepted_all(self) -> None:
        """A complete measurement passed: every streak ends."""
        self._runtime.gate_accepted_all(self._address)
