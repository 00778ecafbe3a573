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

Filters: EKF (Joseph form), UKF (scaled unscented points; alpha, beta, kappa options, default
1, 2, 0; Julier's choice is alpha=1, beta=0, kappa=3-n, Merwe's alpha=1e-3, beta=2, kappa=0),
CKF (third-degree cubature), MCUKF (maximum-correntropy update, kernel bandwidth sigma,
default 15 as in seed 002 Table 6) and HuberUKF (Huber update, gamma default 1.345, 3
iterations fixed at generation). The robust filters predict with the UKF step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "CKF", "EKF", "FilterResult", "HuberUKF", "KalmanFilter", "MCUKF", "UKF", "process_noise", "repair_covariance",
]

SYMMETRY_TOLERANCE = 1e-9  # relative: |A - A^T| <= tol * max|A|
_INF = math.inf  # hot path: one global lookup instead of a global and an attribute lookup


def repair_covariance(P: np.ndarray, floor: float = 1e-10) -> np.ndarray:
    """Nearest-in-spectrum symmetric positive definite matrix: eigenvalues clipped at floor * max|eig|."""
    A = (P + P.T) / 2
    eigenvalues, vectors = np.linalg.eigh(A)
    scale = max(float(np.max(np.abs(eigenvalues))), np.finfo(float).tiny)
    clipped = np.maximum(eigenvalues, floor * scale)
    B = (vectors * clipped) @ vectors.T
    return np.asfortranarray((B + B.T) / 2)


def process_noise(model, x, u, dt, Qw, p=None) -> np.ndarray:
    """G Qw G^T: the additive state covariance of a noise input with covariance Qw held over dt."""
    G = model.G(x, u, p, dt)
    Q = G @ np.asarray(Qw, dtype=np.float64) @ G.T
    return (Q + Q.T) / 2


def _matrix(value, shape, name, *, definite: bool) -> np.ndarray:
    """A checked covariance: finite, the right shape, symmetric, positive (semi-)definite."""
    A = np.array(value, dtype=np.float64)
    if A.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError(f"{name} has non-finite entries")
    scale = float(np.max(np.abs(A))) if A.size else 0.0
    if np.max(np.abs(A - A.T), initial=0.0) > SYMMETRY_TOLERANCE * scale:
        raise ValueError(f"{name} is not symmetric (max |{name} - {name}^T| = {np.max(np.abs(A - A.T)):.3g})")
    A = (A + A.T) / 2
    eigenvalues = np.linalg.eigvalsh(A)
    if definite and not eigenvalues[0] > 0:
        raise ValueError(f"{name} must be positive definite; smallest eigenvalue {eigenvalues[0]:.3g}")
    if not definite and eigenvalues[0] < -SYMMETRY_TOLERANCE * scale:
        raise ValueError(f"{name} must be positive semi-definite; smallest eigenvalue {eigenvalues[0]:.3g}")
    return np.asfortranarray(A)


def _vector(value, n, name) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {v.shape}")
    return v


@dataclass(frozen=True)
class FilterResult:
    """Output of ``run`` over T steps (step k: predict with U[k], then update with Z[k])."""

    x: np.ndarray                  # (T, n_x) estimates after step k
    P: np.ndarray                  # (T, n_x, n_x) covariances after step k
    nis: np.ndarray                # (T,) normalised innovation squared, NaN where no update
    nis_dof: np.ndarray            # (T,) measurement entries used (the chi-square degrees of freedom)
    nees: np.ndarray | None = None  # (T,) normalised estimation error squared, when truth is given

    def rmse(self, truth: np.ndarray) -> np.ndarray:
        """Root-mean-square error per state against truth (T, n_x)."""
        return np.sqrt(np.mean((np.asarray(truth) - self.x) ** 2, axis=0))


class KalmanFilter:
    """Shared runtime of the generated Kalman-family steps; see the module docstring.

    Subclasses name the generated functions and their extra trailing inputs (e.g. abk, sigma).
    """

    predict_function: str = ""
    update_function: str = ""
    #: generated predict + update in one call, used by step() when a measurement is given (optional)
    step_function: str | None = None

    def __init__(self, model, x0, P0, Q, R, *, repair_floor: float = 1e-10):
        if not hasattr(model, "functions") or self.predict_function not in model.functions:
            raise TypeError(
                f"{type(self).__name__} needs a model bundle from abyssal.generated.load() with generated "
                f"{self.predict_function!r}; got {model!r}"
            )
        self.model = model
        n, m = model.n_x, model.n_y
        self.repair_floor = float(repair_floor)
        #: number of covariance repairs (eigenvalue clipping) performed so far
        self.repairs = 0
        x0 = _vector(x0, n, "x0")
        if not np.all(np.isfinite(x0)):
            raise ValueError("x0 has non-finite entries")
        P0 = _matrix(P0, (n, n), "P0", definite=False)
        # Two state buffer sets: the current one and the one a step writes into.
        self._x = [np.array(x0), np.zeros(n)]
        self._P = [np.asfortranarray(P0), np.zeros((n, n), order="F")]
        self._cur = 0
        self._u = np.zeros(model.n_u)
        self._p = np.array(model.p_default)
        self._p_is_default = True
        self._dt = np.zeros(1)
        self._Q = _matrix(Q, (n, n), "Q", definite=False)
        self._R = _matrix(R, (m, m), "R", definite=True)
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
        self._predict = [b.eval for b in self._bindings[:2]]
        self._update = [b.eval for b in self._bindings[2:]]
        self._step = None
        if self.step_function in model.functions:
            step_fn = model.function(self.step_function)
            self._bindings += [
                step_fn.bind([self._x[k], self._P[k], self._u, self._p, self._dt, self._Q, self._z, self._R, self._mask, *ue],
                             [self._x[1 - k], self._P[1 - k], self._innovation[1 - k], self._S[1 - k], self._ok])
                for k in (0, 1)
            ]
            self._step = [b.eval for b in self._bindings[4:]]
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
        self._Q[...] = _matrix(value, self._Q.shape, "Q", definite=False)

    @property
    def R(self) -> np.ndarray:
        return self._R.copy()

    @R.setter
    def R(self, value) -> None:
        self._R[...] = _matrix(value, self._R.shape, "R", definite=True)

    def reset(self, x, P) -> None:
        """Replace the state (checked like x0 and P0)."""
        n = self.model.n_x
        x = _vector(x, n, "x")
        if not np.all(np.isfinite(x)):
            raise ValueError("x has non-finite entries")
        P = _matrix(P, (n, n), "P", definite=False)
        self._x[self._cur][:] = x
        self._P[self._cur][...] = P

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

    # -------------------------------------------------------------- steps
    def _set_p(self, p) -> None:
        if p is None:
            if not self._p_is_default:
                self._p[:] = self.model.p_default
                self._p_is_default = True
            return
        if type(p) is not np.ndarray or p.shape != self._p.shape:
            p = _vector(p, self.model.n_p, "p")
        self._p[:] = p
        self._p_is_default = False

    def predict(self, u, dt: float, p=None) -> None:
        """x, P <- the generated predict step over dt with input u (and parameters p)."""
        if p is not None or not self._p_is_default:
            self._set_p(p)
        try:  # memoryview assignment: an exact (n_u,) float64 match, else the checked slow path
            self._u_view[:] = u
        except (TypeError, ValueError):
            self._u[...] = _vector(u, self.model.n_u, "u")
        if not 0.0 < dt < _INF:
            raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
        self._dt_view[0] = dt
        cur = self._cur
        self._predict[cur]()
        if self._ok_view[0] != 1.0:
            self._recover(self._predict[cur], "predict", {"u": self._u, "p": self._p})
        self._cur = 1 - cur

    def update(self, z, p=None) -> bool:
        """x, P <- the generated update with measurement z; NaN entries are left out.

        Returns False (and changes nothing) when z is None or has no finite entry.
        """
        if z is None:
            return False
        if p is not None or not self._p_is_default:
            self._set_p(p)
        try:
            self._z_view[:] = z
        except (TypeError, ValueError):
            self._z[...] = _vector(z, self.model.n_y, "z")
        cur = self._cur
        self._update[cur]()
        if self._ok_view[0] != 1.0:
            return self._update_slow_path(cur)
        self._cur = self._last_update = 1 - cur
        self._last_dof = self._n_y
        return True

    def _update_slow_path(self, cur: int) -> bool:
        """ok was 0: leave out NaN entries, refuse infinite ones, repair P if needed (see _recover)."""
        finite = np.isfinite(self._z)
        if np.any(np.isinf(self._z)):
            raise ValueError(f"z has infinite entries {self._z}; use NaN for a missing entry")
        if self._last_update == 1 - cur:
            self._last_update = -1  # its buffers were just overwritten by the rejected evaluation
        dof = int(finite.sum())
        if dof == 0:
            return False
        try:
            if dof < self._z.size:
                self._mask[:] = finite
                self._z[~finite] = 0.0
                self._update[cur]()
            if self._ok[0] != 1.0:
                self._recover(self._update[cur], "update", {"z": self._z, "p": self._p})
        finally:
            self._mask[:] = 1.0
        self._cur = self._last_update = 1 - cur
        self._last_dof = dof
        return True

    def step(self, u, dt: float, z=None, p=None) -> bool:
        """predict(u, dt, p) then update(z, p) as one transaction; returns whether an update happened.

        With a generated fused step (EKF, CKF) and a complete finite z this is one C call; any
        other case (missing entries, a repair, an error) runs predict and update, and a rejected
        update also undoes the predict.
        """
        fused = self._step  # hot path: every attribute is read once (each read costs ~15-20 ns)
        if z is None:
            self.predict(u, dt, p)
            return False
        if fused is None:
            return self._predict_then_update(u, dt, z, p)
        if p is not None or not self._p_is_default:
            self._set_p(p)
        try:  # exact float64 vectors of the right length only (see __init__), else predict then update
            self._u_view[:] = u
            self._z_view[:] = z
        except (TypeError, ValueError):
            return self._predict_then_update(u, dt, z, p)
        if not 0.0 < dt < _INF:
            raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
        self._dt_view[0] = dt
        cur = self._cur
        fused[cur]()
        if self._ok_view[0] != 1.0:
            if self._last_update == 1 - cur:
                self._last_update = -1  # its buffers were just overwritten by the rejected evaluation
            return self._predict_then_update(u, dt, z, p)
        self._cur = self._last_update = 1 - cur
        self._last_dof = self._n_y
        return True

    def _predict_then_update(self, u, dt, z, p) -> bool:
        cur, x, P = self._cur, self._x[self._cur].copy(), self._P[self._cur].copy()
        self.predict(u, dt, p)
        try:
            return self.update(z, p)
        except Exception:
            self._cur = cur
            self._x[cur][:] = x
            self._P[cur][...] = P
            if self._last_update == cur:
                self._last_update = -1  # overwritten by the rejected update
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
        P[...] = repair_covariance(saved, self.repair_floor)
        evaluate()
        if self._ok[0] != 1.0:
            P[...] = saved
            raise ValueError(
                f"{type(self).__name__}.{what}: the generated step failed (non-finite outputs or a covariance that "
                "is not positive definite) even after repairing P; the filter diverged or Q, R, dt do not suit the "
                "model. State left unchanged."
            )
        self.repairs += 1

    # -------------------------------------------------------------- sequences
    def run(self, U, Z, dt: float, P=None, truth=None) -> FilterResult:
        """Filter a whole sequence: for k < T, predict(U[k], dt, P[k]) then update(Z[k], P[k]).

        U: (T, n_u). Z: (T, n_y) with NaN for missing entries or rows, or None (prediction only).
        P: model parameters, None, (n_p,) shared or (T, n_p). truth: (T, n_x) for NEES.
        """
        model = self.model
        U = np.asarray(U, dtype=np.float64)
        if U.ndim != 2 or U.shape[1] != model.n_u:
            raise ValueError(f"U must have shape (T, {model.n_u}), got {U.shape}")
        T = U.shape[0]
        if Z is not None:
            Z = np.asarray(Z, dtype=np.float64)
            if Z.shape != (T, model.n_y):
                raise ValueError(f"Z must have shape ({T}, {model.n_y}), got {Z.shape}")
        params = [None] * T
        if P is not None:
            P = np.asarray(P, dtype=np.float64)
            if P.shape == (model.n_p,):
                params = [P] * T
            elif P.shape == (T, model.n_p):
                params = list(P)
            else:
                raise ValueError(f"P (parameters) must have shape ({model.n_p},) or ({T}, {model.n_p}), got {P.shape}")
        if truth is not None:
            truth = np.asarray(truth, dtype=np.float64)
            if truth.shape != (T, model.n_x):
                raise ValueError(f"truth must have shape ({T}, {model.n_x}), got {truth.shape}")
        xs = np.empty((T, model.n_x))
        Ps = np.empty((T, model.n_x, model.n_x))
        innovations = np.zeros((T, model.n_y))
        covariances = np.broadcast_to(np.eye(model.n_y), (T, model.n_y, model.n_y)).copy()
        dof = np.zeros(T, dtype=int)
        has_data = np.zeros(T, dtype=bool) if Z is None else np.any(np.isfinite(Z), axis=1)
        for k in range(T):
            if self.step(U[k], dt, Z[k] if has_data[k] else None, params[k]):
                innovations[k] = self._innovation[self._cur]
                covariances[k] = self._S[self._cur]
                dof[k] = self._last_dof
            xs[k] = self._x[self._cur]
            Ps[k] = self._P[self._cur]
        nis = np.einsum("ti,ti->t", innovations, np.linalg.solve(covariances, innovations[..., None])[..., 0])
        nis[dof == 0] = np.nan
        nees = None
        if truth is not None:
            err = truth - xs
            nees = np.einsum("ti,ti->t", err, np.linalg.solve(Ps, err[..., None])[..., 0])
        return FilterResult(x=xs, P=Ps, nis=nis, nis_dof=dof, nees=nees)


class EKF(KalmanFilter):
    """Extended Kalman filter: <m>_ekf_predict / <m>_ekf_update (Joseph form)."""

    predict_function = "ekf_predict"
    update_function = "ekf_update"
    step_function = "ekf_step"


class CKF(KalmanFilter):
    """Cubature Kalman filter (third-degree spherical-radial rule, 2n points)."""

    predict_function = "ckf_predict"
    update_function = "ckf_update"
    step_function = "ckf_step"


class UKF(KalmanFilter):
    """Unscented Kalman filter with scaled sigma points (alpha, beta, kappa)."""

    predict_function = "ukf_predict"
    update_function = "ukf_update"

    def __init__(self, model, x0, P0, Q, R, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0, **options):
        n = model.n_x
        if not all(math.isfinite(v) for v in (alpha, beta, kappa)) or not alpha**2 * (n + kappa) > 0:
            raise ValueError(f"sigma points need finite alpha, beta, kappa with alpha^2 (n + kappa) > 0 (n = {n})")
        self._abk = np.array([alpha, beta, kappa], dtype=np.float64)
        super().__init__(model, x0, P0, Q, R, **options)

    def _predict_extra(self):
        return [self._abk]

    def _update_extra(self):
        return [self._abk]


class MCUKF(UKF):
    """UKF with the maximum-correntropy update of seed 002 (eqs. 36-39), kernel bandwidth sigma."""

    update_function = "mcukf_update"

    def __init__(self, model, x0, P0, Q, R, *, sigma: float = 15.0, **options):
        if not sigma > 0:
            raise ValueError(f"kernel bandwidth sigma must be > 0 (inf gives the plain UKF), got {sigma!r}")
        self._sigma = np.array([sigma], dtype=np.float64)
        super().__init__(model, x0, P0, Q, R, **options)

    def _update_extra(self):
        return [self._abk, self._sigma]


class HuberUKF(UKF):
    """UKF with a Huber M-estimation update (gamma = 1.345, 3 IRLS iterations; HRUKF of seed 002)."""

    update_function = "huber_ukf_update"

    def __init__(self, model, x0, P0, Q, R, *, gamma: float = 1.345, **options):
        if not gamma > 0:
            raise ValueError(f"Huber threshold gamma must be > 0 (inf gives the plain UKF), got {gamma!r}")
        self._gamma = np.array([gamma], dtype=np.float64)
        super().__init__(model, x0, P0, Q, R, **options)

    def _update_extra(self):
        return [self._abk, self._gamma]
