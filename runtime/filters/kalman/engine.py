"""Kalman-family filters (EKF, UKF, CKF, MCUKF, HuberUKF): thin Python classes over the C runtime.

    rov = abyssal.generated.load("rov4dof")
    ckf = CKF(rov, x0, P0, Q, R)
    ckf.step(tau, 0.1, z)             # predict + update, one C call
    ckf.predict(tau, dt=0.1)
    ckf.update(z)
    result = ckf.run(U, Z, dt=0.1, truth=X)   # estimates, covariances, NIS, NEES

One implementation. Every rule of these filters -- the input checks, the missing-entry mask, the innovation
gate with patience and inflation, covariance repair, dt substepping and its refusal, the transaction that
leaves a refused call without effect, the reports -- is the C runtime of runtime/c (abyssal_kalman.h),
compiled once into its own library and reaching the model through its descriptor, and shipped by `abyssal export`: a filter here
is a filter object in a NumPy buffer (its memory), and each call is one call of the runtime's entry point for it
(abyssal_kalman_binding.c) through the fast binding (casadi.external + Function.buffer, bound once). Python keeps the contract's
shapes and types (a wrong shape or a complex array is refused here, naming the argument), the lock, the
parameter buffer and the wording of the errors.

Contract
--------
* One shape per argument: x0 (n_x,), P0 and Q (n_x, n_x), R (n_y, n_y), u (n_u,), z (n_y,), p (n_p,) or None
  for the model's defaults. Q and R are additive noise covariances; Q is the process noise accumulated over
  one step dt (a caller with noise inputs w can use ``process_noise(model, x, u, dt, Qw)`` = G Qw G^T).
* Missing data: ``update(None)`` or an all-NaN z does nothing; NaN entries of z are left out, so
  measurements may come slower than predictions and sensors may drop out one by one. inf is refused.
* A refused call raises ValueError (TypeError for a wrong type) naming the cause and leaves the filter
  bit-identical: x, P, the reported innovation, S and NIS, the counters, p.
* Factorisation guard and repair: a generated step whose Cholesky guard trips on a covariance that is not
  numerically positive definite (indefinite after roundoff, UKF weights that are negative) is retried once
  on the repaired covariance: symmetrised, eigenvalues clipped from below at ``repair_floor`` x max
  |eigenvalue| (default 1e-10); P0 = 0 becomes ``repair_floor`` x max(max |Q|, 1) x I, the Dirac's nearest
  Gaussian. Counted in ``repairs``; a failed retry is refused ("the filter diverged").
* Innovation gate (on by default; gate.py describes the rule): options ``gate_probability`` (default 1e-10;
  0 turns it off), ``gate_patience`` (5) and ``gate_inflation`` (4); an update with every entry gated returns
  False (the predict stands). Counted in ``gated`` and ``inflations``. (rov4dof, CKF, a permanent 25 m jump
  of the x fix: re-acquired within 5 + 5 updates; tests/runtime/test_kalman.py.)
* dt beyond the model's stable range: every predict is checked for a covariance that grows more than
  ``growth_limit`` (default 1e3) times (max diag P + max diag Q) in one step, or an integration that stops
  being finite (sigma points at high speed make explicit RK4 unstable: rov4dof at dt = 1 s). Such a step is
  split into 2, 4, ..., ``max_substeps`` (64) predicts of dt / k, each adding Q / k (``substeps`` counts the
  subdivided predicts); for a dt larger than any found stable before, the k found is remembered for that dt. If
  even max_substeps fails, the call is refused naming dt -- or, when dt was stable before, naming u and p (an
  input that blows the step up at this state: rov4dof at u = 1e5 N went to |x| ~ 1e39 in one 0.1 s predict,
  was accepted as finite, and every later step was refused; now it is integrated in 64 substeps, and u = 1e8 N
  is refused).
* Sigma-point predicts propagate all points through the model's SIMD kernel ``<m>_f_soa`` in one call.
* ``x`` and ``P`` are copies: the state changes only through the calls and ``reset``.
* Threads: FilterBase's rule (contract.py): a second thread entering while a call is under way is refused
  with RuntimeError (its call did nothing). Different filters on one bundle share nothing mutable.

Filters: EKF (Joseph form), UKF (scaled unscented points; alpha, beta, kappa options, default 1, 2, 0;
Julier's choice is alpha=1, beta=0, kappa=3-n, Merwe's alpha=1e-3, beta=2, kappa=0), CKF (third-degree
cubature), MCUKF (maximum-correntropy update, kernel bandwidth sigma, default 15 as in seed 002 Table 6) and
HuberUKF (Huber update, gamma default 1.345, 3 iterations fixed at generation). The robust filters predict
with the UKF step.
"""
from __future__ import annotations

import numpy as np

from abyssal.runtime.compiled import kalman as kr

from ...contract import (FilterBase, FilterResult, _nonfinite_message, _vector, check_covariance, check_dt, check_state,
                         register)
from ...numerics import REPAIR_FLOOR, repair_covariance

__all__ = [
    "CKF", "EKF", "FilterResult", "HuberUKF", "KalmanFilter", "MCUKF", "UKF", "process_noise", "repair_covariance",
]

#: dt types the hot path hands to the C runtime as they are (anything else, a bool included, is checked first)
_PLAIN_NUMBERS = frozenset({float, int, np.float64})


def process_noise(model, x, u, dt, Qw, p=None) -> np.ndarray:
    """G Qw G^T: the additive state covariance of a noise input with covariance Qw held over dt."""
    G = model.G(x, u, p, dt)
    Q = G @ check_covariance(Qw, model.n_w, "Qw") @ G.T
    return (Q + Q.T) / 2


class KalmanFilter(FilterBase):
    """A Kalman-family filter over the C runtime; see the module docstring. Subclasses name their filter
    (``kind``, a key of compiled.kalman.FILTERS) and their rule's options."""

    kind: str = ""
    #: the filter object's committed state (a view of its memory): what checkpoint/restore copy
    _state = ("_committed",)

    def __init__(self, model, x0, P0, Q, R, *, repair_floor: float = REPAIR_FLOOR, gate_probability: float = 1e-10,
                 gate_patience: int = 5, gate_inflation: float = 4.0, growth_limit: float = 1e3, max_substeps: int = 64,
                 **rule):
        if not (hasattr(model, "functions") and hasattr(model, "library")):
            raise TypeError(f"{type(self).__name__} needs a model bundle from abyssal.generated.load(); got {model!r}")
        runtime = kr.KalmanRuntime.of(model)
        if runtime.descriptor is None:
            raise ValueError(f"{type(self).__name__}: the model folder of {model.name!r} was generated before the C runtime "
                             "of the Kalman family (it has no <model>_descriptor.c): regenerate it (`abyssal regenerate`, "
                             "or `abyssal regenerate --model FILE.py:FUNCTION --out DIR`)")
        n, m = model.n_x, model.n_y
        x0 = check_state(x0, n, "x0")
        P0 = check_covariance(P0, n, "P0")
        Q = check_covariance(Q, n, "Q")
        R = check_covariance(R, m, "R", definite=True)
        values = dict(repair_floor=repair_floor, gate_probability=gate_probability, gate_patience=gate_patience,
                      gate_inflation=gate_inflation, growth_limit=growth_limit, max_substeps=max_substeps, **rule)
        try:
            options = runtime.options(self.kind, **values)
        except (TypeError, ValueError, OverflowError) as exc:  # not a number (or an int beyond C's int)
            raise type(exc)(f"{type(self).__name__}: options {values}: {exc}") from None
        code = runtime.kalman_check_options(runtime.descriptor, options)
        if code != kr.OK:
            raise ValueError(self._option_message(code, runtime, values, model))
        size = runtime.kalman_work_size(runtime.descriptor, options)
        memory = np.zeros(size // 8)
        code = runtime.kalman_init(memory.ctypes.data, size, runtime.descriptor, options, x0.ctypes.data, P0.ctypes.data,
                                   Q.ctypes.data, R.ctypes.data, None)
        if code != kr.OK:
            raise ValueError(f"{type(self).__name__}: {runtime.message(code)}")
        self._runtime, self._memory, self.options = runtime, memory, values
        self._view(runtime, n, m)
        # the call block [dt, u, z, p] and the return code, bound once to each of the runtime's calls
        n_u, n_p = model.n_u, model.n_p
        self._io = np.zeros(1 + n_u + m + n_p)
        self._u, self._z = self._io[1:1 + n_u], self._io[1 + n_u:1 + n_u + m]
        self._init_contract(model, p_buffer=self._io[1 + n_u + m:])
        self._code = np.zeros(1)
        self._buffers, calls = [], {}
        for name in kr.CALLS:
            buffer, calls[name] = runtime.call_function(name).buffer()
            buffer.set_arg(0, memoryview(self._memory))
            buffer.set_arg(1, memoryview(self._io))
            buffer.set_res(0, memoryview(self._code))
            self._buffers.append(buffer)  # an evaluation holds a raw pointer to its buffer (and it to the arrays)
        self._call_step, self._call_predict = calls["step"], calls["predict"]
        self._call_update, self._call_check_p = calls["update"], calls["check_p"]
        # memoryviews: the cheapest way to move a few floats in and out on the hot path. The slice assignment
        # view[:] = u takes u's buffer directly and checks that u is exactly a float64 vector of the right
        # length: another format or shape raises ValueError, an object without a buffer (list, None) TypeError.
        self._u_view, self._z_view = memoryview(self._u), memoryview(self._z)
        self._io_view, self._code_view = memoryview(self._io), memoryview(self._code)
        self._gate = None

    def _view(self, runtime, n: int, m: int) -> None:
        """NumPy views of the filter object's parts (abyssal_kalman_offset)."""
        memory, address = self._memory, self._memory.ctypes.data

        def at(item):
            return int(runtime.kalman_offset(address, item))

        def doubles(item, shape):
            count = int(np.prod(shape))
            return np.frombuffer(memory, np.float64, count, at(item)).reshape(shape, order="F")

        def integer(item, dtype):
            return np.frombuffer(memory, dtype, 1, at(item))

        self._x = [doubles(kr.AT_X + k, (n,)) for k in range(3)]
        self._P = [doubles(kr.AT_P + k, (n, n)) for k in range(3)]
        self._innovation = [doubles(kr.AT_INNOVATION + k, (m,)) for k in range(2)]
        self._S = [doubles(kr.AT_S + k, (m, m)) for k in range(2)]
        self._Q, self._R = doubles(kr.AT_Q, (n, n)), doubles(kr.AT_R, (m, m))
        self._current, self._reported = integer(kr.AT_CURRENT, np.int32), integer(kr.AT_REPORTED, np.int32)
        self._nis, self._nis_dof = integer(kr.AT_NIS, np.float64), integer(kr.AT_NIS_DOF, np.int32)
        self._repairs, self._substeps = integer(kr.AT_REPAIRS, np.int64), integer(kr.AT_SUBSTEPS, np.int64)
        gate = at(kr.AT_GATE)
        self._gate_counters = {name: np.frombuffer(memory, np.int64, 1, gate + getattr(kr.GateHeader, name).offset)
                               for name in ("gated", "inflations")}
        self._gate_offset = gate
        self._committed = memory[: at(kr.AT_STATE_BYTES) // 8]

    def _option_message(self, code: int, runtime, values: dict, model) -> str:
        names = {kr.E_SIGMA_POINTS: ("alpha", "beta", "kappa"), kr.E_ROBUST: ("sigma", "gamma"),
                 kr.E_GATE: ("gate_probability", "gate_patience", "gate_inflation"),
                 kr.E_SUBSTEPS: ("growth_limit", "max_substeps", "repair_floor")}.get(code, ())
        got = ", ".join(f"{name}={values[name]!r}" for name in names if name in values)
        if code == kr.E_MODEL:
            return (f"{type(self).__name__}: {runtime.message(code)}; model {model.name!r} has the filter families "
                    f"{model.filter_families}")
        return f"{type(self).__name__}: {runtime.message(code)}; got {got} (n = {model.n_x})"

    # -------------------------------------------------------------- state
    @property
    def _cur(self) -> int:
        """The buffer set holding the state (the C object's `current`)."""
        return int(self._current[0])

    @property
    def x(self) -> np.ndarray:
        """Current state estimate (a copy)."""
        return self._x[self._current[0]].copy()

    @property
    def P(self) -> np.ndarray:
        """Current state covariance (a copy)."""
        return self._P[self._current[0]].copy()

    @property
    def Q(self) -> np.ndarray:
        return self._Q.copy()

    @Q.setter
    def Q(self, value) -> None:
        Q = check_covariance(value, self._Q.shape[0], "Q")
        self._with_lock(lambda: self._checked(self._runtime.kalman_set_Q(self._memory.ctypes.data, Q.ctypes.data)))

    @property
    def R(self) -> np.ndarray:
        return self._R.copy()

    @R.setter
    def R(self, value) -> None:
        R = check_covariance(value, self._R.shape[0], "R", definite=True)
        self._with_lock(lambda: self._checked(self._runtime.kalman_set_R(self._memory.ctypes.data, R.ctypes.data)))

    def reset(self, x, P) -> None:
        """Replace the state (checked like x0 and P0)."""
        n = self.model.n_x
        x = check_state(x, n, "x")
        P = check_covariance(P, n, "P")
        self._with_lock(lambda: self._checked(self._runtime.kalman_reset(self._memory.ctypes.data, x.ctypes.data,
                                                                         P.ctypes.data)))

    def _checked(self, code: int) -> None:
        if code != kr.OK:
            raise ValueError(f"{type(self).__name__}: {self._runtime.message(code)}")

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
        r = self._reported[0]
        return None if r < 0 else self._innovation[r].copy()

    @property
    def S(self) -> np.ndarray | None:
        """Innovation covariance of the last accepted update (identity rows on unused entries), or None."""
        r = self._reported[0]
        return None if r < 0 else self._S[r].copy()

    @property
    def nis(self) -> float:
        """Normalised innovation squared nu^T S^-1 nu of the last accepted update (NaN if none)."""
        return float(self._nis[0])

    @property
    def nis_dof(self) -> int:
        """Measurement entries used by the last accepted update (0 if none)."""
        return int(self._nis_dof[0])

    @property
    def gated(self) -> int:
        """Measurement entries left out by the innovation gate so far."""
        return int(self._gate_counters["gated"][0])

    @property
    def inflations(self) -> int:
        """Covariance inflations after gate_patience consecutive gated updates of an entry."""
        return int(self._gate_counters["inflations"][0])

    @property
    def repairs(self) -> int:
        """Covariance repairs (eigenvalue clipping) performed so far."""
        return int(self._repairs[0])

    @property
    def substeps(self) -> int:
        """Predicts subdivided because dt was beyond the model's stable range."""
        return int(self._substeps[0])

    @property
    def code(self) -> int:
        """The C runtime's return code of the last call (abyssal_kalman.h: 1 a measurement was used, 0 not, < 0 the
        call was refused)."""
        return int(self._code[0])

    @property
    def gate(self):
        """The filter's innovation gate (gate.py's InnovationGate over the C object's gate: its thresholds and
        counters; the filter applies it)."""
        if self._gate is None:
            from .gate import InnovationGate
            self._gate = InnovationGate.over(self._memory, self._gate_offset)
        return self._gate

    # -------------------------------------------------------------- the contract's calls (FilterBase holds the lock)
    def _step_call(self, u, dt, z, p) -> bool:
        try:  # exact float64 vectors of the right length only (see __init__), else the checked path
            self._u_view[:] = u
            if z is not None:
                self._z_view[:] = z
        except (TypeError, ValueError):
            self._u[:] = _vector(u, self.model.n_u, "u")
            if z is not None:
                self._z[:] = _vector(z, self.model.n_y, "z")
        self._io_view[0] = dt if type(dt) in _PLAIN_NUMBERS else check_dt(dt)
        saved = None if p is None and self._p_is_default else self._use_p(p)
        if z is None:
            self._call_predict()
        else:
            self._call_step()
        code = self._code_view[0]
        if code >= 0.0:
            return code == 1.0
        raise self._refusal(code, saved, "step")

    def _predict_call(self, u, dt, p) -> None:
        try:
            self._u_view[:] = u
        except (TypeError, ValueError):
            self._u[:] = _vector(u, self.model.n_u, "u")
        self._io_view[0] = dt if type(dt) in _PLAIN_NUMBERS else check_dt(dt)
        saved = None if p is None and self._p_is_default else self._use_p(p)
        self._call_predict()
        if self._code_view[0] < 0.0:
            raise self._refusal(self._code_view[0], saved, "predict")

    def _update_call(self, z, p) -> bool:
        if z is not None:
            try:
                self._z_view[:] = z
            except (TypeError, ValueError):
                self._z[:] = _vector(z, self.model.n_y, "z")
        saved = None if p is None and self._p_is_default else self._use_p(p)
        if z is None:
            self._call_check_p()
        else:
            self._call_update()
        code = self._code_view[0]
        if code < 0.0:
            raise self._refusal(code, saved, "update")
        if z is None and saved is not None:  # nothing to update: p is left as it was
            self._p[:], self._p_is_default = saved
        return code == 1.0

    def _use_p(self, p):
        """p into the call block (None: the model's defaults); returns what to put back if the call is refused.
        Its shape and type are checked here, its values by the C runtime."""
        saved = (self._p.copy(), self._p_is_default)
        if p is not None and (type(p) is not np.ndarray or p.shape != self._p.shape or p.dtype != np.float64):
            p = _vector(p, self.model.n_p, "p")
        FilterBase._set_p(self, p)
        return saved

    def _refusal(self, code: float, saved_p, call: str) -> Exception:
        """The ValueError of a refused call (the C object is unchanged); p is put back."""
        code = int(code)
        io = self._io.copy()
        if saved_p is not None:
            self._p[:], self._p_is_default = saved_p
        n_u, m = self.model.n_u, self.model.n_y
        u, z, p, dt = io[1:1 + n_u], io[1 + n_u:1 + n_u + m], io[1 + n_u + m:], float(io[0])
        name = f"{type(self).__name__}.{call}"
        if code == kr.E_U:
            return ValueError(f"{name}: {_nonfinite_message('u', u)}")
        if code == kr.E_P:
            return ValueError(f"{name}: {_nonfinite_message('p', p)}")
        if code == kr.E_Z:
            bad = np.flatnonzero(np.isinf(z))
            return ValueError(f"{name}: z has infinite entries at {bad.tolist()[:8]} (values {z[bad[:8]].tolist()}); use "
                              "NaN for a missing entry")
        if code == kr.E_DT:
            return ValueError(f"{name}: dt must be a positive finite number of seconds, got {dt!r}")
        if code == kr.E_UNSTABLE:
            k, limit = self.options["max_substeps"], self.options["growth_limit"]
            return ValueError(
                f"{name}: dt = {dt!r} s: the step blew up even in {k} substeps of {dt / k:.3g} s (the covariance grew more "
                f"than {limit:g}x in one substep, or the integration overflowed): either the filter diverged, or dt is "
                "beyond the model's stable range at this state (the stable limit is below that substep). State left "
                "unchanged.")
        if code == kr.E_UNSTABLE_INPUT:
            k, limit = self.options["max_substeps"], self.options["growth_limit"]
            given = f"u = {u.tolist()}"
            if p.size and not np.array_equal(p, self.model.p_default):
                given += f", p = {p.tolist()}"
            return ValueError(
                f"{name}: {given}: the predict over dt = {dt!r} s (a step length that was stable before) blew up even in "
                f"{k} substeps (the covariance grew more than {limit:g}x in one substep, or the integration overflowed): "
                "u or p drive the model out of its stable range at this state, or the filter diverged. State left "
                "unchanged.")
        return ValueError(f"{name}: {self._runtime.message(code)}")


@register("kalman")
class EKF(KalmanFilter):
    """Extended Kalman filter: the generated <m>_ekf_predict / <m>_ekf_update (Joseph form)."""

    kind = "ekf"


@register("kalman")
class CKF(KalmanFilter):
    """Cubature Kalman filter (third-degree spherical-radial rule, 2n points)."""

    kind = "ckf"


@register("kalman")
class UKF(KalmanFilter):
    """Unscented Kalman filter with scaled sigma points (alpha, beta, kappa)."""

    kind = "ukf"

    def __init__(self, model, x0, P0, Q, R, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0, **options):
        super().__init__(model, x0, P0, Q, R, alpha=alpha, beta=beta, kappa=kappa, **options)


@register("kalman")
class MCUKF(UKF):
    """UKF with the maximum-correntropy update of seed 002 (eqs. 36-39), kernel bandwidth sigma."""

    kind = "mcukf"

    def __init__(self, model, x0, P0, Q, R, *, sigma: float = 15.0, **options):
        super().__init__(model, x0, P0, Q, R, sigma=sigma, **options)


@register("kalman")
class HuberUKF(UKF):
    """UKF with a Huber M-estimation update (gamma = 1.345, 3 IRLS iterations; HRUKF of seed 002)."""

    kind = "huber"

    def __init__(self, model, x0, P0, Q, R, *, gamma: float = 1.345, **options):
        super().__init__(model, x0, P0, Q, R, gamma=gamma, **options)

