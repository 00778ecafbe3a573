"""The one filter contract: what every filter of abyssal does, present and future.

    filt.step(u, dt, z=None, p=None) -> bool   # predict, then update where z has finite entries
    filt.predict(u, dt, p=None)
    filt.update(z, p=None) -> bool            # False (nothing changed) when z is None or all NaN
    filt.x, filt.P                            # (n,), (n, n) copies
    filt.run(U, Z, dt, params=None, truth=None) -> FilterResult

Shapes: u (n_u,), z (n_y,), p (n_p,) or None (the model's defaults), x0 (n_x,), P0 (n_x, n_x);
U (T, n_u), Z (T, n_y) or None, params None / (n_p,) / (T, n_p), dt a number or (T,), truth
(T, n_x). One shape per argument; anything else is refused.

Input rules (the ``check_*`` helpers below; every filter uses them, none re-implements them):

* p may change every step (a leader's position per ping): each call uses the p it is given;
  p=None means the model's defaults.
* NaN entries of z are left out entry by entry (a Kalman update uses the present rows; a
  particle likelihood uses the present entries only); an all-NaN z is no measurement.
  inf is refused: "use NaN for a missing entry".
* dt must be a positive finite number; u, p, x0 must be finite; covariances finite, symmetric
  and positive semi-definite (validation never overflows on huge finite entries).
* Complex arrays are refused with TypeError (never silently truncated to real).
* N (particles, components) is an int >= 1; ``rng`` is an int seed, a ``SeedSequence`` or a
  ``numpy.random.Generator`` (``as_generator``), anything else is a TypeError.
* A refusal is a ValueError/TypeError naming the argument, and leaves the filter bit-identical:
  its state (x, P, particles, weights, per-particle covariances, random generator) and what it
  reports (innovation, S, NIS, ESS, counters).
* Finite in, finite out: a step whose estimate x or covariance P comes out non-finite is refused
  (ValueError naming the call and its arguments, state unchanged: ``FilterBase._check_finite``);
  LinAlgError, FloatingPointError and OverflowError never escape a call raw.

Reporting attributes every filter has (read by ``run``): ``nis`` (float, NaN when the last
accepted update is undefined or there was none), ``nis_dof`` (int), ``ess`` (float; NaN for
Kalman filters) and ``n_particles`` (float; NaN for Kalman filters). ``checkpoint()`` returns an
opaque copy of the whole state and reports, plain data (it pickles) with what it belongs to (the filter's kind, its
model's name and id, sizes and options); ``restore(checkpoint)`` puts it back, in this process or another, bit for bit,
and refuses (ValueError naming each difference, the filter unchanged) a checkpoint of anything else.

A model that declares its max_dt (``Envelope(max_dt=...)``, recorded in its manifest) says the longest step it is
meant for: a filter stepped (``predict``, ``step``, ``run``; a Kalman filter's ``predict_to`` and
``update_sensor`` ahead of its time too) with a longer dt warns once (``warnings.warn``, a
``LongStepWarning``; once per filter object) and goes on (a step its model cannot take in one piece is subdivided
or refused, as always).

``run`` is all-or-nothing: when row k is refused, the filter is restored to its state before
``run`` and the error (same type) names the row; the cause is chained (``__cause__``).

Threads: a filter object is not shared between threads. Every filter detects concurrent use
and raises RuntimeError instead of silently losing updates: each public call takes the filter's
lock without blocking (``Lock.acquire(False)`` in ``FilterBase``; its cost is in
benchmarks/README.md); the losing call did nothing. Different filters on one model bundle are
independent.

One implementation: ``FilterBase`` owns the public calls, the checks, the lock, p, the snapshot
and its restore on any failure, and the translation of numerical failures; a filter implements
hooks and declares its state (``Stateful._state``), which ``checkpoint``/``restore`` copy.

A new filter class registers itself with ``@register(kind)`` (kind: "kalman", "particle",
"mixture", "gaussian-sum"; see ``register``) so the contract test (tests/runtime/test_contract.py)
runs every rule against it the day it is added; ``registered_filters()`` lists them (importing
every module under runtime/filters). A filter whose constructor fits no kind gives itself a
``contract_example(model, *, x0=None, P0=None, n_particles=None, rng)`` classmethod returning an
instance (None: its own choice; the contract test passes its rules' x0, P0, N and rng through it).
"""
from __future__ import annotations

import functools
import math
import numbers
import threading
import time
import warnings
from collections import deque
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from abyssal.arrays import real_array

from .numerics import SYMMETRY_TOLERANCE, angle_indices, nees, wrap_angles

__all__ = [
    "Filter", "FilterBase", "LongStepWarning", "NUMERICAL_FAILURES", "RunArguments", "Stateful", "FilterResult", "as_generator", "check_count",
    "check_covariance", "check_run_arguments",
    "check_dt", "check_p", "check_state", "check_time", "check_u", "check_z", "real_array", "register", "registered_filters",
    "run_filter",
]



# ---------------------------------------------------------------------------------------------
# the protocol


@runtime_checkable
class Filter(Protocol):
    """What every filter provides (see the module docstring)."""

    model: object
    nis: float
    nis_dof: int
    ess: float
    n_particles: float

    @property
    def x(self) -> np.ndarray: ...

    @property
    def P(self) -> np.ndarray: ...

    def predict(self, u, dt, p=None) -> None: ...

    def update(self, z, p=None) -> bool: ...

    def step(self, u, dt, z=None, p=None) -> bool: ...

    def run(self, U, Z, dt, params=None, truth=None) -> "FilterResult": ...

    def checkpoint(self) -> object: ...

    def restore(self, checkpoint) -> None: ...


@dataclass(frozen=True)
class FilterResult:
    """Output of ``run`` over T steps (step k: predict with U[k], then update with Z[k])."""

    x: np.ndarray                   # (T, n_x) estimates after step k
    P: np.ndarray                   # (T, n_x, n_x) covariances after step k
    nis: np.ndarray                 # (T,) normalised innovation squared, NaN where no update or undefined
    nis_dof: np.ndarray             # (T,) measurement entries used (chi-square degrees of freedom), 0: none
    nees: np.ndarray | None = None  # (T,) normalised estimation error squared, when truth is given
    ess: np.ndarray | None = None   # (T,) effective sample size after the step (NaN for Kalman filters)
    particles: np.ndarray | None = None  # (T,) particle count (NaN for Kalman filters)
    step_time: np.ndarray | None = None  # (T,) wall-clock seconds of each step

    def rmse(self, truth: np.ndarray, angle_states=()) -> np.ndarray:
        """Root-mean-square error per state against truth (T, n_x); angle states wrapped."""
        error = wrap_angles(np.asarray(truth) - self.x, angle_states)
        return np.sqrt(np.mean(error**2, axis=0))


# ---------------------------------------------------------------------------------------------
# registry


_REGISTRY: dict[type, str] = {}
KINDS = ("kalman", "particle", "mixture", "gaussian-sum")


def register(kind: str):
    """Class decorator: put a filter class under the contract test. kind says how it is built:
    "kalman" (model, x0, P0, Q, R), "particle" / "mixture" (model, x0, P0, process_noise,
    measurement_noise, n_particles, rng) with GaussianMixture noises, "gaussian-sum" (model, x0,
    P0, process_noise, measurement_noise, n_components=2, rng=seed)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")

    def decorate(cls):
        _REGISTRY[cls] = kind
        cls.contract_kind = kind
        return cls

    return decorate


def registered_filters() -> dict[type, str]:
    """Every registered filter class and its kind. Imports every module under runtime/filters first,
    so a filter module nobody imports yet is covered too (an import error there is raised here)."""
    import importlib
    import pkgutil

    from . import filters

    for module in pkgutil.walk_packages(filters.__path__, filters.__name__ + "."):
        importlib.import_module(module.name)
    return dict(_REGISTRY)


# ---------------------------------------------------------------------------------------------
# input checks (each names its argument)


def _finite(v: np.ndarray) -> bool:
    """Every entry of a float64 vector finite. For the short vectors of a step, in Python: a finite sum
    proves it (an inf or NaN entry makes the sum inf or NaN), else each entry is checked (the sum of finite
    entries may overflow); ~0.3 us, where np.isfinite(v).all() takes ~0.9 us."""
    if v.shape[0] <= 32:
        entries = v.tolist()
        return math.isfinite(sum(entries)) or all(map(math.isfinite, entries))
    return bool(np.isfinite(v).all())


#: the dtype of float64 arrays, compared by identity on the hot paths (numpy's built-in dtypes are singletons;
#: an equal dtype that is another object takes the general path)
_FLOAT64 = np.dtype(np.float64)


@functools.lru_cache(maxsize=None)
def _all_present(n: int) -> np.ndarray:
    """An (n,) all-True mask, read-only: shared by every fully present z (np.ones takes ~0.7 us)."""
    mask = np.ones(n, dtype=bool)
    mask.flags.writeable = False
    return mask


def _vector(value, n: int, name: str) -> np.ndarray:
    v = real_array(value, name)
    if v.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {v.shape}")
    return v


def _nonfinite_message(name: str, v: np.ndarray) -> str:
    bad = np.flatnonzero(~np.isfinite(v.reshape(-1)))
    return f"{name} has non-finite entries at {bad.tolist()[:8]} (values {v.reshape(-1)[bad[:8]].tolist()})"


def check_state(value, n: int, name: str = "x0") -> np.ndarray:
    """A finite (n,) float64 vector (a copy)."""
    if type(value) is np.ndarray and value.dtype is _FLOAT64 and value.shape == (n,) and _finite(value):
        return value.copy()  # the hot path
    v = _vector(value, n, name)
    if not np.all(np.isfinite(v)):
        raise ValueError(_nonfinite_message(name, v))
    return np.array(v)


def check_u(u, n_u: int) -> np.ndarray:
    """The input u: finite, shape (n_u,)."""
    return check_state(u, n_u, "u")


def check_dt(dt) -> float:
    """dt: a positive finite real number of seconds."""
    if type(dt) is float and 0.0 < dt < math.inf:
        return dt
    if isinstance(dt, np.ndarray) and dt.shape == ():
        dt = dt.item()
    if isinstance(dt, (bool, np.bool_)) or not isinstance(dt, numbers.Real):
        raise TypeError(f"dt must be a real number of seconds, got {type(dt).__name__}")
    dt = float(dt)
    if not 0.0 < dt < math.inf:
        raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
    return dt


def check_time(t, name: str = "t") -> float:
    """A time stamp: a finite real number of seconds."""
    if type(t) is float and math.isfinite(t):
        return t
    if isinstance(t, np.ndarray) and t.shape == ():
        t = t.item()
    if isinstance(t, (bool, np.bool_)) or not isinstance(t, numbers.Real):
        raise TypeError(f"{name} must be a real number of seconds, got {type(t).__name__}")
    t = float(t)
    if not math.isfinite(t):
        raise ValueError(f"{name} must be a finite number of seconds, got {t!r}")
    return t


def check_p(p, model) -> np.ndarray | None:
    """p: None (the model's defaults) or a finite (n_p,) vector (a copy)."""
    if p is None:
        return None
    return check_state(p, model.n_p, "p")


def check_z(z, n_y: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(z with missing entries set to 0, present (n_y,) bool) or None when z is None or all NaN.

    inf is refused: a missing entry is NaN.
    """
    if z is None:
        return None
    if type(z) is np.ndarray and z.dtype is _FLOAT64 and z.shape == (n_y,) and _finite(z):
        return z.copy(), _all_present(n_y)  # the hot path
    v = _vector(z, n_y, "z")
    present = np.isfinite(v)
    if present.all():
        return np.array(v), present
    if np.isinf(v).any():
        raise ValueError(f"z has infinite entries at {np.flatnonzero(np.isinf(v)).tolist()}; use NaN for a missing entry")
    if not present.any():
        return None
    return np.where(present, v, 0.0), present


def check_covariance(value, n: int, name: str, *, definite: bool = False) -> np.ndarray:
    """A finite, symmetric, positive (semi-)definite (n, n) matrix (Fortran-ordered copy).

    The checks run on the matrix scaled by its largest entry, so entries near 1e308 neither
    overflow nor raise LinAlgError.
    """
    A = real_array(value, name)
    if A.shape != (n, n):
        raise ValueError(f"{name} must have shape ({n}, {n}), got {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError(_nonfinite_message(name, A))
    scale = float(np.max(np.abs(A))) if A.size else 0.0
    unit = A / scale if scale > 0 else A
    asymmetry = float(np.max(np.abs(unit - unit.T), initial=0.0))
    if asymmetry > SYMMETRY_TOLERANCE:
        raise ValueError(f"{name} is not symmetric (max |{name} - {name}^T| / max |{name}| = {asymmetry:.3g})")
    A = 0.5 * A + 0.5 * A.T  # (halves first: no overflow near 1e308)
    # definiteness on the Jacobi-scaled matrix D^-1/2 A D^-1/2 (entries in [-1, 1] when A is positive
    # semi-definite), so a diagonal matrix with entries 1e-10 and 1e30, or entries near 1e308, is judged exactly
    d = np.diag(A).copy()
    if definite and not np.all(d > 0):
        raise ValueError(f"{name} must be positive definite; diagonal entry {int(np.argmin(d))} is {d.min():.3g}")
    if d.size and d.min() < 0:
        raise ValueError(f"{name} must be positive semi-definite; diagonal entry {int(np.argmin(d))} is {d.min():.3g}")
    root = np.sqrt(np.where(d > 0, d, 1.0))
    C = (A / root[:, None]) / root[None, :]
    smallest = float(np.linalg.eigvalsh(C)[0]) if n else 0.0
    if definite and not smallest > n * np.finfo(float).eps:
        raise ValueError(f"{name} must be positive definite (its correlation matrix has eigenvalue {smallest:.3g})")
    if not definite and smallest < -SYMMETRY_TOLERANCE:
        raise ValueError(f"{name} must be positive semi-definite (its correlation matrix has eigenvalue {smallest:.3g})")
    return np.asfortranarray(A)


def check_count(value, name: str, minimum: int = 1) -> int:
    """An integer >= minimum (particle or component count)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def as_generator(rng) -> np.random.Generator:
    """A numpy Generator from an int seed, a SeedSequence or a Generator (returned as is)."""
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, (bool, np.bool_)):
        if rng < 0:
            raise ValueError(f"rng seed must be >= 0, got {rng}")
        return np.random.default_rng(int(rng))
    if isinstance(rng, np.random.SeedSequence):
        return np.random.default_rng(rng)
    raise TypeError(f"rng must be an int seed or a numpy.random.Generator, got {type(rng).__name__}")


# ---------------------------------------------------------------------------------------------
# the model's declared step


class LongStepWarning(UserWarning):
    """A filter was stepped with a dt beyond its model's declared max_dt (once per filter object)."""


def declared_max_dt(model) -> float | None:
    """The max_dt the model declares in its envelope (its manifest's), None when it declares none."""
    envelope = getattr(model, "envelope", None)
    if not isinstance(envelope, dict) or not envelope.get("declared") or envelope.get("max_dt") is None:
        return None
    return float(envelope["max_dt"])


# ---------------------------------------------------------------------------------------------
# the transaction and run: one implementation for every filter


#: numerical failures inside a step that the transaction refuses as ValueError (the state is restored)
NUMERICAL_FAILURES = (np.linalg.LinAlgError, FloatingPointError, OverflowError)


def _copy(value):
    """A copy of one state entry: arrays and containers copied, a Generator as its bit-generator state, a
    ``Stateful`` part as its checkpoint; anything else (numbers, strings, immutable objects) as is."""
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, np.random.Generator):
        return value.bit_generator.state
    if isinstance(value, Stateful):
        return value.checkpoint()
    if isinstance(value, (list, tuple, deque)):
        return type(value)(_copy(v) for v in value)
    return value


#: the key of a filter checkpoint's identity (FilterBase.checkpoint)
CHECKPOINT_HEADER = "abyssal checkpoint of"


def _same(a, b) -> bool:
    """Equal option values (NaN equal to NaN: an option may be NaN)."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    try:
        return bool(a == b)
    except (TypeError, ValueError):
        return a is b


def _put(owner, name: str, saved) -> None:
    """Restore one entry: in place where the current value is a buffer of the same shape (a buffer may be
    bound to generated C), else by assignment of a copy."""
    current = getattr(owner, name)
    if isinstance(current, np.random.Generator):
        current.bit_generator.state = saved
    elif isinstance(current, Stateful):
        current.restore(saved)
    elif (isinstance(current, np.ndarray) and isinstance(saved, np.ndarray) and current.shape == saved.shape
          and current.dtype == saved.dtype):
        current[...] = saved
    elif isinstance(current, list) and isinstance(saved, list) and len(current) == len(saved) and all(
            isinstance(c, np.ndarray) for c in current):
        for c, v in zip(current, saved):
            c[...] = v
    else:
        setattr(owner, name, _copy(saved))


class Stateful:
    """Something whose state is a declared list of attribute names, copied by ``checkpoint`` and put back
    by ``restore`` (a filter, or a part of one such as a particle proposal or an innovation gate).

    ``_state`` names attributes of self; a name may be a Stateful attribute itself (its own checkpoint
    is nested). Buffers (numpy arrays, lists of them) are restored in place, so buffers bound to
    generated C keep their addresses.
    """

    _state: tuple[str, ...] = ()

    def checkpoint(self) -> dict:
        """An opaque copy of everything the object holds and reports."""
        return {name: _copy(getattr(self, name)) for name in self._state}

    def restore(self, checkpoint: dict) -> None:
        """Put a checkpoint back."""
        for name in self._state:
            _put(self, name, checkpoint[name])


class FilterBase(Stateful):
    """The contract's transaction, once: predict/update/step/run/checkpoint/restore for every filter.

    A filter implements, on checked inputs and with ``self._p`` already set to the call's parameters,
    either both of

        _predict(u, dt)                -> None
        _update(z, present)            -> bool   (z with 0 where missing, present (n_y,) bool)

    or one move ``_advance(u, dt, measurement) -> bool`` (u, dt None: an update alone; measurement None
    or (z, present)), which by default is _predict then _update.

    and declares in ``_state`` the attribute names of everything it holds and reports (``_p`` and
    ``_p_is_default`` are added here). A public call takes the filter's lock without blocking, checks
    its inputs (each refusal names the argument), saves the state a hook may change (``_touched``:
    the names a hook writes before its commit; default every name in ``_state``), sets p, runs the
    hook, and on any failure restores what it saved and re-raises; a numerical failure (LinAlgError,
    FloatingPointError, OverflowError) becomes a ValueError saying the state was left unchanged.

    A filter with its own double-buffered fast path (the Kalman engine) overrides the ``_*_call``
    methods instead, which receive the raw arguments under the lock and must leave the filter
    unchanged when they raise.
    """

    nis: float = math.nan
    nis_dof: int = 0
    ess: float = math.nan
    n_particles: float = math.nan
    _touched: tuple[str, ...] | None = None
    #: the step a dt is compared with: the model's declared max_dt until the filter has warned about a longer one
    #: (``_warn_long_step``), inf after that or when the model declares none (one comparison on the hot path)
    _max_dt: float = math.inf
    _declared_max_dt: float | None = None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        own = tuple(name for name in cls._state if name not in ("_p", "_p_is_default"))
        cls._state = own + ("_p", "_p_is_default")
        if cls._touched is not None:
            cls._touched = tuple(name for name in cls._touched if name not in ("_p", "_p_is_default")) + ("_p", "_p_is_default")

    def _init_contract(self, model, p_buffer: np.ndarray | None = None) -> None:
        """Called by a filter's __init__: the model, the parameter buffer (the model's defaults) and the lock."""
        self.model = model
        self._p = np.array(model.p_default, dtype=np.float64) if p_buffer is None else p_buffer
        self._p[:] = model.p_default
        self._p_is_default = True
        self._lock = threading.Lock()
        self._declared_max_dt = declared_max_dt(model)
        self._max_dt = math.inf if self._declared_max_dt is None else self._declared_max_dt

    @property
    def x(self) -> np.ndarray:
        """The state estimate (n_x,), a copy (filters keep it in ``_x``)."""
        return self._x.copy()

    @property
    def P(self) -> np.ndarray:
        """Its covariance (n_x, n_x), a copy (filters keep it in ``_P``)."""
        return self._P.copy()

    @property
    def p(self) -> np.ndarray:
        """The model parameters of the current (or last) call: the filter's buffer, bound to its generated
        calls (read it; a call's p argument is the way to change it)."""
        return self._p

    # ---------------------------------------------------------------- the public calls
    def predict(self, u, dt, p=None) -> None:
        """Move the estimate over dt with input u (and parameters p; None: the model's defaults)."""
        if not self._lock.acquire(False):
            raise self._busy()
        try:
            self._predict_call(u, dt, p)
        except NUMERICAL_FAILURES as error:
            raise self._numerical_failure(error) from error
        finally:
            self._lock.release()
        if dt > self._max_dt:  # (the call accepted dt: a positive finite real number)
            self._warn_long_step(dt)

    def update(self, z, p=None) -> bool:
        """Correct the estimate with the present (finite) entries of z; False (nothing changed) when z is
        None or all NaN, or when every entry was left out (an innovation gate)."""
        if not self._lock.acquire(False):
            raise self._busy()
        try:
            return self._update_call(z, p)
        except NUMERICAL_FAILURES as error:
            raise self._numerical_failure(error) from error
        finally:
            self._lock.release()

    def step(self, u, dt, z=None, p=None) -> bool:
        """predict(u, dt, p) then update(z, p) as one transaction; returns whether an update happened."""
        if not self._lock.acquire(False):
            raise self._busy()
        try:
            updated = self._step_call(u, dt, z, p)
        except NUMERICAL_FAILURES as error:
            raise self._numerical_failure(error) from error
        finally:
            self._lock.release()
        if dt > self._max_dt:  # (the call accepted dt: a positive finite real number)
            self._warn_long_step(dt)
        return updated

    def run(self, U, Z, dt, params=None, truth=None) -> FilterResult:
        """Filter a whole sequence (see ``run_filter``)."""
        return run_filter(self, U, Z, dt, params, truth)

    # ---------------------------------------------------------------- the transaction
    def _predict_call(self, u, dt, p) -> None:
        u, dt, p = check_u(u, self.model.n_u), check_dt(dt), check_p(p, self.model)
        self._transaction(self._advance, (u, dt, None), p)

    def _update_call(self, z, p) -> bool:
        measurement, p = check_z(z, self.model.n_y), check_p(p, self.model)
        if measurement is None:
            return False
        return self._transaction(self._advance, (None, None, measurement), p)

    def _step_call(self, u, dt, z, p) -> bool:
        u, dt = check_u(u, self.model.n_u), check_dt(dt)
        measurement, p = check_z(z, self.model.n_y), check_p(p, self.model)
        return self._transaction(self._advance, (u, dt, measurement), p)

    def _transaction(self, hook, args, p):
        names = self._state if self._touched is None else self._touched
        saved = {name: _copy(getattr(self, name)) for name in names}
        try:
            self._set_p(p)
            result = hook(*args)
            if self._touched is None:  # (a filter that narrows _touched checks before its commit: _check_finite)
                self._check_finite(self._x, self._P, *args)
            return result
        except BaseException:
            for name in names:
                _put(self, name, saved[name])
            raise

    def _check_finite(self, x: np.ndarray, P: np.ndarray, u, dt, measurement) -> None:
        """Finite in, finite out: a step whose estimate x or covariance P is not finite is refused (ValueError
        naming the call and its arguments). The transaction runs it after the hook for a filter that snapshots
        its whole state; a filter that narrows ``_touched`` (its commit is the hook's last line) calls it on
        the new x, P (for particle filters the weighted moments, non-finite whenever a weighted particle or a
        weight is) before that line; the compiled SIR step checks its moments itself and such a filter calls
        it only when the step reports them not finite (its NONFINITE_MOMENTS status)."""
        if _finite(x) and (_finite(P) if P.ndim == 1 else _finite(P.reshape(-1))):
            return
        call = "update" if u is None else ("predict" if measurement is None else "step")
        culprits = {"predict": "u, dt or p", "update": "z or p", "step": "u, dt, z or p"}[call]
        bad = [name for name, value in (("x", x), ("P", P)) if not np.all(np.isfinite(value))]
        raise ValueError(f"{type(self).__name__}.{call}: the result is not finite ({' and '.join(bad)} with non-finite "
                         f"entries): {culprits} drive the filter out of its finite range; state left unchanged")

    def _set_p(self, p) -> None:
        """p (checked) into the parameter buffer; None: the model's defaults (copied only when they changed)."""
        if p is None:
            if not self._p_is_default:
                self._p[:] = self.model.p_default
                self._p_is_default = True
        else:
            self._p[:] = p
            self._p_is_default = False

    def _advance(self, u, dt, measurement) -> bool:
        if u is not None:
            self._predict(u, dt)
        return False if measurement is None else self._update(*measurement)

    def _predict(self, u, dt) -> None:
        raise NotImplementedError(f"{type(self).__name__} implements neither _advance nor _predict")

    def _update(self, z, present) -> bool:
        raise NotImplementedError(f"{type(self).__name__} implements neither _advance nor _update")

    # ---------------------------------------------------------------- checkpoints that travel
    def checkpoint(self) -> dict:
        """An opaque copy of everything the filter holds and reports, with what it belongs to (CHECKPOINT_HEADER: the
        filter's kind, its model's name and id, its sizes and options). Plain data: it pickles, and restores into a
        filter of the same kind, model, sizes and options in another process, bit for bit."""
        state = super().checkpoint()
        state[CHECKPOINT_HEADER] = self._checkpoint_identity()
        return state

    def restore(self, checkpoint: dict) -> None:
        """Put a checkpoint of this filter (or of one of the same kind, model, sizes and options) back; any other is
        refused, naming what differs, and the filter is left unchanged."""
        self._check_checkpoint(checkpoint)
        super().restore(checkpoint)

    def _checkpoint_identity(self) -> dict:
        model = self.model
        manifest = getattr(model, "manifest", None) or {}
        sizes = {name: int(getattr(model, name)) for name in ("n_x", "n_u", "n_y", "n_p") if hasattr(model, name)}
        return {"kind": type(self).__name__, "model": str(getattr(model, "name", type(model).__name__)),
                "model id": manifest.get("model_id") or manifest.get("equations_sha256"),
                "sizes": {**sizes, **self._checkpoint_sizes()}, "options": self._checkpoint_options()}

    def _checkpoint_sizes(self) -> dict:
        """Sizes of the filter's buffers beyond the model's (a filter with such buffers adds them)."""
        return {}

    def _checkpoint_options(self) -> dict:
        """The options a checkpoint must share with the filter it is restored into (default: ``self.options``)."""
        options = getattr(self, "options", None)
        return dict(options) if isinstance(options, dict) else {}

    def _check_checkpoint(self, checkpoint) -> None:
        """Refuse (ValueError, naming what differs; the filter unchanged) a checkpoint of another kind of filter,
        model, size or option set, or no checkpoint of a filter at all."""
        name = type(self).__name__
        if not isinstance(checkpoint, dict) or not isinstance(checkpoint.get(CHECKPOINT_HEADER), dict):
            raise ValueError(f"{name}.restore: refused, not a checkpoint of a filter (give what a filter's checkpoint() "
                             f"returned; got {type(checkpoint).__name__}); the filter is unchanged")
        theirs, ours = checkpoint[CHECKPOINT_HEADER], self._checkpoint_identity()
        differs = []
        for key in ("kind", "model", "model id", "sizes", "options"):
            a, b = theirs.get(key), ours[key]
            if isinstance(a, dict) and isinstance(b, dict):
                for item in sorted(set(a) | set(b), key=str):
                    if not _same(a.get(item, "(none)"), b.get(item, "(none)")):
                        differs.append(f"{key[:-1] if key.endswith('s') else key} {item} = {a.get(item, '(none)')!r} "
                                       f"(this filter: {b.get(item, '(none)')!r})")
            elif not _same(a, b):
                differs.append(f"{key} {a!r} (this filter: {b!r})")
        missing = [entry for entry in self._state if entry not in checkpoint]
        if missing and not differs:
            differs.append(f"entries {missing} are missing")
        if differs:
            raise ValueError(f"{name}.restore: refused, the checkpoint is of another filter: {'; '.join(differs)}; the "
                             "filter is unchanged")

    def _warn_long_step(self, dt, stacklevel: int = 3) -> None:
        """Once per filter: an accepted step (predict, step, run, predict_to) of dt beyond the model's declared max_dt.
        Every filter's calls compare dt with ``_max_dt`` and call this when it is longer; it then sets ``_max_dt`` to
        inf, so the filter says it once. stacklevel: the user's frame as seen from here."""
        self._max_dt = math.inf
        warnings.warn(f"{type(self).__name__}: dt = {float(dt):g} s is beyond the longest step model {self.model.name!r} "
                      f"declares, max_dt = {self._declared_max_dt:g} s (its envelope): its discretisation is not meant for "
                      "it (`abyssal verify` reports the longest step it is stable at); a step it cannot take in one piece "
                      "is subdivided or refused. Said once per filter.", LongStepWarning, stacklevel=stacklevel)

    def _busy(self) -> RuntimeError:
        return RuntimeError(f"{type(self).__name__} is being used from two threads at once; a filter is not thread-safe "
                            "(use one filter per thread, or serialise the calls with your own lock)")

    def _numerical_failure(self, error) -> ValueError:
        return ValueError(f"{type(self).__name__}: the step failed numerically ({error}): u, dt, z or p drive the model "
                          "out of its finite range; state left unchanged")


def _rows(value, T: int, n: int, name: str, *, allow_nan: bool = False) -> np.ndarray:
    A = real_array(value, name)
    if A.shape != (T, n):
        raise ValueError(f"{name} must have shape ({T}, {n}), got {A.shape}")
    bad = np.isinf(A) if allow_nan else ~np.isfinite(A)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        hint = "; use NaN for a missing entry" if allow_nan else ""
        raise ValueError(f"{name} has a non-finite entry at row {row}, column {col}: {A[row, col]}{hint}")
    return A


@dataclass
class RunArguments:
    """run()'s arguments, checked: U (T, n_u), Z (T, n_y) or None, dts (T,) floats, rows_p (T entries: None or
    (n_p,)), truth (T, n_x) or None; dt_each_row: dt was given per row (else one number for every row)."""

    U: np.ndarray
    Z: np.ndarray | None
    dts: list
    rows_p: list
    truth: np.ndarray | None
    dt_each_row: bool

    @property
    def has_data(self) -> np.ndarray:
        """(T,) bools: the rows of Z with a finite entry (the others are all NaN). Computed on use: the reduction
        costs ~10 µs, a noticeable share of a C-backed run of a few hundred rows that does not need it."""
        return np.zeros(self.U.shape[0], dtype=bool) if self.Z is None else np.isfinite(self.Z).any(axis=1)


def check_run_arguments(model, U, Z, dt, params=None, truth=None) -> RunArguments:
    """Every argument of run() checked before the first step (each refusal names the argument, row and column)."""
    U = real_array(U, "U")
    if U.ndim != 2 or U.shape[1] != model.n_u:
        raise ValueError(f"U must have shape (T, {model.n_u}), got {U.shape}")
    T = U.shape[0]
    U = _rows(U, T, model.n_u, "U")
    Z = None if Z is None else _rows(Z, T, model.n_y, "Z", allow_nan=True)
    each_row = isinstance(dt, np.ndarray) and dt.ndim == 1
    if each_row:
        if dt.shape != (T,):
            raise ValueError(f"dt must be a number or shape ({T},), got {dt.shape}")
        dts = [check_dt(float(d)) for d in real_array(dt, "dt")]
    else:
        dts = [check_dt(dt)] * T
    if params is None:
        rows_p = [None] * T
    else:
        A = real_array(params, "params")
        if A.shape == (model.n_p,):
            rows_p = [check_state(A, model.n_p, "params")] * T
        else:
            rows_p = list(_rows(A, T, model.n_p, "params"))
    if truth is not None:
        truth = _rows(truth, T, model.n_x, "truth")
    return RunArguments(U, Z, dts, rows_p, truth, each_row)


def run_filter(filt, U, Z, dt, params=None, truth=None) -> FilterResult:
    """For k < T: filt.step(U[k], dt[k], Z[k], params[k]); all-or-nothing.

    Every argument is checked before the first step. If a step is refused at row k, the filter
    is restored to its state before the call and the error (same type) names row k.
    """
    model = filt.model
    a = check_run_arguments(model, U, Z, dt, params, truth)
    U, Z, dts, rows_p, truth, has_data = a.U, a.Z, a.dts, a.rows_p, a.truth, a.has_data
    T = U.shape[0]
    n = model.n_x
    xs, Ps = np.empty((T, n)), np.empty((T, n, n))
    nis, dof = np.full(T, np.nan), np.zeros(T, dtype=int)
    ess, particles, times = np.empty(T), np.empty(T), np.empty(T)
    saved = filt.checkpoint()
    clock = time.perf_counter
    k = 0
    try:
        for k in range(T):
            t0 = clock()
            updated = filt.step(U[k], dts[k], Z[k] if has_data[k] else None, rows_p[k])
            times[k] = clock() - t0
            xs[k], Ps[k] = filt.x, filt.P
            if updated:
                nis[k], dof[k] = filt.nis, filt.nis_dof
            ess[k], particles[k] = filt.ess, filt.n_particles
    except (ValueError, TypeError, FloatingPointError, np.linalg.LinAlgError) as error:
        filt.restore(saved)
        raise type(error)(f"run: row {k} refused ({error}); the filter was restored to its state before run") from error
    return FilterResult(x=xs, P=Ps, nis=nis, nis_dof=dof, nees=result_nees(model, truth, xs, Ps), ess=ess,
                        particles=particles, step_time=times)


def result_nees(model, truth, xs: np.ndarray, Ps: np.ndarray) -> np.ndarray | None:
    """The NEES of a run's estimates against the truth (None without one)."""
    return None if truth is None else _nees(truth, xs, Ps, angle_indices(model, "states"))


def _nees(truth: np.ndarray, xs: np.ndarray, Ps: np.ndarray, angle_states) -> np.ndarray:
    """e^T P^-1 e per step, e = truth - x with angle states wrapped (numerics.nees: floored eigenvalues)."""
    return nees(wrap_angles(truth - xs, angle_states), Ps)
