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
  0 turns it off), ``gate_patience`` (5), ``gate_inflation`` (4) and ``gate_max_inflations`` (10 per streak, so P
  grows at most 4^10 along a sensor: a real jump of up to ~1000 gate widths is re-acquired, a sensor stuck
  further out is held as rejected); an update with every entry gated returns False (the predict stands). Counted
  in ``gated`` and ``inflations``. (rov4dof, CKF, a permanent 25 m jump of the x fix: re-acquired within 5 + 5
  updates; tests/runtime/test_kalman.py. A depth gauge stuck at +1e6 m from the first step: rejected after 10
  inflations, the filter carried on by the others; tests/runtime/test_unit_slip.py.)
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

import ctypes
import math
import time

import numpy as np

from abyssal.arrays import aligned_zeros
from abyssal.runtime.compiled import kalman as kr

from ...contract import (FilterBase, FilterResult, _nonfinite_message, _vector, check_covariance, check_dt,
                         check_run_arguments, check_state, check_time, register, result_nees)
from ...numerics import REPAIR_FLOOR, repair_covariance
from .units import UnitWatch

__all__ = [
    "CKF", "EKF", "FilterResult", "HuberUKF", "KalmanFilter", "MCUKF", "UKF", "process_noise", "repair_covariance",
]

#: dt types the hot path hands to the C runtime as they are (anything else, a bool included, is checked first)
_PLAIN_NUMBERS = frozenset({float, int, np.float64})
_BLOCK_TIME, _BLOCK_SENSOR, _BLOCK_HAS_R, _BLOCK_HAS_Q = kr.BLOCK_TIME, kr.BLOCK_SENSOR, kr.BLOCK_HAS_R, kr.BLOCK_HAS_Q
#: the history's events when a filter keeps one (history_seconds > 0 or smoothing) and history_entries is not given
DEFAULT_HISTORY_ENTRIES = 256


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

    def __init__(self, model, x0, P0, Q, R=None, *, t0: float = 0.0, noise: str = "step", history_seconds: float = 0.0,
                 history_entries: int | None = None, smoothing: bool = False, repair_floor: float = REPAIR_FLOOR,
                 gate_probability: float = 1e-10, gate_patience: int = 5, gate_inflation: float = 4.0,
                 gate_max_inflations: int = 10, growth_limit: float = 1e3, max_substeps: int = 64, **rule):
        if not (hasattr(model, "functions") and hasattr(model, "library")):
            raise TypeError(f"{type(self).__name__} needs a model bundle from abyssal.generated.load(); got {model!r}")
        runtime = kr.KalmanRuntime.of(model)
        if runtime.descriptor is None:
            raise ValueError(f"{type(self).__name__}: the model folder of {model.name!r} was generated before the C runtime "
                             "of the Kalman family (it has no <model>_descriptor.c): regenerate it (`abyssal regenerate`, "
                             "or `abyssal regenerate --model FILE.py:FUNCTION --out DIR`)")
        n, m = model.n_x, model.n_y
        if noise not in kr.NOISE:
            raise ValueError(f"{type(self).__name__}: noise={noise!r}: choose one of {sorted(kr.NOISE)} (how Q accrues: per "
                             "predict call, per second, or Q is the spectral density of the model's noise inputs)")
        x0 = check_state(x0, n, "x0")
        P0 = check_covariance(P0, n, "P0")
        Q = check_covariance(Q, model.n_w if noise == "inputs" else n, "Q")
        R = None if R is None else check_covariance(R, m, "R", definite=True)
        t0 = check_time(t0, "t0")
        if history_entries is None:
            history_entries = DEFAULT_HISTORY_ENTRIES if history_seconds > 0 or smoothing else 0
        values = dict(repair_floor=repair_floor, gate_probability=gate_probability, gate_patience=gate_patience,
                      gate_inflation=gate_inflation, gate_max_inflations=gate_max_inflations, growth_limit=growth_limit,
                      max_substeps=max_substeps, noise=noise, history_seconds=history_seconds,
                      history_entries=history_entries, smoothing=smoothing, **rule)
        try:
            options = runtime.options(self.kind, **{**values, "noise": kr.NOISE[noise], "smoothing": int(bool(smoothing))})
        except (TypeError, ValueError, OverflowError) as exc:  # not a number (or an int beyond C's int)
            raise type(exc)(f"{type(self).__name__}: options {values}: {exc}") from None
        code = runtime.kalman_check_options(runtime.descriptor, options)
        if code != kr.OK:
            raise ValueError(self._option_message(code, runtime, values, model))
        size = runtime.kalman_work_size(runtime.descriptor, options)
        memory = aligned_zeros(size // 8)  # (on a cache line: its step's speed never depends on where it landed)
        code = runtime.kalman_init(memory.ctypes.data, size, runtime.descriptor, options, x0.ctypes.data, P0.ctypes.data,
                                   Q.ctypes.data, None if R is None else R.ctypes.data, t0, None)
        if code != kr.OK:
            if code == kr.E_R and R is None:
                undeclared = [s["name"] for s in model.sensors if s.get("noise") is None]
                raise ValueError(f"{type(self).__name__}: R is required: sensor(s) {undeclared} declare no noise (give R, "
                                 f"the ({m}, {m}) covariance of every sensor's outputs stacked, or declare the sensors' noise)")
            raise ValueError(f"{type(self).__name__}: {runtime.message(code)}")
        self._runtime, self._memory, self.options = runtime, memory, values
        self._view(runtime, n, m, Q.shape[0], len(model.sensors))
        # the call block [model, dt or t, sensor, has_R, has_q, u, z, p, R, q] and the return code, bound once to each
        # of the runtime's calls (abyssal_kalman_binding.c)
        n_u, n_p, head = model.n_u, model.n_p, kr.BLOCK_HEAD
        self._io = np.zeros(head + n_u + m + n_p + m * m + n_p)
        self._io[:1].view(np.uint64)[0] = runtime.descriptor  # the descriptor's address (its bits, not a number)
        self._u, self._z = self._io[head:head + n_u], self._io[head + n_u:head + n_u + m]
        at = head + n_u + m + n_p
        self._R_call, self._q_call = self._io[at:at + m * m], self._io[at + m * m:]
        self._init_contract(model, p_buffer=self._io[head + n_u + m:at])
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
        self._call_predict_to, self._call_update_sensor = calls["predict_to"], calls["update_sensor"]
        # memoryviews: the cheapest way to move a few floats in and out on the hot path. The slice assignment
        # view[:] = u takes u's buffer directly and checks that u is exactly a float64 vector of the right
        # length: another format or shape raises ValueError, an object without a buffer (list, None) TypeError.
        self._u_view, self._z_view = memoryview(self._u), memoryview(self._z)
        self._io_view, self._code_view = memoryview(self._io), memoryview(self._code)
        self._gate = None
        self._acquire, self._release = self._lock.acquire, self._lock.release  # (bound once: the hot path's lock)
        # by sensor name: its index, the index as the call block holds it, and a view of its outputs' place in the
        # call block (the call block's R and p flags are down between calls: update)
        self._sensor_views = {s["name"]: (k, float(k), memoryview(self._z[:len(s["outputs"])]))
                              for k, s in enumerate(model.sensors)}
        self._unit_watch = UnitWatch(model, type(self).__name__)  # the first updates, for values in another unit
        # the plain step(u, dt, z) and update(sensor, z, t) as one C call each (KalmanRuntime.one_calls), the filter's
        # own attributes over the class's methods, which take every other case (a subclass's own method stays its own)
        fast = runtime.one_calls(self._memory, self._io, self._code,
                                 {name: view[0] for name, view in self._sensor_views.items()}, self)
        for name, call in fast.items():
            if getattr(type(self), name) is getattr(KalmanFilter, name):
                setattr(self, name, call)

    def _view(self, runtime, n: int, m: int, q_rows: int, n_sensors: int) -> None:
        """NumPy views of the filter object's parts (abyssal_kalman_offset)."""
        memory, address = self._memory, self._memory.ctypes.data

        def at(item):
            return int(runtime.kalman_offset(address, item))

        def doubles(item, shape):
            count = int(np.prod(shape))
            return np.frombuffer(memory, np.float64, count, at(item)).reshape(shape, order="F")

        def integer(item, dtype):
            return np.frombuffer(memory, dtype, 1, at(item))

        self._x = [doubles(kr.AT_X + k, (n,)) for k in range(kr.SETS)]
        self._P = [doubles(kr.AT_P + k, (n, n)) for k in range(kr.SETS)]
        self._innovation = [doubles(kr.AT_INNOVATION + k, (m,)) for k in range(2)]
        self._S = [np.frombuffer(memory, np.float64, m * m, at(kr.AT_S + k)) for k in range(2)]
        self._Q = doubles(kr.AT_Q, (q_rows, q_rows))
        self._R = doubles(kr.AT_R, (m, m))
        self._current, self._reported = integer(kr.AT_CURRENT, np.int32), integer(kr.AT_REPORTED, np.int32)
        self._reported_rows = integer(kr.AT_REPORTED_ROWS, np.int32)
        self._reported_sensor = integer(kr.AT_REPORTED_SENSOR, np.int32)
        self._nis, self._nis_dof = integer(kr.AT_NIS, np.float64), integer(kr.AT_NIS_DOF, np.int32)
        self._repairs, self._substeps = integer(kr.AT_REPAIRS, np.int64), integer(kr.AT_SUBSTEPS, np.int64)
        self._inflations, self._late = integer(kr.AT_INFLATIONS, np.int64), integer(kr.AT_LATE, np.int64)
        self._time, self._history = integer(kr.AT_TIME, np.float64), integer(kr.AT_HISTORY, np.int32)
        self._time_view = memoryview(self._time)  # (its item is a Python float: the hot path's reads)
        self._sensor_block = np.frombuffer(memory, np.float64, n_sensors * len(kr.SENSOR_FIELDS),
                                           at(kr.AT_SENSORS)).reshape(n_sensors, len(kr.SENSOR_FIELDS))
        gate = at(kr.AT_GATE)
        self._gate_counters = {"gated": np.frombuffer(memory, np.int64, 1, gate + kr.GateHeader.gated.offset)}
        self._gate_offset = gate
        self._committed = memory[: at(kr.AT_STATE_BYTES) // 8]

    def _option_message(self, code: int, runtime, values: dict, model) -> str:
        names = {kr.E_SIGMA_POINTS: ("alpha", "beta", "kappa"), kr.E_ROBUST: ("sigma", "gamma", "huber_iterations"),
                 kr.E_GATE: ("gate_probability", "gate_patience", "gate_inflation", "gate_max_inflations"),
                 kr.E_SUBSTEPS: ("growth_limit", "max_substeps", "repair_floor"),
                 kr.E_OPTIONS: ("noise", "history_entries", "history_seconds", "smoothing")}.get(code, ())
        got = ", ".join(f"{name}={values[name]!r}" for name in names if name in values)
        if code == kr.E_MODEL:
            return (f"{type(self).__name__}: {runtime.message(code)}; model {model.name!r} (regenerate its folder if it was "
                    "written by an older abyssal)")
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
    def t(self) -> float:
        """The filter's time, s (t0, advanced by every predict)."""
        return float(self._time[0])

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

    def set_sensor_R(self, sensor: str, R) -> None:
        """Replace one sensor's block of R (its (n_y_k, n_y_k) covariance) for later measurements."""
        k = self._sensor(sensor)
        rows = self.model.sensors[k]["outputs"]
        R = check_covariance(R, len(rows), "R", definite=True)
        self._with_lock(lambda: self._checked(self._runtime.kalman_set_sensor_R(
            self._memory.ctypes.data, self._runtime.descriptor, k, R.ctypes.data)))

    def reset(self, x, P) -> None:
        """Replace the state (checked like x0 and P0); the history restarts from it."""
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

    # -------------------------------------------------------------- reports
    @property
    def innovation(self) -> np.ndarray | None:
        """Innovation of the last accepted update (its rows: every sensor stacked, or the one sensor it measured;
        0 on unused entries), or None."""
        r = self._reported[0]
        return None if r < 0 else self._innovation[r][: self._reported_rows[0]].copy()

    @property
    def S(self) -> np.ndarray | None:
        """Innovation covariance of the last accepted update (identity rows on unused entries), or None."""
        r = self._reported[0]
        if r < 0:
            return None
        rows = int(self._reported_rows[0])
        return self._S[r][: rows * rows].reshape(rows, rows, order="F").copy()

    @property
    def reported_sensor(self) -> str | None:
        """The sensor the last accepted update measured (None: every sensor stacked, or none yet)."""
        k = int(self._reported_sensor[0])
        return self.model.sensor_names[k] if k >= 0 else None

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
        """Covariance inflations along a sensor's directions after gate_patience consecutive gates of its entries."""
        return int(self._inflations[0])

    @property
    def repairs(self) -> int:
        """Covariance repairs (eigenvalue clipping) performed so far."""
        return int(self._repairs[0])

    @property
    def substeps(self) -> int:
        """Predicts subdivided because dt was beyond the model's stable range."""
        return int(self._substeps[0])

    @property
    def late(self) -> int:
        """Measurements fused at their own earlier stamp from the history."""
        return int(self._late[0])

    @property
    def history(self) -> int:
        """Events (predicts, updates) the history holds now."""
        return int(self._history[0])

    def sensor_report(self, sensor: str) -> dict:
        """What one sensor did so far: used (its updates that used an entry), accepted (its entries used), gated (its
        entries left out), late (its measurements fused from the history), inflations, rejected (held as stuck or
        lost), nis and nis_dof of its last accepted update, last_t (its last stamp)."""
        row = self._sensor_block[self._sensor(sensor)]
        out = dict(zip(kr.SENSOR_FIELDS, row.tolist()))
        del out["accepted_at_streak"]  # (the runtime's bookkeeping of the inflation rule)
        for name in ("used", "gated", "inflations", "late", "nis_dof", "streak_inflations", "accepted"):
            out[name] = int(out[name])
        out["rejected"] = bool(out["rejected"])
        if out["last_t"] == -math.inf:
            out["last_t"] = math.nan
        return out

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

    # -------------------------------------------------------------- sensors and time
    def _sensor(self, name) -> int:
        if not isinstance(name, str):
            raise TypeError(f"sensor must be a sensor's name (str), got {type(name).__name__}")
        try:
            return self._sensor_views[name][0]
        except KeyError:
            raise ValueError(f"sensor {name!r} is not one of model {self.model.name!r}'s sensors "
                             f"{list(self.model.sensor_names)}") from None

    def predict_to(self, t, u, p=None) -> None:
        """Integrate from the filter's time to t (s) with the input u held over the interval (and parameters p;
        None: the model's defaults). t equal to the filter's time only holds u and p; an earlier t is refused."""
        if not self._lock.acquire(False):
            raise self._busy()
        try:
            t = check_time(t, "t")
            try:
                self._u_view[:] = u
            except (TypeError, ValueError):
                self._u[:] = _vector(u, self.model.n_u, "u")
            self._io_view[kr.BLOCK_TIME] = t
            saved = None if p is None and self._p_is_default else self._use_p(p)
            start = self._time_view[0]
            self._call_predict_to()
            if self._code_view[0] < 0.0:
                raise self._refusal(self._code_view[0], saved, "predict_to")
            if t - start > self._max_dt:  # (contract.py's FilterBase: once per filter, after an accepted call)
                self._warn_long_step(t - start)
        finally:
            self._lock.release()

    def update(self, z, z_or_p=None, t=None, R=None, p=None) -> bool:
        """update(z, p=None): every sensor stacked, at the filter's time (the fixed-rate call); or
        update(sensor, z, t, R=None, p=None): one sensor's measurement stamped t (see update_sensor). One signature
        for both forms, its second argument z or p by form, and the stamped form's body in this one frame like
        step(): it is the hot path of a sensor's stream (a *args signature or a second frame costs it ~0.1-0.3 µs)."""
        if type(z) is not str:
            if isinstance(z, str):  # (a str subclass: the same call with the name as a plain str)
                return self.update_sensor(str.__str__(z), z_or_p, t, R, p)
            if t is not None or R is not None:
                raise TypeError(f"{type(self).__name__}.update: t and R belong to one sensor's update, "
                                f"update(sensor, z, t, R=None, p=None) with sensor one of {list(self.model.sensor_names)}")
            if z_or_p is not None and p is not None:
                raise TypeError(f"{type(self).__name__}.update(z, p): p given twice")
            return super().update(z, p if z_or_p is None else z_or_p)
        sensor, z = z, z_or_p
        if not self._acquire(False):
            raise self._busy()
        try:
            try:
                k, block_sensor, z_view = self._sensor_views[sensor]
            except KeyError:
                raise ValueError(f"{type(self).__name__}.update: z (or sensor) {sensor!r} is not one of model "
                                 f"{self.model.name!r}'s sensors {list(self.model.sensor_names)} (nor a measurement "
                                 "vector)") from None
            if type(t) not in _PLAIN_NUMBERS:  # (a plain number's finiteness is the C runtime's check)
                t = check_time(t, "t")
            try:  # an exact float64 vector of the sensor's outputs goes straight in, as in step()
                z_view[:] = z
            except (TypeError, ValueError):
                self._z[:len(z_view)] = _vector(z, len(z_view), "z")
            io = self._io_view
            io[_BLOCK_TIME] = t
            io[_BLOCK_SENSOR] = block_sensor
            own = R is not None or p is not None
            if own:  # checked into the call block; flagged below for this one call
                self._put_sensor_R_p(k, R, p)
            predicted = None
            if self._unit_watch is not None and self._unit_watch.watching[k]:
                spec = self.model.sensors[k]
                predicted = self._unit_prediction(
                    k, None if p is None else (spec["p_offset"], self._q_call[:len(spec["parameters"])]))
            start = self._time_view[0]
            if not own:
                self._call_update_sensor()
            else:  # the flags up for this call only, down again whatever happens
                io[_BLOCK_HAS_R], io[_BLOCK_HAS_Q] = float(R is not None), float(p is not None)
                try:
                    self._call_update_sensor()
                finally:
                    io[_BLOCK_HAS_R] = io[_BLOCK_HAS_Q] = 0.0
            code = self._code_view[0]
            if code < 0.0:
                raise self._sensor_refusal(int(code), sensor, t, z)
            if predicted is not None:  # (the watch sees accepted calls only)
                self._observe_sensor_units(k, R, predicted)
            if self._time_view[0] - start > self._max_dt:  # predicted ahead to t first (a late fix: no time moved;
                self._warn_long_step(self._time_view[0] - start)  # plain floats, cheaper than t's own arithmetic)
            return code == 1.0
        finally:
            self._release()

    def update_sensor(self, sensor: str, z, t, R=None, p=None) -> bool:
        """One sensor's measurement z (its outputs; NaN entries missing) stamped t (s), with R (its own covariance,
        e.g. a USBL fix's quality figure; None: the filter's) and p (the sensor's own parameters, e.g. a leader's
        position; None: those held). Ahead of the filter's time it is predicted to t with the held input first; behind
        it (a late fix) it is fused at t from the history (history_seconds), or refused when older. Returns whether
        a measurement entry was used; a refusal (ValueError) leaves the filter unchanged. (The same call as
        update(sensor, z, t, R, p), which runs it.)"""
        self._sensor(sensor)  # (refuses anything but one of the model's sensor names, naming the argument)
        return self.update(sensor, z, t, R, p)

    def _put_sensor_R_p(self, k: int, R, p) -> None:
        """Sensor k's own R and/or parameters p of this call, checked, into the call block (not yet flagged)."""
        spec = self.model.sensors[k]
        rows, n_q = len(spec["outputs"]), len(spec["parameters"])
        if R is not None:
            self._R_call[: rows * rows] = check_covariance(R, rows, "R", definite=True).reshape(-1, order="F")
        if p is not None:
            self._q_call[:n_q] = check_state(p, n_q, "p")

    def _observe_sensor_units(self, k: int, R, predicted) -> None:
        """Hand the unit watch sensor k's accepted values, with the R the call used (its own, or the filter's)."""
        spec = self.model.sensors[k]
        rows, offset = len(spec["outputs"]), spec["offset"]
        R_k = self._R[offset:offset + rows, offset:offset + rows] if R is None else self._R_call[:rows * rows]
        self._observe_units(k, self._z[:rows], np.reshape(R_k, (rows, rows)), predicted)

    def smooth(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rauch-Tung-Striebel smoothing over the history (smoothing=True): (t (K,), x (K, n_x), P (K, n_x, n_x)),
        one row per event the history holds, oldest first, given every measurement in it (the C runtime's
        abyssal_kalman_smooth). The filter is unchanged."""
        if not self.options.get("smoothing"):
            raise ValueError(f"{type(self).__name__}.smooth: built without smoothing=True (the history keeps no smoother "
                             "gains)")
        n, K = self.model.n_x, self.history
        t, x, P = np.empty(K), np.empty((K, n)), np.empty((K, n, n))
        count = ctypes.c_int(0)
        if not self._lock.acquire(False):
            raise self._busy()
        try:
            code = self._runtime.kalman_smooth(self._memory.ctypes.data, t.ctypes.data, x.ctypes.data, P.ctypes.data, K,
                                               ctypes.byref(count))
        finally:
            self._lock.release()
        if code != kr.OK:
            raise ValueError(f"{type(self).__name__}.smooth: {self._runtime.message(code)}")
        return t[: count.value], x[: count.value], np.ascontiguousarray(np.transpose(P[: count.value], (0, 2, 1)))

    # -------------------------------------------------------------- a whole sequence in one call
    def run(self, U, Z, dt, params=None, truth=None) -> FilterResult:
        """Filter a whole sequence in one call of the C runtime (abyssal_kalman_run): the same steps, results and
        reports as T calls of step(); all-or-nothing (a refused row k restores the filter and the error names
        row k). step_time is the run's time per row (the C loop is not timed row by row)."""
        model = self.model
        a = check_run_arguments(model, U, Z, dt, params, truth)
        T, n = a.U.shape[0], model.n_x
        U = np.ascontiguousarray(a.U)
        Z = None if a.Z is None else np.ascontiguousarray(a.Z)  # (a row without a finite entry is all NaN: no update)
        # one dt for every row goes as one number (the C reads it with step 0), as do absent parameters
        dts, dt_step = (np.ascontiguousarray(a.dts, dtype=np.float64), 1) if a.dt_each_row else (np.array(a.dts[:1]), 0)
        given = [] if params is None else [p for p in a.rows_p if p is not None]
        P_rows = None if not given else np.ascontiguousarray([model.p_default if p is None else p for p in a.rows_p])
        longest = float(dts.max()) if dts.size else 0.0
        xs, Ps = np.empty((T, n)), np.empty((T, n, n))
        # (the C writes every row of each: NaN and 0 where a row has no update)
        nis, dof, row = np.empty(T), np.empty(T, dtype=np.int32), ctypes.c_longlong(-1)
        if not self._lock.acquire(False):
            raise self._busy()
        try:
            saved = self._committed.copy()
            start = time.perf_counter()
            code = self._runtime.kalman_run(self._memory.ctypes.data, self._runtime.descriptor, T, U.ctypes.data,
                                            dts.ctypes.data, dt_step, None if Z is None else Z.ctypes.data,
                                            None if P_rows is None else P_rows.ctypes.data, 1, xs.ctypes.data,
                                            Ps.ctypes.data, nis.ctypes.data, dof.ctypes.data, ctypes.byref(row))
            elapsed = time.perf_counter() - start
            if code < 0:
                k = int(row.value)
                self._committed[...] = saved
                self._u[:], self._io_view[kr.BLOCK_TIME] = U[k], dts[k * dt_step]
                if Z is not None:
                    self._z[:] = Z[k]
                p_saved = (self._p.copy(), self._p_is_default)
                self._p[:] = model.p_default if P_rows is None else P_rows[k]
                error = self._refusal(code, p_saved, "step")
                raise type(error)(f"run: row {k} refused ({error}); the filter was restored to its state before run") \
                    from error
        finally:
            self._lock.release()
        if T:  # the parameter buffer as T calls of step() leave it
            FilterBase._set_p(self, a.rows_p[-1])
        if longest > self._max_dt:
            self._warn_long_step(longest)
        return FilterResult(x=xs, P=Ps, nis=nis, nis_dof=dof.astype(int), nees=result_nees(model, a.truth, xs, Ps),
                            ess=np.full(T, np.nan), particles=np.full(T, np.nan),
                            step_time=np.full(T, elapsed / max(T, 1)))

    # -------------------------------------------------------------- the contract's calls (FilterBase holds the lock)
    def step(self, u, dt, z=None, p=None) -> bool:
        """predict(u, dt, p) then update(z, p) as one transaction; returns whether an update happened. (The
        contract's step in one frame: the C step is itself the transaction, and this is the hot path. A filter built
        where Python's headers are found has its plain case as its own ``step``, one C call (KalmanRuntime.one_calls)
        that sends every other case here.)"""
        if not self._acquire(False):
            raise self._busy()
        try:
            try:  # exact float64 vectors of the right length only (see __init__), else the checked path
                self._u_view[:] = u
                if z is not None:
                    self._z_view[:] = z
            except (TypeError, ValueError):
                self._u[:] = _vector(u, self.model.n_u, "u")
                if z is not None:
                    self._z[:] = _vector(z, self.model.n_y, "z")
            if type(dt) not in _PLAIN_NUMBERS:
                dt = check_dt(dt)
            self._io_view[_BLOCK_TIME] = dt
            saved = None if p is None and self._p_is_default else self._use_p(p)
            if z is None:
                self._call_predict()
            else:
                predicted = None if self._unit_watch is None else self._unit_prediction(None, None)
                self._call_step()
                if predicted is not None and self._code_view[0] >= 0.0:  # (the watch sees accepted calls only)
                    self._observe_units(None, self._z, self._R, predicted)
            code = self._code_view[0]
            if code >= 0.0:
                if dt > self._max_dt:  # (contract.py's FilterBase: once per filter, after an accepted call)
                    self._warn_long_step(dt)
                return code == 1.0
            raise self._refusal(code, saved, "step")
        finally:
            self._release()

    def _predict_call(self, u, dt, p) -> None:
        try:
            self._u_view[:] = u
        except (TypeError, ValueError):
            self._u[:] = _vector(u, self.model.n_u, "u")
        if type(dt) not in _PLAIN_NUMBERS:
            dt = check_dt(dt)
        self._io_view[kr.BLOCK_TIME] = dt
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
        predicted = None if z is None or self._unit_watch is None else self._unit_prediction(None, None)
        if z is None:
            self._call_check_p()
        else:
            self._call_update()
        code = self._code_view[0]
        if predicted is not None and code >= 0.0:  # (the watch sees accepted calls only)
            self._observe_units(None, self._z, self._R, predicted)
        if code < 0.0:
            raise self._refusal(code, saved, "update")
        if z is None and saved is not None:  # nothing to update: p is left as it was
            self._p[:], self._p_is_default = saved
        return code == 1.0

    def _unit_prediction(self, sensor, sensor_p) -> np.ndarray | None:
        """The prediction h(x) from the filter's estimate that the unit watch (units.py) compares sensor k's values
        with (sensor None: every sensor; sensor_p: (its offset in p, the sensor's own parameters of this call) or
        None); None when the watch is done with it, or when h is not finite at the estimate (nothing to compare)."""
        watch = self._unit_watch
        if not (any(watch.watching) if sensor is None else watch.watching[sensor]):
            return None
        p = self._p.copy()
        if sensor_p is not None:
            p[sensor_p[0]:sensor_p[0] + len(sensor_p[1])] = sensor_p[1]
        try:
            with np.errstate(all="ignore"):
                return self.model.h(self.x, p)
        except FloatingPointError:
            return None

    def _observe_units(self, sensor, z, R, y) -> None:
        """Hand the unit watch an accepted update's values z of sensor k (None: every sensor, z stacked), their noise R
        and the prediction y from _unit_prediction."""
        watch = self._unit_watch
        z = np.asarray(z, dtype=float)
        for k in range(len(watch.sensors)) if sensor is None else (sensor,):
            first, end = watch.sensors[k]
            values = z[first:end] if sensor is None else z
            if watch.watching[k] and not np.isnan(values).all():
                block = R[first:end, first:end] if sensor is None else R
                watch.observe_sensor(k, values, y[first:end], block)
        if watch.done:
            self._unit_watch = None

    def _checkpoint_sizes(self) -> dict:
        return {"object doubles": int(self._committed.size), "sensors": len(self.model.sensors)}

    def _use_p(self, p):
        """p into the call block (None: the model's defaults); returns what to put back if the call is refused.
        Its shape and type are checked here, its values by the C runtime."""
        saved = (self._p.copy(), self._p_is_default)
        if p is not None and (type(p) is not np.ndarray or p.shape != self._p.shape or p.dtype != np.float64):
            p = _vector(p, self.model.n_p, "p")
        FilterBase._set_p(self, p)
        return saved

    def _block_parts(self):
        io, n_u, m, head = self._io.copy(), self.model.n_u, self.model.n_y, kr.BLOCK_HEAD
        return io[head:head + n_u], io[head + n_u:head + n_u + m], self._p.copy(), float(io[kr.BLOCK_TIME])

    def _refusal(self, code: float, saved_p, call: str) -> Exception:
        """The ValueError of a refused call (the C object is unchanged); p is put back."""
        code = int(code)
        u, z, p, dt = self._block_parts()
        if saved_p is not None:
            self._p[:], self._p_is_default = saved_p
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
            return ValueError(f"{name}: dt must be a positive finite number of seconds, got {float(dt)!r}")
        if code == kr.E_TIME:
            return ValueError(f"{name}: t = {float(dt)!r} s is before the filter's time {self.t!r} s (a predict cannot go back)")
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
        if code == kr.E_UNSTABLE_STATE:
            x = self.x
            return ValueError(
                f"{name}: the state given to the filter (x0 or reset: |x| up to {np.max(np.abs(x)):.3g}, largest variance "
                f"{np.max(np.diag(self.P)):.3g}) blew up in its first predict over dt = {dt!r} s even in "
                f"{self.options['max_substeps']} substeps: x or P is outside the model's stable range. State left "
                "unchanged.")
        return ValueError(f"{name}: {self._runtime.message(code)}")

    def _sensor_refusal(self, code: int, sensor: str, t: float, z: np.ndarray) -> Exception:
        name = f"{type(self).__name__}.update({sensor!r})"
        report = self.sensor_report(sensor)
        t = float(t)  # (a NumPy scalar is named as a number)
        if code == kr.E_TIME:
            if not math.isfinite(t):
                return ValueError(f"{name}: t must be a finite time stamp in seconds, got {t!r}")
            return ValueError(f"{name}: t = {t!r} s is not after this sensor's previous stamp {report['last_t']!r} s (each "
                              "sensor's stamps must increase)")
        if code == kr.E_TOO_LATE:
            lag = self.options["history_seconds"]
            return ValueError(f"{name}: t = {t!r} s is older than the history holds (the filter is at {self.t!r} s; "
                              f"history_seconds = {lag!r}, history_entries = {self.options['history_entries']}): the "
                              "measurement was not used; nothing changed")
        if code == kr.E_Z:
            bad = np.flatnonzero(np.isinf(z))
            return ValueError(f"{name}: z has infinite entries at {bad.tolist()[:8]}; use NaN for a missing entry")
        if code == kr.E_U:
            return ValueError(f"{name}: t = {t!r} s is ahead of the filter's time {self.t!r} s and no input is held to "
                              "predict with: call predict_to (or step) first")
        if code == kr.E_P:
            return ValueError(f"{name}: p (the sensor's own parameters) has non-finite entries")
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

    def __init__(self, model, x0, P0, Q, R=None, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
                 **options):
        super().__init__(model, x0, P0, Q, R, alpha=alpha, beta=beta, kappa=kappa, **options)


@register("kalman")
class MCUKF(UKF):
    """UKF with the maximum-correntropy update of seed 002 (eqs. 36-39), kernel bandwidth sigma."""

    kind = "mcukf"

    def __init__(self, model, x0, P0, Q, R=None, *, sigma: float = 15.0, **options):
        super().__init__(model, x0, P0, Q, R, sigma=sigma, **options)


@register("kalman")
class HuberUKF(UKF):
    """UKF with a Huber M-estimation update (gamma = 1.345, 3 IRLS iterations; HRUKF of seed 002)."""

    kind = "huber"

    def __init__(self, model, x0, P0, Q, R=None, *, gamma: float = 1.345, **options):
        super().__init__(model, x0, P0, Q, R, gamma=gamma, **options)
