"""Kalman-family filters running whole generated filter steps (EKF, UKF, CKF, MCUKF, HuberUKF).

    rov = abyssal.generated.load("rov4dof")
    ckf = CKF(rov, x0, P0, Q, R)
    ckf.predict(tau, dt=0.1)          # x, P <- <m>_ckf_predict(x, P, u, p, dt, Q)
    ckf.update(z)                     # x, P <- <m>_ckf_update(x, P, z, p, R, mask)
    result = ckf.run(U, Z, dt=0.1, truth=X)   # estimates, covariances, NIS, NEES

Contract
--------
* One shape per argument: x0 (n_x,), P0 and Q (n_x, n_x), R (n_y, n_y), u (n_u,), z (n_y,),
  p (n_p,) or None for the model's defaults. Q and R are additive noise covariances; Q is the
  process noise accumulated over one step dt (a caller with noise inputs w can use
  ``process_noise(model, x, u, dt, Qw)`` = G Qw G^T).
* Missing data: ``update(None)`` or an all-NaN z does nothing; NaN entries of z are left out
  (the mask input of the generated update), so measurements may come slower than predictions
  and sensors may drop out one by one.
* predict and update are each one call of one generated C function on preallocated buffers
  bound once in ``__init__`` (``step`` with a complete measurement is one call of the fused
  ``<m>_ekf_step`` / ``<m>_ckf_step`` where generated); results go to a second set of buffers,
  committed by swapping the two sets only when the C function's ``ok`` flag is 1 (every
  Cholesky pivot passed its guard and every output is finite). Finiteness of inputs is
  therefore checked by the compiled code: a NaN or inf in u, p or z reaches the outputs and
  makes ok = 0; only then does the (slow) diagnosis below run. Shapes and dtypes are checked
  on every call (a memoryview assignment; anything but an exact float64 vector takes a
  converting slow path).
* A call that is rejected leaves x and P exactly as they were and raises ValueError naming the
  cause (wrong shape, non-finite input, or a filter that diverged).
* Factorisation guard and repair: when ok = 0 and the inputs are finite, the covariance was not
  numerically positive definite (indefinite after roundoff, or UKF weights that are negative).
  The filter then repairs P: symmetrise, clip its eigenvalues from below at
  ``repair_floor * max(|eigenvalue|)`` (default 1e-10, which makes every pivot pass the C
  guard of 1e-13), and retries once. A successful retry is committed and counted in
  ``repairs``; a failed one raises and leaves the state untouched.
* ``x`` and ``P`` are copies: the filter state cannot be changed from outside except by
  ``reset``.
* Innovation gate (on by default) and recovery from repeated gating: ``InnovationGate``
  (gate.py), the same for every Kalman-type filter: options ``gate_probability`` (default 1e-10;
  0 turns it off), ``gate_patience`` (5) and ``gate_inflation`` (4); an update with every entry
  gated returns False (the predict stands). Counted in ``gated`` and ``inflations``. (Measured on
  rov4dof, CKF, a permanent 25 m jump of the x fix: re-acquired within 5 + 5 updates; see
  tests/runtime/test_kalman.py.)
* dt beyond the model's stable range: the first predict with a dt larger than any seen so far
  is checked for a covariance that grows more than ``growth_limit`` (default 1e3) times
  (max diag P + max diag Q) in one step, or an integration that stops being finite (sigma points
  at high speed make explicit RK4 unstable: rov4dof at dt = 1 s). Such a step is subdivided into
  2, 4, ..., ``max_substeps`` (64) predicts of dt / k, each adding Q k^-1; the k found is kept for
  that dt (``substeps`` counts the subdivided predicts). If even max_substeps fails, the call is
  refused with a message naming the smallest dt tried.
* Everything a refused call would report is restored (x, P, innovation, S, NIS, counters).
* Threads: FilterBase's rule (contract.py): a second thread entering while a call is under way
  is refused with RuntimeError (its call did nothing). Different filters on one bundle share
  nothing mutable and run independently.
* Singular or zero P0: accepted. The EKF runs it as is; the sigma-point filters (no factor of
  a singular matrix) repair it on the first call that fails its Cholesky guard: P0 = 0 becomes
  ``repair_floor`` x max(max |Q|, tiny) x I, the Dirac's nearest Gaussian.

Filters: EKF (Joseph form), UKF (scaled unscented points; alpha, beta, kappa options, default
1, 2, 0; Julier's choice is alpha=1, beta=0, kappa=3-n, Merwe's alpha=1e-3, beta=2, kappa=0),
CKF (third-degree cubature), MCUKF (maximum-correntropy update, kernel bandwidth sigma,
default 15 as in seed 002 Table 6) and HuberUKF (Huber update, gamma default 1.345, 3
iterations fixed at generation). The robust filters predict with the UKF step.
"""
from __future__ import annotations

import math

import numpy as np

from ...contract import FilterBase, FilterResult, check_covariance, check_dt, check_state, real_array, register
from ...numerics import REPAIR_FLOOR, factorable_covariance, grew_beyond, repair_covariance
from abyssal.symbolic.filters.families import FUNCTIONS

from .gate import InnovationGate

__all__ = [
    "CKF", "EKF", "FilterResult", "HuberUKF", "KalmanFilter", "MCUKF", "UKF", "process_noise", "repair_covariance",
]

#: dt types the hot path takes without check_dt (anything else, a bool included, is checked)
_PLAIN_NUMBERS = frozenset({float, int, np.float64})


def process_noise(model, x, u, dt, Qw, p=None) -> np.ndarray:
    """G Qw G^T: the additive state covariance of a noise input with covariance Qw held over dt."""
    G = model.G(x, u, p, dt)
    Q = G @ check_covariance(Qw, model.n_w, "Qw") @ G.T
    return (Q + Q.T) / 2


def _matrix(value, shape, name, *, definite: bool) -> np.ndarray:
    return check_covariance(value, shape[0], name, definite=definite)


def _vector(value, n, name) -> np.ndarray:
    v = real_array(value, name)
    if v.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {v.shape}")
    return v


class KalmanFilter(FilterBase):
    """Shared runtime of the generated Kalman-family steps; see the module docstring.

    Subclasses name the generated functions and their extra trailing inputs (e.g. abk, sigma).
    """

    predict_function: str = ""
    update_function: str = ""
    #: generated predict + update in one call, used by step() when a measurement is given (optional)
    step_function: str | None = None
    #: S = (predicted measurement covariance) + R with a positive semi-definite first term, so
    #: nu^T R^-1 nu bounds the NIS from above (true for the EKF and the CKF's positive weights)
    S_dominates_R: bool = False
    _state = ("_cur", "_x", "_P", "_last_update", "_last_dof", "_innovation", "_S", "repairs", "substeps", "gate")

    def __init__(self, model, x0, P0, Q, R, *, repair_floor: float = REPAIR_FLOOR, gate_probability: float = 1e-10,
                 gate_patience: int = 5, gate_inflation: float = 4.0, growth_limit: float = 1e3, max_substeps: int = 64):
        if not hasattr(model, "functions") or self.predict_function not in model.functions:
            raise TypeError(
                f"{type(self).__name__} needs a model bundle from abyssal.generated.load() with generated "
                f"{self.predict_function!r}; got {model!r}"
            )
        if not (growth_limit > 1.0 and int(max_substeps) >= 1):
            raise ValueError(f"growth_limit > 1 and max_substeps >= 1 are required, got {growth_limit!r}, {max_substeps!r}")
        self._init_contract(model)
        n, m = model.n_x, model.n_y
        self.repair_floor = float(repair_floor)
        #: number of covariance repairs (eigenvalue clipping) performed so far
        self.repairs = 0
        #: predicts subdivided because dt was beyond the model's stable range
        self.substeps = 0
        self.growth_limit, self.max_substeps = float(growth_limit), int(max_substeps)
        self._checked_dt = 0.0  # predicts with dt up to this passed the stability check
        self._dt_pieces: dict[float, int] = {}  # dt -> number of substeps found stable
        x0 = check_state(x0, n, "x0")
        P0 = _matrix(P0, (n, n), "P0", definite=False)
        # Two state buffer sets: the current one and the one a step writes into.
        self._x = [np.array(x0), np.zeros(n)]
        self._P = [np.asfortranarray(P0), np.zeros((n, n), order="F")]
        self._cur = 0
        self._u = np.zeros(model.n_u)
        self._dt = np.zeros(1)
        self._Q = _matrix(Q, (n, n), "Q", definite=False)
        self._R = _matrix(R, (m, m), "R", definite=True)
        self.gate = InnovationGate(self._R, probability=gate_probability, patience=gate_patience, inflation=gate_inflation,
                                   S_dominates_R=self.S_dominates_R)
        self._z = np.zeros(m)
        self._mask = np.ones(m)
        self._ok = np.zeros(1)
        self._innovation = [np.zeros(m), np.zeros(m)]
        self._S = [np.eye(m, order="F"), np.eye(m, order="F")]
        self._last_update = -1  # which innovation/S buffer holds the last accepted update, -1: none
        self._last_dof = 0
        self._n_y = m
        predict_fn = model.function(self.predict_function)
        update_fn = model.function(self.update_function)
        pe, ue = self._predict_extra(), self._update_extra()
        # _predict[k] reads buffer set k and writes set 1 - k; likewise _update. The Binding objects own
        # the C-side buffer objects: keep them for the filter's lifetime, call their bound eval.
        self._bindings = [
            predict_fn.bind([self._x[k], self._P[k], self._u, self._p, self._dt, self._Q, *pe],
                            [self._x[1 - k], self._P[1 - k], self._ok])
            for k in (0, 1)
        ] + [
            update_fn.bind([self._x[k], self._P[k], self._z, self._p, self._R, self._mask, *ue],
                           [self._x[1 - k], self._P[1 - k], self._innovation[1 - k], self._S[1 - k], self._ok])
            for k in (0, 1)
        ]
        self._c_predict = [b.eval for b in self._bindings[:2]]
        self._c_update = [b.eval for b in self._bindings[2:]]
        self._c_step = None
        if self.step_function in model.functions:
            step_fn = model.function(self.step_function)
            self._bindings += [
                step_fn.bind([self._x[k], self._P[k], self._u, self._p, self._dt, self._Q, self._z, self._R, self._mask, *ue],
                             [self._x[1 - k], self._P[1 - k], self._innovation[1 - k], self._S[1 - k], self._ok])
                for k in (0, 1)
            ]
            self._c_step = [b.eval for b in self._bindings[4:]]
        # memoryviews: the cheapest way to move a few floats in and out on the hot path. The slice
        # assignment view[:] = u takes u's buffer directly (no memoryview(u) object to build: about
        # half the cost) and checks that u is exactly a float64 vector of the right length: another
        # format or shape raises ValueError, an object without a buffer (list, scalar) TypeError.
        self._u_view, self._z_view = memoryview(self._u), memoryview(self._z)
        self._dt_view, self._ok_view = memoryview(self._dt), memoryview(self._ok)

    # -------------------------------------------------------------- extension points
    def _predict_extra(self) -> list[np.ndarray]:
        return []

    def _update_extra(self) -> list[np.ndarray]:
        return []

    # -------------------------------------------------------------- state
    @property
    def x(self) -> np.ndarray:
        """Current state estimate (a copy)."""
        return self._x[self._cur].copy()

    @property
    def P(self) -> np.ndarray:
        """Current state covariance (a copy)."""
        return self._P[self._cur].copy()

    @property
    def Q(self) -> np.ndarray:
        return self._Q.copy()

    @Q.setter
    def Q(self, value) -> None:
        Q = _matrix(value, self._Q.shape, "Q", definite=False)
        self._with_lock(lambda: self._Q.__setitem__(Ellipsis, Q))

    @property
    def R(self) -> np.ndarray:
        return self._R.copy()

    @R.setter
    def R(self, value) -> None:
        R = _matrix(value, self._R.shape, "R", definite=True)

        def change():
            self._R[...] = R
            self.gate.set_R(R)
        self._with_lock(change)

    def reset(self, x, P) -> None:
        """Replace the state (checked like x0 and P0)."""
        n = self.model.n_x
        x = check_state(x, n, "x")
        P = _matrix(P, (n, n), "P", definite=False)
        self._with_lock(lambda: (self._x[self._cur].__setitem__(slice(None), x),
                                 self._P[self._cur].__setitem__(Ellipsis, P)))

    def _with_lock(self, change) -> None:
        if not self._lock.acquire(False):
            raise self._busy()
        try:
            change()
        finally:
            self._lock.release()

    @property
    def innovation(self) -> np.ndarray | None:
        """Innovation of the last accepted update (0 on unused entries), or None."""
        return None if self._last_update < 0 else self._innovation[self._last_update].copy()

    @property
    def S(self) -> np.ndarray | None:
        """Innovation covariance of the last accepted update (identity rows on unused entries), or None."""
        return None if self._last_update < 0 else self._S[self._last_update].copy()

    @property
    def nis(self) -> float:
        """Normalised innovation squared nu^T S^-1 nu of the last accepted update (NaN if none)."""
        if self._last_update < 0:
            return math.nan
        nu = self._innovation[self._last_update]
        return float(nu @ np.linalg.solve(self._S[self._last_update], nu))

    @property
    def nis_dof(self) -> int:
        """Measurement entries used by the last accepted update (0 if none)."""
        return 0 if self._last_update < 0 else self._last_dof

    @property
    def gated(self) -> int:
        """Measurement entries left out by the innovation gate so far."""
        return self.gate.gated

    @property
    def inflations(self) -> int:
        """Covariance inflations after gate_patience consecutive gated updates of an entry."""
        return self.gate.inflations

    def _counters(self):
        return self.repairs, self.substeps, self.gate.checkpoint()

    def _set_counters(self, counters) -> None:
        self.repairs, self.substeps, gate = counters
        self.gate.restore(gate)

    # -------------------------------------------------------------- the contract's calls (FilterBase holds the lock)
    def _step_call(self, u, dt, z, p) -> bool:
        fused = self._c_step  # hot path: every attribute is read once (each read costs ~15-20 ns)
        if z is None:
            self._predict_call(u, dt, p)
            return False
        if fused is None:
            return self._predict_then_update(u, dt, z, p)
        try:  # exact float64 vectors of the right length only (see __init__), else predict then update
            self._u_view[:] = u
            self._z_view[:] = z
        except (TypeError, ValueError):
            return self._predict_then_update(u, dt, z, p)
        # dt invalid, not a plain number (a bool is refused by check_dt), or larger than any checked
        careful = type(dt) not in _PLAIN_NUMBERS or not 0.0 < dt <= self._checked_dt
        if careful:
            return self._predict_then_update(u, dt, z, p)
        if p is not None or not self._p_is_default:
            self._set_p(p)
        self._dt_view[0] = dt
        cur = self._cur
        saved = None if self._last_update != 1 - cur else self._save_report(cur)
        fused[cur]()
        if self._ok_view[0] != 1.0 or not self.gate.passes(self._innovation[1 - cur], self._S[1 - cur], self._n_y):
            self._restore_report(cur, saved)
            return self._predict_then_update(u, dt, z, p)
        self._cur = self._last_update = 1 - cur
        self._last_dof = self._n_y
        if self.gate.streaking:
            self.gate.accepted_all()
        return True

    # -------------------------------------------------------------- steps
    def _set_p(self, p) -> None:
        """FilterBase's, on an unchecked p (the hot path checks it here)."""
        if p is not None:
            if type(p) is not np.ndarray or p.shape != self._p.shape or p.dtype != np.float64:
                p = _vector(p, self.model.n_p, "p")
            if not np.isfinite(p).all():
                raise ValueError(f"p has non-finite entries {p}")
        FilterBase._set_p(self, p)

    def _save_report(self, cur: int):
        """The reported innovation/S when the next evaluation would overwrite them (else None)."""
        if self._last_update == 1 - cur:
            return self._innovation[1 - cur].copy(), self._S[1 - cur].copy()
        return None

    def _restore_report(self, cur: int, saved) -> None:
        if saved is not None:
            self._innovation[1 - cur][:] = saved[0]
            self._S[1 - cur][...] = saved[1]

    def _predict_call(self, u, dt, p) -> None:
        """Checks, then the predict (subdivided when dt is beyond the stable range)."""
        try:  # memoryview assignment: an exact (n_u,) float64 match, else the checked slow path
            self._u_view[:] = u
        except (TypeError, ValueError):
            self._u[...] = _vector(u, self.model.n_u, "u")
        checked = type(dt) in _PLAIN_NUMBERS and 0.0 < dt <= self._checked_dt
        if not checked:
            dt = check_dt(dt)
        p_saved = None
        if p is not None or not self._p_is_default:
            p_saved = (self._p.copy(), self._p_is_default)
            self._set_p(p)
        try:
            if dt <= self._checked_dt:
                self._predict_once(dt)
            else:
                self._predict_checking_stability(dt)
        except BaseException:
            if p_saved is not None:
                self._p[:], self._p_is_default = p_saved
            raise

    def _predict_once(self, dt: float) -> None:
        self._dt_view[0] = dt
        cur = self._cur
        self._c_predict[cur]()
        if self._ok_view[0] != 1.0:
            self._recover(self._c_predict[cur], "predict", {"u": self._u, "p": self._p})
        self._cur = 1 - cur

    def _stable(self, cur: int) -> bool:
        """The predict just written to set 1 - cur did not blow up (see the module docstring)."""
        return self._ok[0] == 1.0 and not grew_beyond(self.growth_limit, self._P[cur], self._P[1 - cur], self._Q)

    def _predict_checking_stability(self, dt: float) -> None:
        """A dt larger than any checked: predict in k = 1, 2, 4, ... pieces until every piece is stable."""
        cur0, x0, P0 = self._cur, self._x[self._cur].copy(), self._P[self._cur].copy()
        Q = self._Q.copy()
        pieces = self._dt_pieces.get(dt, 1)
        while pieces <= self.max_substeps:
            ok = True
            self._Q[...] = Q / pieces
            try:
                for _ in range(pieces):
                    self._dt_view[0] = dt / pieces
                    cur = self._cur
                    self._c_predict[cur]()
                    if self._ok[0] != 1.0:
                        for name, value in (("u", self._u), ("p", self._p)):
                            if not np.all(np.isfinite(value)):
                                raise ValueError(f"{type(self).__name__}.predict: {name} has non-finite entries {value}")
                        if pieces == 1:  # maybe only a covariance to repair
                            try:
                                self._recover(self._c_predict[cur], "predict", {})
                            except ValueError:
                                pass
                    if not self._stable(cur):
                        ok = False
                        break
                    self._cur = 1 - cur
            finally:
                self._Q[...] = Q
            if ok:
                if pieces == 1:
                    self._checked_dt = dt
                else:
                    self._dt_pieces[dt] = pieces
                    self.substeps += 1
                return
            self._cur = cur0  # start again from the state before this predict
            self._x[cur0][:] = x0
            self._P[cur0][...] = P0
            pieces *= 2
        raise ValueError(
            f"{type(self).__name__}.predict: dt = {dt!r} s: the step blew up even in {self.max_substeps} substeps of "
            f"{dt / self.max_substeps:.3g} s (the covariance grew more than {self.growth_limit:g}x in one substep, or the "
            "integration overflowed): either the filter diverged, or dt is beyond the model's stable range at this "
            "state (the stable limit is below that substep). State left unchanged.")

    def _update_call(self, z, p) -> bool:
        if z is None:
            if p is not None:  # nothing to update, but a bad p is still refused
                p = _vector(p, self.model.n_p, "p")
                if not np.isfinite(p).all():
                    raise ValueError(f"p has non-finite entries {p}")
            return False
        try:
            self._z_view[:] = z
        except (TypeError, ValueError):
            self._z[...] = _vector(z, self.model.n_y, "z")
        p_saved = None
        if p is not None or not self._p_is_default:
            p_saved = (self._p.copy(), self._p_is_default)
            self._set_p(p)
        cur = self._cur
        saved = self._save_report(cur)
        counters = self._counters()
        try:
            self._c_update[cur]()
            if self._ok_view[0] == 1.0 and self.gate.passes(self._innovation[1 - cur], self._S[1 - cur], self._n_y):
                self._cur = self._last_update = 1 - cur
                self._last_dof = self._n_y
                if self.gate.streaking:
                    self.gate.accepted_all()
                return True
            if self._update_slow_path(cur):
                return True
            self._restore_report(cur, saved)  # nothing was committed: the report is as it was
            return False
        except BaseException:
            self._restore_report(cur, saved)
            self._set_counters(counters)
            self._cur = cur
            if p_saved is not None:
                self._p[:], self._p_is_default = p_saved
            raise

    def _update_slow_path(self, cur: int) -> bool:
        """ok was 0 or the gate failed: leave out NaN entries, refuse infinite ones, repair P if needed,
        gate entry by entry (gate.py)."""
        if np.any(np.isinf(self._z)):
            raise ValueError(f"z has infinite entries {self._z}; use NaN for a missing entry")
        present = np.isfinite(self._z)
        if not present.any():
            return False
        z = self._z.copy()

        def evaluate(entries):
            self._mask[:] = entries
            self._z[~entries] = 0.0
            self._c_update[cur]()
            if self._ok[0] != 1.0:
                self._recover(self._c_update[cur], "update", {"z": self._z, "p": self._p})
            return self._innovation[1 - cur], self._S[1 - cur]

        try:
            accepted, gated = self.gate.select(evaluate, present)
        finally:
            self._mask[:] = 1.0
            self._z[:] = z
        if accepted is not None:
            self._cur = self._last_update = 1 - cur
            self._last_dof = int(accepted.sum())
        if self.gate.note(gated, present):
            self._P[self._cur] *= self.gate.inflation
        return accepted is not None

    def _predict_then_update(self, u, dt, z, p) -> bool:
        """predict then update; a refused update (which restores its own reports, counters and p)
        also undoes the predict."""
        cur, x, P = self._cur, self._x[self._cur].copy(), self._P[self._cur].copy()
        counters = self._counters()
        self._predict_call(u, dt, p)
        try:
            return self._update_call(z, p)
        except BaseException:
            self._cur = cur
            self._x[cur][:] = x
            self._P[cur][...] = P
            self._set_counters(counters)  # a subdivided or repaired predict is undone too
            raise

    def _recover(self, evaluate, what: str, inputs: dict) -> None:
        """The step's ok flag was 0: name a bad input, or repair P and retry once, or raise."""
        for name, value in inputs.items():
            if not np.all(np.isfinite(value)):
                raise ValueError(f"{type(self).__name__}.{what}: {name} has non-finite entries {value}")
        P = self._P[self._cur]
        if not np.all(np.isfinite(P)) or not np.all(np.isfinite(self._x[self._cur])):
            raise ValueError(f"{type(self).__name__}.{what}: the filter state is not finite")
        saved = P.copy()
        P[...] = factorable_covariance(saved, self._Q, self.repair_floor)
        evaluate()
        if self._ok[0] != 1.0:
            P[...] = saved
            raise ValueError(
                f"{type(self).__name__}.{what}: the generated step failed (non-finite outputs or a covariance that "
                "is not positive definite) even after repairing P; the filter diverged or Q, R, dt do not suit the "
                "model. State left unchanged."
            )
        self.repairs += 1


@register("kalman")
class EKF(KalmanFilter):
    """Extended Kalman filter: <m>_ekf_predict / <m>_ekf_update (Joseph form)."""

    S_dominates_R = True
    predict_function, update_function, step_function = (FUNCTIONS["ekf"][r] for r in ("predict", "update", "step"))


@register("kalman")
class CKF(KalmanFilter):
    """Cubature Kalman filter (third-degree spherical-radial rule, 2n points)."""

    S_dominates_R = True
    predict_function, update_function, step_function = (FUNCTIONS["ckf"][r] for r in ("predict", "update", "step"))


@register("kalman")
class UKF(KalmanFilter):
    """Unscented Kalman filter with scaled sigma points (alpha, beta, kappa)."""

    predict_function, update_function = FUNCTIONS["ukf"]["predict"], FUNCTIONS["ukf"]["update"]

    def __init__(self, model, x0, P0, Q, R, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0, **options):
        n = model.n_x
        if not all(math.isfinite(v) for v in (alpha, beta, kappa)) or not alpha**2 * (n + kappa) > 0:
            raise ValueError(f"sigma points need finite alpha, beta, kappa with alpha^2 (n + kappa) > 0 (n = {n})")
        self._abk = np.array([alpha, beta, kappa], dtype=np.float64)
        lam = alpha**2 * (n + kappa) - n
        # non-negative covariance weights make the predicted measurement covariance PSD, so S >= R
        self.S_dominates_R = type(self) is UKF and lam / (n + lam) + 1 - alpha**2 + beta >= 0 and n + lam > 0
        super().__init__(model, x0, P0, Q, R, **options)

    def _predict_extra(self):
        return [self._abk]

    def _update_extra(self):
        return [self._abk]


@register("kalman")
class MCUKF(UKF):
    """UKF with the maximum-correntropy update of seed 002 (eqs. 36-39), kernel bandwidth sigma."""

    update_function = FUNCTIONS["robust"]["mcc_update"]

    def __init__(self, model, x0, P0, Q, R, *, sigma: float = 15.0, **options):
        if not sigma > 0:
            raise ValueError(f"kernel bandwidth sigma must be > 0 (inf gives the plain UKF), got {sigma!r}")
        self._sigma = np.array([sigma], dtype=np.float64)
        super().__init__(model, x0, P0, Q, R, **options)

    def _update_extra(self):
        return [self._abk, self._sigma]


@register("kalman")
class HuberUKF(UKF):
    """UKF with a Huber M-estimation update (gamma = 1.345, 3 IRLS iterations; HRUKF of seed 002)."""

    update_function = FUNCTIONS["robust"]["huber_update"]

    def __init__(self, model, x0, P0, Q, R, *, gamma: float = 1.345, **options):
        if not gamma > 0:
            raise ValueError(f"Huber threshold gamma must be > 0 (inf gives the plain UKF), got {gamma!r}")
        self._gamma = np.array([gamma], dtype=np.float64)
        super().__init__(model, x0, P0, Q, R, **options)

    def _update_extra(self):
        return [self._abk, self._gamma]
