"""Calling compiled generated functions from Python.

Two paths:

* Convenience calls (``bundle.f(x, u, p, dt)``, ``fn(*args)``) check every argument (shape,
  dtype, finiteness; complex is a TypeError), evaluate on private buffers and return new NumPy
  arrays (~15-25 us, mostly the checks); a non-finite output is a FloatingPointError. The batch
  convenience calls (``f_batch``, ``h_batch``, ``fn.batch``) check the same and name the
  offending columns; the finiteness check is one reduction over the outputs.
* The fast path: ``fn.bind(inputs, outputs)`` fixes preallocated float64 buffers once and
  returns a zero-argument callable that evaluates the C function in place through
  ``casadi.external`` + ``Function.buffer()`` (measured ~0.2 us per call; ctypes was ~0.6 us).
  ``fn.bind_batch(...)`` does the same for the ``<name>_batch`` entry point over N slices, N
  chosen per call (any function; one scalar C call per slice, bitwise equal to ``fn``).
  ``fn.bind_soa(...)`` binds the SIMD structure-of-arrays kernel of ``f`` and ``h`` (4x faster
  on rov4dof; equal to ``fn`` up to the last bits of libmvec's sin/cos). Bindings keep their
  arrays alive; filters hold them for their lifetime. Bindings never copy a buffer (a
  non-contiguous one is refused, also when shared by a batch), refuse read-only outputs, and do
  not check finiteness: their callers do, once per step.

Layout: CasADi stores matrices column-major. A matrix buffer is a Fortran-ordered array of
the declared shape. For ``bind_batch`` a batch of N vectors of size n is an (n, N)
Fortran-ordered array (each column contiguous) and a batch of N matrices (r, c) an (r, c, N)
Fortran-ordered array; for ``bind_soa`` a batch is an (n, N) C-ordered array (each row
contiguous, one column per particle), the layout of ``f_batch``.
"""
from __future__ import annotations

import ctypes
import threading
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from abyssal.arrays import real_array


@dataclass(frozen=True)
class Signature:
    name: str
    shape: tuple[int, int]

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]


def _writable(arr: np.ndarray, sig: Signature, what: str) -> None:
    if not arr.flags.writeable:
        raise ValueError(f"{what} {sig.name!r}: buffer is read-only (the function writes its result there); "
                         "pass a writable float64 array")


def _all_finite(arr: np.ndarray) -> bool:
    """Whether every entry is finite. For large arrays a finite sum proves it (one pass, no
    temporary; only a non-finite or overflowing sum pays for the exact check)."""
    if arr.size < 1 << 16:
        return bool(np.isfinite(arr).all())
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(np.add.reduce(arr, axis=None)):
            return True
    return bool(np.isfinite(arr).all())


def _finite_columns(name: str, outs, sigs, n: int) -> None:
    """FloatingPointError naming the output and its columns (last axis) with a non-finite entry."""
    for out, sig in zip(outs, sigs):
        if _all_finite(out):
            continue
        bad = np.flatnonzero(~np.isfinite(out).all(axis=tuple(range(out.ndim - 1))))
        if bad.size:
            shown = ", ".join(map(str, bad[:10])) + (f", ... ({bad.size} columns)" if bad.size > 10 else "")
            raise FloatingPointError(f"{name}: output {sig.name!r} is not finite in column(s) {shown} of {n} "
                                     "(at those columns' arguments)")


def _as_buffer(arr: np.ndarray, sig: Signature, what: str, output: bool = False) -> np.ndarray:
    """1-D float64 view of a preallocated buffer, in CasADi's column-major order."""
    if not isinstance(arr, np.ndarray) or arr.dtype != np.float64:
        raise TypeError(f"{what} {sig.name!r}: expected a float64 numpy array, got {type(arr).__name__}"
                        + (f" of {arr.dtype}" if isinstance(arr, np.ndarray) else ""))
    if output:
        _writable(arr, sig, what)
    if arr.size != sig.size:
        raise ValueError(f"{what} {sig.name!r}: expected {sig.size} elements (shape {sig.shape}), got shape {arr.shape}")
    if arr.ndim <= 1 or (arr.ndim == 2 and 1 in sig.shape):
        if not arr.flags.c_contiguous:
            raise ValueError(f"{what} {sig.name!r}: buffer must be contiguous")
        return arr.reshape(-1)
    if arr.shape != sig.shape or not arr.flags.f_contiguous:
        raise ValueError(f"{what} {sig.name!r}: matrix buffer must be a Fortran-ordered array of shape {sig.shape}")
    return arr.reshape(-1, order="F")


def _batch_buffer(arr: np.ndarray, sig: Signature, n: int, what: str, output: bool = False) -> tuple[np.ndarray, int]:
    """(buffer, step) of a batch argument, bound in place (never a private copy).

    A batch has one more axis than the argument: (rows, N) for a vector, (rows, cols, N) for a
    matrix, Fortran-ordered. Anything else of the argument's own size is shared (step 0), and
    must be contiguous like a ``bind`` buffer: later writes to it are seen by the next call.
    """
    if not isinstance(arr, np.ndarray) or arr.dtype != np.float64:
        raise TypeError(f"{what} {sig.name!r}: expected a float64 numpy array")
    if output:
        _writable(arr, sig, what)
    batch_ndim = 2 if sig.shape[1] == 1 else 3
    if (arr.ndim < batch_ndim and arr.size == sig.size) or (arr.shape == sig.shape and not (output and n > 1)):
        return _as_buffer(arr, sig, what), 0  # (rows, 1) is the declared shape: shared, not a batch of one
    want = (sig.shape[0],) if sig.shape[1] == 1 else sig.shape
    if arr.ndim != batch_ndim or arr.shape[:-1] != want or arr.shape[-1] < n:
        raise ValueError(
            f"{what} {sig.name!r}: expected shape {sig.shape} (shared) or a batch of shape "
            f"{(*want, 'N')} with N >= {n}, got {arr.shape}"
        )
    if not arr.flags.f_contiguous:
        raise ValueError(f"{what} {sig.name!r}: batch buffer must be Fortran-ordered (each slice contiguous)")
    return arr.reshape(-1, order="F"), sig.size


class Binding:
    """A compiled function bound to fixed buffers; calling it evaluates in place.

    ``eval`` is the bare zero-argument evaluation for hot loops; it pins its own buffers.
    """

    def __init__(self, eval_fn):
        self.eval = eval_fn

    def __call__(self) -> None:
        self.eval()


class BatchBinding:
    """The ``_batch`` entry point bound to fixed buffers; ``binding(N)`` evaluates N slices."""

    def __init__(self, fn, name, arg_ptrs, arg_steps, res_ptrs, res_steps, capacity, keep):
        self._fn = fn
        self._name = name
        self._args = (arg_ptrs, arg_steps, res_ptrs, res_steps)
        self._keep = keep
        self.capacity = capacity

    def __call__(self, n: int) -> None:
        if not 0 <= n <= self.capacity:
            raise ValueError(f"{self._name}: batch size {n} outside 0..{self.capacity} of the bound buffers")
        status = self._fn(ctypes.c_longlong(n), *self._args)
        if status:
            raise FloatingPointError(f"{self._name}: evaluation of slice {status - 1} failed")


class SoaBinding:
    """The ``_soa`` kernel bound to fixed buffers; ``binding(N)`` evaluates particles 0..N-1."""

    def __init__(self, fn, name, arg_ptrs, res_ptrs, ld, keep):
        self._fn = fn
        self._name = name
        self._ptrs = (arg_ptrs, res_ptrs)
        self._ld = ctypes.c_longlong(ld)
        self._keep = keep
        self.capacity = ld

    def __call__(self, n: int) -> None:
        if not 0 <= n <= self.capacity:
            raise ValueError(f"{self._name}: batch size {n} outside 0..{self.capacity} of the bound buffers")
        self._fn(ctypes.c_longlong(n), self._ld, *self._ptrs)


class CompiledFunction:
    """One generated function in a compiled library."""

    def __init__(self, name: str, library: Path, cdll: ctypes.CDLL, spec: dict):
        self.name = name
        self.library = library
        self.inputs = tuple(Signature(s["name"], tuple(s["shape"])) for s in spec["inputs"])
        self.outputs = tuple(Signature(s["name"], tuple(s["shape"])) for s in spec["outputs"])
        self.spec = spec
        self.external = ca.external(name, str(library))
        self._batch = getattr(cdll, name + "_batch")
        self._batch.restype = ctypes.c_int
        #: names of the inputs that vary per particle in the SIMD structure-of-arrays kernel, if any
        self.soa_batched_inputs = tuple(spec.get("soa_batched_inputs", ()))
        self._soa = getattr(cdll, name + "_soa") if self.soa_batched_inputs else None
        self._scratch_binding = None
        self._lock = threading.Lock()
        if self.external.n_in() != len(self.inputs) or self.external.n_out() != len(self.outputs):
            raise RuntimeError(f"{name}: compiled library disagrees with its manifest; run `abyssal regenerate`")

    def __repr__(self):
        ins = ", ".join(f"{s.name}{s.shape}" for s in self.inputs)
        outs = ", ".join(f"{s.name}{s.shape}" for s in self.outputs)
        return f"<CompiledFunction {self.name}({ins}) -> ({outs})>"

    # ---------------------------------------------------------------- fast path
    def bind(self, inputs, outputs) -> Binding:
        """Bind preallocated float64 buffers (see module docstring for layout)."""
        if len(inputs) != len(self.inputs) or len(outputs) != len(self.outputs):
            raise ValueError(f"{self.name}: expected {len(self.inputs)} inputs and {len(self.outputs)} outputs")
        ins = [_as_buffer(a, s, f"{self.name} input") for a, s in zip(inputs, self.inputs)]
        outs = [_as_buffer(a, s, f"{self.name} output", output=True) for a, s in zip(outputs, self.outputs)]
        buffer, eval_fn = self.external.buffer()
        for i, a in enumerate(ins):
            buffer.set_arg(i, memoryview(a))
        for i, a in enumerate(outs):
            buffer.set_res(i, memoryview(a))
        # eval_fn (a functools.partial) only holds a raw pointer to `buffer`: pin the buffer and arrays
        # on it, so `fn.bind(...).eval` stays valid after the Binding itself is dropped.
        eval_fn.keep_alive = (buffer, ins, outs, list(inputs), list(outputs))
        return Binding(eval_fn)

    def bind_batch(self, inputs, outputs, capacity: int) -> BatchBinding:
        """Bind buffers for up to `capacity` slices; an input of its plain shape is shared by all slices."""
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
        return BatchBinding(self._batch, self.name, arg_ptrs, arg_steps, res_ptrs, res_steps, capacity,
                            (ins, outs, list(inputs), list(outputs)))

    def bind_soa(self, inputs, outputs) -> SoaBinding:
        """Bind buffers for the SIMD kernel: inputs named in `soa_batched_inputs` and all outputs are
        C-ordered (rows, L) arrays with one column per particle (the same L for all); others shared."""
        if self._soa is None:
            raise ValueError(f"{self.name} has no structure-of-arrays kernel (see codegen.SOA_KERNELS)")
        inputs, outputs = list(inputs), list(outputs)
        if len(inputs) != len(self.inputs) or len(outputs) != len(self.outputs):
            raise ValueError(f"{self.name}: expected {len(self.inputs)} inputs and {len(self.outputs)} outputs")
        lds = set()
        for arr, sig, batched in [(a, s, s.name in self.soa_batched_inputs) for a, s in zip(inputs, self.inputs)] + [
            (a, s, True) for a, s in zip(outputs, self.outputs)
        ]:
            if not batched:
                _as_buffer(arr, sig, f"{self.name} shared input")
                continue
            if (not isinstance(arr, np.ndarray) or arr.dtype != np.float64 or arr.ndim != 2
                    or arr.shape[0] != sig.size or not arr.flags.c_contiguous):
                raise ValueError(f"{self.name} {sig.name!r}: expected a C-ordered float64 array of shape ({sig.size}, N)")
            if any(arr is o for o in outputs):
                _writable(arr, sig, f"{self.name} output")
            lds.add(arr.shape[1])
        if len(lds) != 1:
            raise ValueError(f"{self.name}: batched buffers must share one number of columns, got {sorted(lds)}")
        arg_ptrs = (ctypes.c_void_p * len(inputs))(*[a.ctypes.data for a in inputs])
        res_ptrs = (ctypes.c_void_p * len(outputs))(*[a.ctypes.data for a in outputs])
        return SoaBinding(self._soa, self.name, arg_ptrs, res_ptrs, lds.pop(), (inputs, outputs))

    @property
    def soa_address(self) -> int:
        """Address of the C function ``<name>_soa`` (for runtime C that calls the kernel itself); the
        library stays loaded while this CompiledFunction lives."""
        if self._soa is None:
            raise ValueError(f"{self.name} has no structure-of-arrays kernel (see codegen.SOA_KERNELS)")
        return ctypes.cast(self._soa, ctypes.c_void_p).value

    @property
    def batch_address(self) -> int:
        """Address of the C function ``<name>_batch`` (n evaluations on strided slices, its work on its own stack: for
        runtime C that calls the function itself); the library stays loaded while this CompiledFunction lives."""
        return ctypes.cast(self._batch, ctypes.c_void_p).value

    # ---------------------------------------------------------- convenience path
    def _checked(self, value, sig: Signature) -> np.ndarray:
        """value as a flat column-major float64 array, after shape and finiteness checks."""
        arr = real_array(value, f"{self.name}: argument {sig.name!r}")
        if arr.shape not in (sig.shape, (sig.size,)) and not (sig.size == 1 and arr.ndim == 0):
            want = f"({sig.shape[0]},)" if sig.shape[1] == 1 else str(sig.shape)
            raise ValueError(f"{self.name}: argument {sig.name!r} must have shape {want}, got {arr.shape}")
        flat = arr.reshape(-1, order="F")
        if not np.isfinite(flat).all():
            raise ValueError(f"{self.name}: argument {sig.name!r} has non-finite entries")
        return flat

    def _shaped(self, flat: np.ndarray, sig: Signature) -> np.ndarray:
        if sig.shape[1] == 1:
            return flat.reshape(sig.shape[0])
        return flat.reshape(sig.shape, order="F")

    def _scratch(self):
        """One binding to private buffers, reused by every convenience call (under a lock)."""
        if self._scratch_binding is None:
            ins = [np.zeros(s.size) for s in self.inputs]
            outs = [np.zeros(s.size) for s in self.outputs]
            self._scratch_binding = (ins, outs, self.bind(ins, outs).eval)
        return self._scratch_binding

    def __call__(self, *args):
        """Evaluate once; vectors are (n,), matrices (r, c). Returns new arrays (one, or a tuple)."""
        if len(args) != len(self.inputs):
            raise TypeError(f"{self.name} takes {len(self.inputs)} arguments ({', '.join(s.name for s in self.inputs)})")
        checked = [self._checked(a, s) for a, s in zip(args, self.inputs)]
        with self._lock:
            ins, outs, evaluate = self._scratch()
            for buf, value in zip(ins, checked):
                buf[:] = value
            evaluate()
            results = tuple(self._shaped(o.copy(), s) for o, s in zip(outs, self.outputs))
        for r, s in zip(results, self.outputs):
            if not np.isfinite(r).all():
                raise FloatingPointError(f"{self.name}: output {s.name!r} is not finite at the given arguments")
        return results[0] if len(results) == 1 else results

    def batch(self, n: int, *args):
        """Evaluate over n slices; each argument is shared (its plain shape) or batched (last axis n).

        Returns outputs shaped (rows, n) for vector outputs and (rows, cols, n) for matrices.
        """
        if len(args) != len(self.inputs):
            raise TypeError(f"{self.name} takes {len(self.inputs)} arguments ({', '.join(s.name for s in self.inputs)})")
        ins = []
        for a, s in zip(args, self.inputs):
            arr = np.asfortranarray(real_array(a, f"{self.name}: argument {s.name!r}"))  # shapes are checked by bind_batch
            if not _all_finite(arr):
                raise ValueError(f"{self.name}: argument {s.name!r} has non-finite entries")
            ins.append(arr)
        outs = [np.zeros((s.shape[0], n) if s.shape[1] == 1 else (*s.shape, n), order="F") for s in self.outputs]
        self.bind_batch(ins, outs, n)(n)
        _finite_columns(f"{self.name} batch", outs, self.outputs, n)
        return outs[0] if len(outs) == 1 else tuple(outs)


class ModelBundle:
    """The compiled functions of one model, with its names, shapes and default parameters."""

    def __init__(self, manifest: dict, library: Path):
        self.manifest = manifest
        self.name = manifest["model"]
        self.library = library
        self.state_names = tuple(q["name"] for q in manifest["states"])
        self.input_names = tuple(q["name"] for q in manifest["inputs"])
        self.parameter_names = tuple(q["name"] for q in manifest["parameters"])
        self.noise_names = tuple(q["name"] for q in manifest["noises"])
        self.output_names = tuple(q["name"] for q in manifest["outputs"])
        self.angle_outputs = tuple(manifest["angle_outputs"])
        #: indices of states that are angles (the runtime wraps them to (-pi, pi])
        self.angle_states = tuple(manifest.get("angle_states", ()))
        #: "rk4" / "euler" (a discretised continuous model) or "discrete" (x_next given directly)
        self.discretisation = manifest["discretisation"]
        #: the operating envelope the manifest records: {"declared": bool, "states"/"inputs": name -> [low, high],
        #: "max_dt", "min_dt", "default_range"} (None: a manifest written before models declared envelopes)
        self.envelope = manifest.get("envelope")
        #: the folder the sources were read from (set by abyssal.generated.load)
        self.folder: Path | None = None
        self.n_x, self.n_u, self.n_p = len(self.state_names), len(self.input_names), len(self.parameter_names)
        self.n_w, self.n_y = len(self.noise_names), len(self.output_names)
        self.p_default = np.array([q["default"] for q in manifest["parameters"]], dtype=np.float64)
        self.p_default.setflags(write=False)
        #: the model's sensors (manifest "sensors": name, offset, p_offset, outputs, parameters, noise, angle_outputs,
        #: rate, latency, functions), in the order of the stacked measurement
        self.sensors = tuple(manifest.get("sensors", ()))
        self.sensor_names = tuple(s["name"] for s in self.sensors)
        self._cdll = ctypes.CDLL(str(library))
        prefix = self.name + "_"
        self.functions = {
            name[len(prefix):]: CompiledFunction(name, library, self._cdll, spec)
            for name, spec in sorted(manifest["functions"].items())
        }

    def sensor(self, name: str) -> dict:
        """The manifest's record of the sensor called name (KeyError listing the model's sensors)."""
        for s in self.sensors:
            if s["name"] == name:
                return s
        raise KeyError(f"model {self.name!r} has no sensor {name!r}; its sensors: {list(self.sensor_names)}")

    def __repr__(self):
        return (f"<ModelBundle {self.name}: {self.n_x} states, {self.n_u} inputs, {self.n_p} parameters, "
                f"{self.n_y} outputs; functions {', '.join(self.functions)}>")

    def function(self, name: str) -> CompiledFunction:
        try:
            return self.functions[name]
        except KeyError:
            raise KeyError(f"model {self.name!r} has no generated function {name!r}; it has {sorted(self.functions)}") from None

    @property
    def is_discrete(self) -> bool:
        return self.discretisation == "discrete"

    @property
    def defaults(self) -> dict[str, float]:
        """Parameter name -> default value, in vector order."""
        return dict(zip(self.parameter_names, self.p_default.tolist()))

    def parameter_table(self) -> str:
        """The parameters as a printable table: index, name, default, unit, description."""
        from abyssal.symbolic.model import parameter_table

        return parameter_table([(q["name"], q["default"], q["unit"], q["description"]) for q in self.manifest["parameters"]])

    def params(self, p=None, **by_name) -> np.ndarray:
        """The runtime parameter vector: defaults when p is None, else p checked for shape and finiteness.

        Entries can be set by name, on the defaults or on p: ``bundle.params(m=30.0)``; an unknown
        name is a KeyError listing the parameters.
        """
        if by_name:
            unknown = sorted(set(by_name) - set(self.parameter_names))
            if unknown:
                raise KeyError(f"model {self.name!r} has no parameter(s) {unknown}; its parameters: {list(self.parameter_names)}")
            base = self.params(p)
            for name, value in by_name.items():
                base[self.parameter_names.index(name)] = value
            if not np.all(np.isfinite(base)):
                raise ValueError(f"{self.name}: parameters {sorted(by_name)} must be finite")
            return base
        if p is None:
            return np.array(self.p_default)
        arr = real_array(p, f"{self.name}: p")
        if arr.shape != (self.n_p,):
            raise ValueError(f"{self.name}: p must have shape ({self.n_p},) [{', '.join(self.parameter_names)}], got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{self.name}: p has non-finite entries")
        return arr

    @staticmethod
    def _dt(dt) -> float:
        if dt is None:
            raise TypeError("dt (the step length in seconds) is required")
        real = (int, float, np.integer, np.floating)
        if (isinstance(dt, (bool, np.bool_)) or not isinstance(dt, (*real, np.ndarray))
                or (isinstance(dt, np.ndarray) and (dt.ndim or dt.dtype.kind not in "iuf"))):
            raise TypeError(f"dt must be a real number of seconds, got {type(dt).__name__} {dt!r}")
        dt = float(dt)
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive finite number of seconds, got {dt}")
        return dt

    def f(self, x, u, p=None, dt=None) -> np.ndarray:
        """One discrete step x_{k+1} = f(x_k, u_k, p, dt), shape (n_x,)."""
        return self.functions["f"](x, u, self.params(p), self._dt(dt))

    def F(self, x, u, p=None, dt=None) -> np.ndarray:
        """Jacobian of the discrete step in x, shape (n_x, n_x)."""
        return np.reshape(self.functions["F"](x, u, self.params(p), self._dt(dt)), (self.n_x, self.n_x))

    def G(self, x, u, p=None, dt=None) -> np.ndarray:
        """Jacobian of the discrete step in the noise input (held over dt), shape (n_x, n_w)."""
        # a matrix even for one noise input or one state (a one-column output comes back as a vector)
        return np.reshape(self.function("G")(x, u, self.params(p), self._dt(dt)), (self.n_x, self.n_w))

    def h(self, x, p=None) -> np.ndarray:
        """Measurement, shape (n_y,)."""
        return np.atleast_1d(self.functions["h"](x, self.params(p)))

    def H(self, x, p=None) -> np.ndarray:
        """Jacobian of the measurement, shape (n_y, n_x)."""
        return np.reshape(self.functions["H"](x, self.params(p)), (self.n_y, self.n_x))

    def xdot(self, x, u, p=None, w=None) -> np.ndarray:
        """Continuous dynamics, shape (n_x,); w=None means zero noise input."""
        if self.is_discrete:
            raise TypeError(f"model {self.name!r} is discrete (x_next given directly): it has no xdot; use x_next or f")
        w = np.zeros(self.n_w) if w is None else w
        return self.functions["xdot"](x, u, self.params(p), w)

    def x_next(self, x, u, p=None, w=None, dt=None) -> np.ndarray:
        """The given step of a discrete model with its noise input, shape (n_x,); w=None means zero."""
        if not self.is_discrete:
            raise TypeError(f"model {self.name!r} is continuous ({self.discretisation}): use f (the step) or xdot")
        w = np.zeros(self.n_w) if w is None else w
        return self.functions["x_next"](x, u, self.params(p), w, self._dt(dt))

    def _state_batch(self, X) -> np.ndarray:
        """X as a checked, finite, C-ordered (n_x, N) batch (the SIMD kernels' layout)."""
        X = np.ascontiguousarray(real_array(X, f"{self.name}: X"))
        if X.ndim != 2 or X.shape[0] != self.n_x:
            raise ValueError(f"{self.name}: X must have shape ({self.n_x}, N), got {X.shape}")
        if not _all_finite(X):
            raise ValueError(f"{self.name}: X must be finite")
        return X

    def f_batch(self, X, U, p=None, dt=None) -> np.ndarray:
        """One step for each column of X (n_x, N); U is (n_u, N) or (n_u,) shared. Returns (n_x, N)."""
        X = self._state_batch(X)
        U = real_array(U, f"{self.name}: U")
        if U.shape not in ((self.n_u,), (self.n_u, X.shape[1])):
            raise ValueError(f"{self.name}: U must have shape ({self.n_u}, {X.shape[1]}) or ({self.n_u},), got {U.shape}")
        if not np.isfinite(U).all():
            raise ValueError(f"{self.name}: U must be finite")
        n = X.shape[1]
        U = np.ascontiguousarray(np.broadcast_to(U.reshape(self.n_u, -1), (self.n_u, n)))
        out = np.empty((self.n_x, n))
        self.functions["f"].bind_soa([X, U, self.params(p), np.array([self._dt(dt)])], [out])(n)
        _finite_columns(f"{self.name} f_batch", [out], self.functions["f"].outputs, n)
        return out

    def h_batch(self, X, p=None) -> np.ndarray:
        """Measurement of each column of X (n_x, N). Returns (n_y, N)."""
        X = self._state_batch(X)
        out = np.empty((self.n_y, X.shape[1]))
        self.functions["h"].bind_soa([X, self.params(p)], [out])(X.shape[1])
        _finite_columns(f"{self.name} h_batch", [out], self.functions["h"].outputs, X.shape[1])
        return out
