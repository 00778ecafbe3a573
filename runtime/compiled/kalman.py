"""The C runtime of the Kalman family (runtime/c, hand-written C99) as Python sees it: ctypes declarations, once.

    runtime = KalmanRuntime.of(bundle)     # the runtime with a model's descriptor
    runtime = KalmanRuntime.standalone()   # the runtime alone (the innovation gate needs no model)

The runtime is one library, compiled once through the cache (sources.KALMAN, strictly); a model's own library
holds its generated C and its descriptor ``<m>_descriptor`` (abyssal_model.h), whose address the runtime's calls
are given, so one runtime serves every model. InnovationGate objects of filters that run their own updates use the
same library without a descriptor.
The hot path of a Kalman filter does not go through ctypes: ``call_function(name)`` is one of the runtime's
CasADi-convention entry points (abyssal_kalman_binding.c: step, predict, update, check_p) loaded by
``casadi.external`` and bound once with ``Function.buffer()`` (the fast binding of every generated function,
bundle.py).

The option struct and the return codes below mirror abyssal_kalman.h (tests/runtime/test_kalman_runtime.py
checks the mirror against the C).
"""
from __future__ import annotations

import ctypes
from functools import lru_cache

import casadi as ca

from abyssal.generated.build import build

from .sources import KALMAN, sources

#: abyssal_filter of abyssal_kalman.h
FILTERS = {"ekf": 1, "ukf": 2, "ckf": 3, "mcukf": 4, "huber": 5}

#: abyssal_noise of abyssal_kalman.h: how Q accrues
NOISE = {"step": 0, "rate": 1, "inputs": 2}

# return codes of abyssal_kalman.h
UPDATED, OK = 1, 0
(E_MEMORY, E_MODEL, E_FILTER, E_SIGMA_POINTS, E_ROBUST, E_GATE, E_SUBSTEPS, E_X0, E_P0, E_Q, E_R, E_U, E_DT, E_Z, E_P,
 E_DIVERGED, E_UNSTABLE, E_STATE, E_UNSTABLE_INPUT, E_SENSOR, E_TIME, E_TOO_LATE, E_LIVE, E_UNSTABLE_STATE,
 E_OPTIONS) = range(-1, -26, -1)

#: the calls of abyssal_kalman_binding.c (abyssal_kalman_<name>_call)
CALLS = ("step", "predict", "update", "check_p", "predict_to", "update_sensor")
#: the call block's leading slots (abyssal_kalman_binding.c): [model, dt or t, sensor, has_R, has_q], then u, z, p, R, q
BLOCK_MODEL, BLOCK_TIME, BLOCK_SENSOR, BLOCK_HAS_R, BLOCK_HAS_Q, BLOCK_HEAD = range(6)

# items of abyssal_kalman_offset (four buffer sets of x and P, two report buffers)
SETS = 4
(AT_X, AT_P, AT_INNOVATION, AT_S, AT_Q, AT_R, AT_GATE, AT_CURRENT, AT_REPORTED, AT_NIS, AT_NIS_DOF, AT_REPAIRS,
 AT_SUBSTEPS, AT_STATE_BYTES, AT_TIME, AT_SENSORS, AT_REPORTED_ROWS, AT_REPORTED_SENSOR, AT_INFLATIONS, AT_LATE,
 AT_HISTORY) = (0, 4, 8, 10, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28)
#: the per-sensor block at AT_SENSORS: its fields, in order (ABYSSAL_SENSOR_*)
SENSOR_FIELDS = ("used", "gated", "inflations", "rejected", "streak_inflations", "nis", "nis_dof", "last_t", "late")


class Options(ctypes.Structure):
    """abyssal_kalman_options."""

    _fields_ = [("filter", ctypes.c_int), ("alpha", ctypes.c_double), ("beta", ctypes.c_double),
                ("kappa", ctypes.c_double), ("sigma", ctypes.c_double), ("gamma", ctypes.c_double),
                ("huber_iterations", ctypes.c_int), ("gate_probability", ctypes.c_double), ("gate_patience", ctypes.c_int),
                ("gate_inflation", ctypes.c_double), ("gate_max_inflations", ctypes.c_int),
                ("growth_limit", ctypes.c_double), ("max_substeps", ctypes.c_int), ("repair_floor", ctypes.c_double),
                ("noise", ctypes.c_int), ("history_entries", ctypes.c_int), ("history_seconds", ctypes.c_double),
                ("smoothing", ctypes.c_int)]


class GateHeader(ctypes.Structure):
    """abyssal_gate (abyssal_kalman_gate.h): its counters are read through views of these offsets."""

    _fields_ = [("magic", ctypes.c_ulonglong), ("m", ctypes.c_int), ("patience", ctypes.c_int),
                ("probability", ctypes.c_double), ("inflation", ctypes.c_double), ("gated", ctypes.c_longlong),
                ("inflations", ctypes.c_longlong), ("streaking", ctypes.c_longlong), ("thresholds", ctypes.c_longlong),
                ("streak", ctypes.c_longlong), ("bytes", ctypes.c_longlong)]


_P, _I, _D, _LL, _SZ = ctypes.c_void_p, ctypes.c_int, ctypes.c_double, ctypes.c_longlong, ctypes.c_size_t
_SIGNATURES = {
    "abyssal_kalman_default_options": (Options, [_I]),
    "abyssal_kalman_check_options": (_I, [_P, ctypes.POINTER(Options)]),
    "abyssal_kalman_work_size": (_SZ, [_P, ctypes.POINTER(Options)]),
    "abyssal_kalman_init": (_I, [_P, _SZ, _P, ctypes.POINTER(Options), _P, _P, _P, _P, _D, _P]),
    "abyssal_kalman_release": (None, [_P]),
    "abyssal_kalman_reset": (_I, [_P, _P, _P]),
    "abyssal_kalman_set_Q": (_I, [_P, _P]),
    "abyssal_kalman_set_R": (_I, [_P, _P]),
    "abyssal_kalman_set_sensor_R": (_I, [_P, _P, _I, _P]),
    "abyssal_kalman_smooth": (_I, [_P, _P, _P, _P, _I, ctypes.POINTER(_I)]),
    "abyssal_rts_step": (_I, [_I, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P]),
    "abyssal_kalman_model_id": (ctypes.c_ulonglong, [_P]),
    "abyssal_kalman_sensor_index": (_I, [_P, ctypes.c_char_p]),
    "abyssal_kalman_offset": (_LL, [_P, _I]),
    "abyssal_kalman_message": (ctypes.c_char_p, [_I]),
    "abyssal_gate_size": (_SZ, [_I]),
    "abyssal_gate_init": (_I, [_P, _SZ, _I, _D, _I, _D, _P]),
    "abyssal_gate_threshold": (_D, [_P, _I]),
    "abyssal_gate_judge": (_I, [_P, _I, _P, _P, _P, _P, _P, _P]),
    "abyssal_gate_note": (_I, [_P, _P, _P]),
    "abyssal_gate_accepted_all": (None, [_P]),
    "abyssal_chi2_isf": (_D, [_D, _I]),
    "abyssal_nis": (_D, [_I, _P, _P, _P]),
    "abyssal_repair_covariance": (_I, [_I, _P, _P, _D, _P, _P]),
    "abyssal_covariance_problem": (_I, [_I, _P, _I, _P]),
}


class KalmanRuntime:
    """The runtime's C functions in one library (attributes named as in C without the ``abyssal_`` prefix)."""

    def __init__(self, library: str, descriptor: int | None):
        self.library = library
        self.cdll = ctypes.CDLL(library)
        for name, (restype, argtypes) in _SIGNATURES.items():
            fn = getattr(self.cdll, name)
            fn.restype, fn.argtypes = restype, argtypes
            setattr(self, name.removeprefix("abyssal_"), fn)
        #: the address of the model's descriptor (None for the standalone runtime)
        self.descriptor = descriptor
        self._calls: dict[str, ca.Function] = {}

    @classmethod
    def of(cls, bundle) -> "KalmanRuntime":
        """The runtime with the descriptor of a model bundle (abyssal.generated.load): None when its folder has none."""
        return _of(str(bundle.library), bundle.name)

    @staticmethod
    def standalone() -> "KalmanRuntime":
        """The runtime compiled alone (through the compile cache): the gate, chi-square quantiles, repair."""
        return _standalone()

    def message(self, code: int) -> str:
        return self.kalman_message(int(code)).decode()

    def options(self, filter_name: str, **values) -> Options:
        """The defaults of a filter with `values` (floats and ints as the struct's fields) set."""
        options = self.kalman_default_options(FILTERS[filter_name])
        for name, value in values.items():
            setattr(options, name, value)
        return options

    def call_function(self, name: str) -> ca.Function:
        """``abyssal_kalman_<name>_call`` (abyssal_kalman_binding.c; name in CALLS) as a CasADi Function: arguments
        (filter memory, call block [model, dt or t, sensor, has_R, has_q, u, z, p, R, q]), result (the return code);
        bind it with ``.buffer()``."""
        if name not in self._calls:
            self._calls[name] = ca.external(f"abyssal_kalman_{name}_call", self.library)
        return self._calls[name]


@lru_cache(maxsize=None)
def _of(model_library: str, model: str) -> KalmanRuntime:
    cdll = ctypes.CDLL(model_library)
    try:
        address = ctypes.addressof(ctypes.c_char.in_dll(cdll, f"{model}_descriptor"))
    except ValueError:
        address = None
    runtime = KalmanRuntime(_library(), address)
    runtime.model_library = cdll  # the descriptor's library stays loaded while the runtime points into it
    return runtime


@lru_cache(maxsize=1)
def _library() -> str:
    return str(build("abyssal_kalman", sources(KALMAN), strict=True))


@lru_cache(maxsize=1)
def _standalone() -> KalmanRuntime:
    return KalmanRuntime(_library(), None)


__all__ = ["FILTERS", "GateHeader", "KalmanRuntime", "Options"]
