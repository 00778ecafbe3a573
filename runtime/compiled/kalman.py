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
bundle.py). A filter's plain ``step(u, dt, z)`` and ``update(sensor, z, t)`` go one step shorter: ``one_calls``
makes each a CPython extension object (abyssal_kalman_python.c, built through the same cache against the running
Python's headers) that copies the arguments into the call block and calls the runtime itself, with no Python frame;
where the headers are missing there are none and the class's methods take the CasADi binding, with the same results.

The option struct and the return codes below mirror abyssal_kalman.h (tests/runtime/test_kalman_runtime.py
checks the mirror against the C).
"""
from __future__ import annotations

import ctypes
import functools
import importlib.machinery
import importlib.util
import sys
import sysconfig
from functools import lru_cache
from pathlib import Path

import numpy as np

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
SENSOR_FIELDS = ("used", "gated", "inflations", "rejected", "streak_inflations", "nis", "nis_dof", "accepted",
                 "accepted_at_streak", "last_t", "late")


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
    "abyssal_steps_batch_scratch_bytes": (_SZ, [_P, _I]),
    "abyssal_kalman_run": (_I, [_P, _P, _LL, _P, _P, _I, _P, _P, _I, _P, _P, _P, _P, ctypes.POINTER(_LL)]),
    "abyssal_steps_batch": (_I, [_P, _I, _I, _P, _LL, _P, _P, _P, _P]),
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

    def one_calls(self, memory: np.ndarray, block: np.ndarray, code: np.ndarray, sensors: dict[str, int], owner) -> dict:
        """The filter `owner`'s plain step(u, dt, z) and update(sensor, z, t) as one C call each (abyssal_kalman_python.c),
        for its filter object `memory`, call block `block` and return code's place `code` (`sensors`: name -> index):
        {"step": StepCall, "update": UpdateCall}, to be installed as the owner's own attributes; every other case of
        each goes to the owner's class method. Empty when the extension cannot be built here (no Python headers)."""
        module = _python_module()
        if module is None:
            return {}
        common = (owner._lock.locked, np.float64, owner.__dict__)
        return {"step": module.StepCall(memory, block, code, self._address("step"), self._address("predict"), None,
                                        *common, type(owner).step.__get__(owner), owner._refusal, owner._warn_long_step),
                "update": module.UpdateCall(memory, block, code, self._address("update_sensor"), self._address("time"),
                                            sensors, *common, type(owner).update.__get__(owner), owner._sensor_refusal,
                                            owner._warn_long_step)}

    def _address(self, name: str) -> int:
        """The address of abyssal_kalman_<name> in the runtime's library."""
        return ctypes.cast(getattr(self.cdll, f"abyssal_kalman_{name}"), ctypes.c_void_p).value


#: the batched steps (abyssal_kalman_steps.h): name -> (filter, op, inputs, outputs) with the shapes of each input
#: and output as functions of (n_x, n_u, n_p, n_y); the names and argument orders are those of the generated steps
#: they replace
_VEC, _MAT = "vector", "matrix"
_PREDICT_IN = (("x", "x"), ("P", "xx"), ("u", "u"), ("p", "p"), ("dt", "1"), ("Q", "xx"))
_UPDATE_IN = (("x", "x"), ("P", "xx"), ("z", "y"), ("p", "p"), ("R", "yy"), ("mask", "y"))
_PREDICT_OUT = (("x_pred", "x"), ("P_pred", "xx"), ("ok", "1"))
_UPDATE_OUT = (("x_post", "x"), ("P_post", "xx"), ("innovation", "y"), ("S", "yy"), ("ok", "1"))
BATCH_PREDICT, BATCH_UPDATE, BATCH_STEP = 0, 1, 2
BATCH_STEPS = {
    "ekf_predict": ("ekf", BATCH_PREDICT, _PREDICT_IN, _PREDICT_OUT),
    "ekf_update": ("ekf", BATCH_UPDATE, _UPDATE_IN, _UPDATE_OUT),
    "ckf_predict": ("ckf", BATCH_PREDICT, _PREDICT_IN, _PREDICT_OUT),
    "ckf_update": ("ckf", BATCH_UPDATE, _UPDATE_IN, _UPDATE_OUT),
    "ckf_step": ("ckf", BATCH_STEP, _PREDICT_IN + _UPDATE_IN[2:3] + _UPDATE_IN[4:], _UPDATE_OUT),
    "ukf_predict": ("ukf", BATCH_PREDICT, _PREDICT_IN + (("abk", "3"),), _PREDICT_OUT),
    "ukf_update": ("ukf", BATCH_UPDATE, _UPDATE_IN + (("abk", "3"),), _UPDATE_OUT),
    "mcukf_update": ("mcukf", BATCH_UPDATE, _UPDATE_IN + (("abk", "3"), ("sigma", "1")), _UPDATE_OUT),
    "huber_ukf_update": ("huber", BATCH_UPDATE, _UPDATE_IN + (("abk", "3"), ("gamma", "1")), _UPDATE_OUT),
}


class BatchStep:
    """One of the runtime's batched Kalman steps (BATCH_STEPS) on a model, with the calling convention of a
    generated function (abyssal.generated.bundle.CompiledFunction): ``bind_batch(inputs, outputs, capacity)`` for
    the particle and Gaussian-sum filters (compiled.batches.ParallelBatch), ``step(*args)`` for one evaluation.
    The algebra is the C runtime's (abyssal_steps_batch), the same that every Kalman filter runs."""

    def __init__(self, bundle, name: str):
        from abyssal.generated.bundle import Signature

        if name not in BATCH_STEPS:
            raise ValueError(f"no batched step {name!r}; the runtime has {sorted(BATCH_STEPS)}")
        runtime = KalmanRuntime.of(bundle)
        if runtime.descriptor is None:
            raise ValueError(f"{bundle.name}: its folder has no descriptor (generated by an older abyssal): regenerate it")
        kind, self._op, inputs, outputs = BATCH_STEPS[name]
        sizes = {"x": (bundle.n_x, 1), "xx": (bundle.n_x, bundle.n_x), "u": (bundle.n_u, 1), "p": (bundle.n_p, 1),
                 "y": (bundle.n_y, 1), "yy": (bundle.n_y, bundle.n_y), "1": (1, 1), "3": (3, 1)}
        self.name = f"{bundle.name}_{name}"
        self.inputs = tuple(Signature(n, sizes[shape]) for n, shape in inputs)
        self.outputs = tuple(Signature(n, sizes[shape]) for n, shape in outputs)
        self._runtime, self._filter = runtime, FILTERS[kind]
        self._scratch_bytes = int(runtime.steps_batch_scratch_bytes(runtime.descriptor, self._filter))

    def __repr__(self):
        return f"<BatchStep {self.name} (the C runtime's)>"

    def bind_batch(self, inputs, outputs, capacity: int):
        """Bind buffers for up to `capacity` slices (an input of its plain shape is shared by every slice)."""
        from abyssal.generated.bundle import BatchBinding, _batch_buffer

        ins = [_batch_buffer(a, s, capacity, f"{self.name} input") for a, s in zip(inputs, self.inputs, strict=True)]
        outs = [_batch_buffer(a, s, capacity, f"{self.name} output", output=True)
                for a, s in zip(outputs, self.outputs, strict=True)]
        for (_, step), s in zip(outs, self.outputs):
            if step == 0 and capacity > 1:
                raise ValueError(f"{self.name} output {s.name!r}: a batch output needs one slice per column")
        n_in, n_out = len(ins), len(outs)
        arg_ptrs = (ctypes.c_void_p * n_in)(*[a.ctypes.data for a, _ in ins])
        arg_steps = (ctypes.c_longlong * n_in)(*[st for _, st in ins])
        res_ptrs = (ctypes.c_void_p * n_out)(*[a.ctypes.data for a, _ in outs])
        res_steps = (ctypes.c_longlong * n_out)(*[st for _, st in outs])
        scratch = np.zeros(self._scratch_bytes // 8 + 1)  # each binding (a ParallelBatch chunk) its own
        call = functools.partial(self._runtime.steps_batch, self._runtime.descriptor, self._filter, self._op,
                                 scratch.ctypes.data)
        return BatchBinding(call, self.name, arg_ptrs, arg_steps, res_ptrs, res_steps, capacity,
                            (ins, outs, list(inputs), list(outputs), scratch))

    def __call__(self, *args):
        """One evaluation: vectors (n,), matrices (r, c); returns the outputs (new arrays, a tuple)."""
        if len(args) != len(self.inputs):
            raise TypeError(f"{self.name} takes {len(self.inputs)} arguments ({', '.join(s.name for s in self.inputs)})")
        ins = [np.asfortranarray(np.asarray(a, dtype=np.float64).reshape(s.shape, order="F")) for a, s in
               zip(args, self.inputs)]
        outs = [np.zeros(s.shape, order="F") for s in self.outputs]
        self.bind_batch(ins, outs, 1)(1)
        for o, s in zip(outs, self.outputs):
            if not np.isfinite(o).all():
                raise FloatingPointError(f"{self.name}: output {s.name!r} is not finite at the given arguments")
        return tuple(o.reshape(s.shape[0]) if s.shape[1] == 1 else o for o, s in zip(outs, self.outputs))


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
def _python_module():
    """The extension module abyssal_kalman_python, built for the running Python; None without its headers."""
    include = Path(sysconfig.get_paths()["include"])
    if not (include / "Python.h").is_file():
        return None
    texts = sources([name for name in KALMAN if name.endswith(".h")] + ["abyssal_kalman_python.c"])
    # the interpreter it is built for, into the key (the headers' folder alone may serve several patch releases)
    texts["abyssal_kalman_python_abi.h"] = f"/* {sys.implementation.cache_tag} {sysconfig.get_config_var('EXT_SUFFIX')} " \
                                           f"{sys.version.split()[0]} */\n"
    library = build("abyssal_kalman_python", texts, strict=True, include_dirs=(include,))
    name = "abyssal_kalman_python"
    loader = importlib.machinery.ExtensionFileLoader(name, str(library))
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(name, loader))
    loader.exec_module(module)
    return module


@lru_cache(maxsize=1)
def _standalone() -> KalmanRuntime:
    return KalmanRuntime(_library(), None)


__all__ = ["BATCH_STEPS", "BatchStep", "FILTERS", "GateHeader", "KalmanRuntime", "Options"]
