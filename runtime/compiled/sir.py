"""The compiled SIR step (``runtime/c/abyssal_sir.h``) bound to one filter's buffers.

One C call does a whole particle-filter step -- the process-noise draws from the step's own
counter-based generator (Philox4x32-10), the model's structure-of-arrays f, pins, h, the exact
(mixture) likelihood of the present entries of z with the innovation gate and the underflow rule,
log-weights, ESS, weighted moments and systematic or stratified resampling -- over the buffers
held here, in blocks of ``BLOCK`` particles, on one or more threads. ``abyssal_sir.h`` is the
reference for what a step computes; this module allocates the buffers, describes the model and its
noises to the C and says which side of each buffer is committed.

    step = CompiledSIR(n, n_x, n_u, n_y, p, f=..., measure=..., process=ProcessNoise..., measurement=mixture)
    step.u[...] = u; step.inputs[IN_DT] = dt; ...        # the step's inputs (views of one array)
    status = step()                                          # writes the uncommitted side only
    step.commit()                                            # the written side becomes the committed one

Random numbers: a step's draws are Philox4x32-10 of (particle, row, step counter) under a 64-bit key
(``rng[0]``; ``rng[1]`` counts steps and is advanced by ``commit``), so they do not depend on the
thread count, the blocking or anything drawn before; the state is those two words. Normals by the
Box-Muller transform in single precision (each to ~1e-7 relative, the tail to 6.8 sigma).

Threads: a step whose serial time exceeds ``SPLIT_MIN_SECONDS`` (compiled.batches) is timed on one
thread and on every core (a few steps each, again after ``FIRST_RETIME_STEPS`` steps, then after gaps
doubling up to ``RETIME_STEPS``) and runs with the faster count: on a loaded machine the other core may be busy, and
the step's threads (started per step, tens of microseconds) wait for each other at its barriers. The
results are bit-identical whatever the count (tests/runtime/test_sir_step.py), so the choice never
changes them.
"""
from __future__ import annotations

import ctypes
import math
import os
import struct
import time
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from abyssal.arrays import aligned_zeros

from .batches import SPLIT_MIN_SECONDS


#: particles per block of the C step (ABYSSAL_SIR_BLOCK)
BLOCK = 512
MAX_THREADS = 64
#: steps timed on one thread, then on every core, to choose the thread count (CompiledSIR._probed_call) ...
PROBE_STEPS = 3
#: ... again after FIRST_RETIME_STEPS, then after twice as many steps each time up to every RETIME_STEPS (the
#: machine's load changes). A filter's first steps are not its usual ones (pages touched for the first time,
#: resampling at every step), nor are a process's first ~10 split steps (slow on a 2-vCPU VM: benchmarks/README.md,
#: bench_sir): timed there, 2 threads lost to 1 at N = 10^4 where they take 0.6 of its time.
#: The doubling gaps time the split again while that start is still recent, at a cost of PROBE_STEPS steps.
RETIME_STEPS = 2000
FIRST_RETIME_STEPS = 50

# in[] scalars (abyssal_sir.h: ABYSSAL_SIR_IN_*) and settings (ABYSSAL_SIR_SET_*, at CompiledSIR.io.settings)
IN_CUR, IN_SIDE, IN_PRIOR, IN_MOVE, IN_MEASURE, IN_DT, IN_PIECES, IN_PINS, IN_HEAD = range(9)
SET_THREADS, SET_SCHEME, SET_RESAMPLE_BELOW, SET_RATIO, SET_COUNT = range(5)
MOVE_NONE, MOVE_TRANSITION, MOVE_GIVEN = 0, 1, 2
SYSTEMATIC, STRATIFIED, CALLER = 0, 1, 2
SCHEMES = {"systematic": SYSTEMATIC, "stratified": STRATIFIED}
# report scalars (ABYSSAL_SIR_R_*)
(R_ESS, R_RESAMPLED, R_RESAMPLE, R_UNINFORMATIVE, R_USED, R_GATED, R_MAX_LOG_LIK, R_LOG_MEAN, R_PASSES,
 R_HEAD) = range(10)
# tags of the generator's counter
TAG_NORMALS, TAG_COMPONENTS, TAG_RESAMPLING = 0, 1, 2

#: the status of a step refused because its weighted mean or covariance is not finite (the contract's "finite in,
#: finite out", checked by the C step instead of by every caller); every status's text: message()
NONFINITE_MOMENTS = 6


class _InOffsets(ctypes.Structure):
    _fields_ = [(name, ctypes.c_longlong) for name in ("pin_values", "pin_rows", "u", "u_std", "z", "present",
                                                       "thresholds", "settings", "size")]


class _ReportOffsets(ctypes.Structure):
    _fields_ = [(name, ctypes.c_longlong) for name in ("gated", "mean", "cov", "extra", "nu", "S", "size")]


class _Sir(ctypes.Structure):
    """struct abyssal_sir (abyssal_sir.h), field for field."""

    _fields_ = [
        ("n", ctypes.c_longlong), ("ld", ctypes.c_longlong), ("n_x", ctypes.c_int), ("n_u", ctypes.c_int), ("n_y", ctypes.c_int),
        ("n_p", ctypes.c_int), ("n_extra", ctypes.c_int), ("has_valid", ctypes.c_int), ("max_threads", ctypes.c_int),
        ("f", ctypes.c_void_p), ("h", ctypes.c_void_p), ("h_ctx", ctypes.c_void_p), ("p", ctypes.c_void_p),
        ("rank", ctypes.c_int), ("q_components", ctypes.c_int), ("support", ctypes.c_void_p),
        ("factor", ctypes.c_void_p), ("noise_mean", ctypes.c_void_p), ("q_cumulative", ctypes.c_void_p),
        ("q_means", ctypes.c_void_p), ("q_factors", ctypes.c_void_p), ("input_noise", ctypes.c_int),
        ("r_components", ctypes.c_int), ("n_angles", ctypes.c_int), ("angle_outputs", ctypes.c_void_p),
        ("r_weights", ctypes.c_void_p), ("r_means", ctypes.c_void_p), ("r_covs", ctypes.c_void_p),
        ("R", ctypes.c_void_p), ("R_mean", ctypes.c_void_p), ("invalid_log_lik", ctypes.c_double),
        ("max_abs", ctypes.c_double),
        ("particles", ctypes.c_void_p * 3), ("log_w", ctypes.c_void_p * 2), ("w", ctypes.c_void_p * 2),
        ("report", ctypes.c_void_p * 2), ("log_ratio", ctypes.c_void_p), ("rng", ctypes.c_void_p),
        ("inputs", ctypes.c_void_p), ("work", ctypes.c_void_p), ("work_size", ctypes.c_longlong),
    ]


class SoaMeasure(ctypes.Structure):
    """abyssal_soa_measure: the context of abyssal_sir_soa_measure (a model's h kernel)."""

    _fields_ = [("h", ctypes.c_void_p)]


@lru_cache(maxsize=1)
def library() -> ctypes.CDLL:
    """The compiled C runtime of the particle filters (built once through the cache of abyssal.generated.build)."""
    from abyssal.generated.build import build

    from .sources import SIR, sources

    lib = ctypes.CDLL(str(build("abyssal_sir", sources(SIR), strict=True,
                                symbols=("abyssal_sir_step", "abyssal_sir_normals", "abyssal_terrain_bilinear"))))
    lib.abyssal_sir_step.restype = ctypes.c_int
    lib.abyssal_sir_work_size.restype = ctypes.c_longlong
    lib.abyssal_sir_work_size.argtypes = [ctypes.c_longlong, ctypes.c_longlong] + [ctypes.c_int] * 8
    lib.abyssal_sir_inputs.restype = _InOffsets
    lib.abyssal_sir_inputs.argtypes = [ctypes.c_int] * 3
    lib.abyssal_sir_report.restype = _ReportOffsets
    lib.abyssal_sir_report.argtypes = [ctypes.c_int] * 3
    lib.abyssal_sir_normals.restype = None
    lib.abyssal_sir_normals.argtypes = [ctypes.c_uint64, ctypes.c_uint64, ctypes.c_uint32, ctypes.c_longlong,
                                        ctypes.c_longlong, ctypes.c_int, ctypes.c_void_p, ctypes.c_longlong]
    lib.abyssal_sir_uniforms.restype = None
    lib.abyssal_sir_uniforms.argtypes = [ctypes.c_uint64, ctypes.c_uint64, ctypes.c_uint32, ctypes.c_longlong,
                                         ctypes.c_longlong, ctypes.c_void_p]
    lib.abyssal_sir_philox.restype = None
    lib.abyssal_sir_box_muller.restype = None
    lib.abyssal_sir_box_muller.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p,
                                           ctypes.c_void_p]
    lib.abyssal_sir_wrap_residuals.restype = None
    lib.abyssal_sir_wrap_residuals.argtypes = [ctypes.c_void_p, ctypes.c_longlong]
    lib.abyssal_sir_message.restype = ctypes.c_char_p
    lib.abyssal_sir_message.argtypes = [ctypes.c_int]
    lib.abyssal_terrain_bilinear.restype = None
    lib.abyssal_sir_terrain_step.restype = ctypes.c_int
    return lib


def address(name: str) -> int:
    """Address of a C function of the runtime (e.g. a measurement function for ``CompiledSIR``)."""
    return ctypes.cast(getattr(library(), name), ctypes.c_void_p).value


# ------------------------------------------------------------------------------------------- the generator
def philox(counter, key) -> np.ndarray:
    """Philox4x32-10 of counter (4 uint32) under key (2 uint32): 4 uint32."""
    c = (ctypes.c_uint32 * 4)(*[int(v) for v in counter])
    k = (ctypes.c_uint32 * 2)(*[int(v) for v in key])
    out = (ctypes.c_uint32 * 4)()
    library().abyssal_sir_philox(c, k, out)
    return np.array(out[:], dtype=np.uint32)


def message(status: int) -> str:
    """The C step's own text for a status it returns (abyssal_sir_message)."""
    return library().abyssal_sir_message(int(status)).decode()


def box_muller(a, b) -> tuple[np.ndarray, np.ndarray]:
    """The step's Box-Muller transform of 32-bit words a, b (equal lengths): (r cos t, r sin t), r = sqrt(-2 ln u),
    u = (a + 1/2) 2^-32, t = 2 pi b 2^-32, in single precision as the step computes its normals."""
    a, b = np.ascontiguousarray(a, dtype=np.uint32), np.ascontiguousarray(b, dtype=np.uint32)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"a and b must be 1-D of one length, got shapes {a.shape} and {b.shape}")
    c, s = np.empty(a.size), np.empty(a.size)
    library().abyssal_sir_box_muller(a.ctypes.data, b.ctypes.data, a.size, c.ctypes.data, s.ctypes.data)
    return c, s


def wrap_residuals(values) -> np.ndarray:
    """A copy of values (1-D) with the entries beyond +-pi wrapped to (-pi, pi] as the step wraps angle residuals."""
    out = np.array(values, dtype=np.float64).ravel()
    library().abyssal_sir_wrap_residuals(out.ctypes.data, out.size)
    return out


def normals(key: int, counter: int, rows: int, n: int, i0: int = 0) -> np.ndarray:
    """(rows, n): the normals a step with this key and counter draws for particles i0..i0+n-1 (row q of particle
    i: its q-th noise normal; the input noise's rows first when the model has input noise)."""
    out = np.empty((rows, n))
    if rows and n:
        library().abyssal_sir_normals(key, counter, TAG_NORMALS, i0, n, rows, out.ctypes.data, n)
    return out


def uniforms(key: int, counter: int, tag: int, n: int, i0: int = 0) -> np.ndarray:
    """(n,) uniforms in (0, 1) of the generator's `tag` (TAG_COMPONENTS: a mixture's component per particle,
    TAG_RESAMPLING: u0 of systematic resampling at index 0, u_k of stratified)."""
    out = np.empty(n)
    if n:
        library().abyssal_sir_uniforms(key, counter, tag, i0, n, out.ctypes.data)
    return out


def draw_key(rng: np.random.Generator) -> int:
    """A 64-bit Philox key drawn from a numpy Generator (one draw: the Generator advances once)."""
    return int(rng.integers(0, 2 ** 64, dtype=np.uint64, endpoint=False))


# ------------------------------------------------------------------------------------------- noises
@dataclass
class ProcessNoise:
    """The additive process noise w as the C step draws it: w = mean + factor y, y ~ N(0, I_rank).

    ``support`` (rank,) state rows with ``factor`` their standard deviations (rank,) -- a diagonal covariance,
    possibly singular -- or ``support`` None and ``factor`` (n_x, rank). A Gaussian mixture of K >= 2
    components instead: ``cumulative`` (K,), ``means`` (K, n_x), ``factors`` (K, n_x, n_x) lower Cholesky
    factors (rank = n_x). The arrays are bound once: write new values into them in place (e.g. a sigma that
    changes every step).
    """

    rank: int
    factor: np.ndarray
    support: np.ndarray | None = None
    mean: np.ndarray | None = None
    cumulative: np.ndarray | None = None
    means: np.ndarray | None = None
    factors: np.ndarray | None = None

    @classmethod
    def from_transition(cls, transition) -> "ProcessNoise":
        """From the SIR engine's TransitionNoise (its positive-definite subspace of Q, or its mixture)."""
        if transition.mixture is not None:
            mix = transition.mixture
            return cls(rank=mix.dim, factor=np.zeros(1), cumulative=np.cumsum(mix.weights),
                       means=np.ascontiguousarray(mix.means, dtype=np.float64),
                       factors=np.ascontiguousarray(np.linalg.cholesky(mix.covariances)))
        std = np.sqrt(transition.variances)
        mean = np.ascontiguousarray(transition.mean, dtype=np.float64) if transition.mean.any() else None
        if transition.support is not None:
            return cls(rank=transition.rank, factor=np.ascontiguousarray(std),
                       support=np.ascontiguousarray(transition.support, dtype=np.int32), mean=mean)
        return cls(rank=transition.rank, factor=np.ascontiguousarray(transition.basis * std[None, :]), mean=mean)


def _array(a, dtype=np.float64) -> np.ndarray | None:
    return None if a is None else np.ascontiguousarray(a, dtype=dtype)


def _ptr(a) -> int | None:
    return None if a is None else a.ctypes.data


class CompiledSIR:
    """The C step bound to its buffers (module docstring). ``particles[cur]`` are the committed particles,
    ``log_w[side]``, ``w[side]``, ``report[side]`` the committed weights and report."""

    def __init__(self, n: int, n_x: int, n_u: int, n_y: int, p: np.ndarray, *, f: int | None, measure: tuple | None,
                 process: ProcessNoise, measurement, angle_outputs=(), input_noise: bool = False, n_extra: int = 0,
                 has_valid: bool = False, invalid_log_lik: float = -math.inf, max_abs: float = math.inf,
                 max_threads: int | None = None, entry: str = "abyssal_sir_step"):
        if not 1 <= n < 2 ** 32:
            raise ValueError(f"n_particles must be between 1 and 2^32 - 1 for the compiled step, got {n}")
        if n_x > 64 or n_y > 64:
            raise ValueError(f"the compiled SIR step takes at most 64 states and 64 outputs, got {n_x} and {n_y}")
        if not (isinstance(p, np.ndarray) and p.dtype == np.float64 and p.ndim == 1 and p.flags.c_contiguous):
            raise TypeError("p must be the filter's contiguous float64 parameter buffer")
        lib = library()
        self.n, self.n_x, self.n_u, self.n_y, self.n_extra = n, n_x, n_u, n_y, n_extra
        self.max_threads = min(MAX_THREADS, os.cpu_count() or 1) if max_threads is None else int(max_threads)
        io, ro = lib.abyssal_sir_inputs(n_x, n_u, n_y), lib.abyssal_sir_report(n_x, n_y, n_extra)
        # the inputs, then the process noise's factor (an input too: a filter may change it every step, e.g. a
        # sigma of its own; the struct points at it), so a filter writes all it changes in one slice
        factor_at = io.size
        self.inputs = np.zeros(io.size + process.factor.size)
        #: the process noise's factor as the step reads it (write new values here, not into process.factor)
        self.factor = self.inputs[factor_at:].reshape(process.factor.shape)
        self.factor[...] = process.factor
        self.u, self.u_std = self.inputs[io.u:io.u + n_u], self.inputs[io.u_std:io.u_std + n_u]
        self.z, self.present = self.inputs[io.z:io.z + n_y], self.inputs[io.present:io.present + n_y]
        self.thresholds = self.inputs[io.thresholds:io.thresholds + n_y + 1]
        self.thresholds[...] = math.inf
        self.pin_rows, self.pin_values = self.inputs[io.pin_rows:io.pin_rows + n_x], self.inputs[io.pin_values:io.pin_values + n_x]
        #: [threads, scheme, resample below, use log ratio] (see the properties)
        self.settings = self.inputs[io.settings:io.settings + SET_COUNT]
        self.inputs[IN_PIECES] = 1.0
        self.settings[SET_THREADS] = 1.0
        # the step's inputs CUR .. the thresholds as one struct write (run)
        self._head = struct.Struct(f"{io.settings}d")
        self._inputs_bytes = memoryview(self.inputs).cast("B")
        #: offsets of the inputs' vectors (u, u_std, z, present, thresholds, pin_rows, pin_values) and the report's
        self.io, self._ro = io, ro
        #: row stride of the particle buffers: n rounded up to 8 doubles, so every row starts 64-byte aligned
        self.ld = ld = -(-n // 8) * 8
        #: the three particle buffers, (n_x, n) views of (n_x, ld) aligned arrays (rows contiguous)
        self.particles = [aligned_zeros((n_x, ld))[:, :n] for _ in range(3)]
        self.log_w = [np.full(n, -math.log(n)) for _ in range(2)]
        self.w = [np.full(n, 1.0 / n) for _ in range(2)]
        self.report = [np.zeros(ro.size) for _ in range(2)]
        for r in self.report:
            r[R_ESS] = n
        ro_ = ro
        #: per side: the weighted mean (n_x,), covariance (n_x, n_x) and extra rows' means (n_extra,) (views)
        self.means = [r[ro_.mean:ro_.mean + n_x] for r in self.report]
        self.covs = [r[ro_.cov:ro_.cov + n_x * n_x].reshape(n_x, n_x) for r in self.report]
        self.extras = [r[ro_.extra:ro_.extra + n_extra] for r in self.report]
        self._report_bytes = [memoryview(r).cast("B") for r in self.report]
        self._report_head = struct.Struct(f"{R_HEAD}d")
        self.log_ratio = np.zeros(n)
        self.rng = np.zeros(2, dtype=np.uint64)
        self._counter = ctypes.c_uint64.from_buffer(self.rng, 8)  # rng[1], written without a numpy call
        self.cur, self.side = 0, 0
        #: the committed weights are exp(the committed log-weights) (no resampling since): see IN_PRIOR
        self.weights_match = True
        # noises
        self.process = process
        mixture = measurement  # None: a model without measurement (n_y = 0; steps never weigh)
        if mixture is None and n_y:
            raise ValueError("measurement noise is needed for a model with outputs")
        k = 1 if mixture is None else mixture.n_components
        self._keep = [p, process.support, process.mean, process.cumulative, process.means, process.factors]
        if mixture is None:
            r_weights = r_means = r_covs = R = R_mean = None
        else:
            r_weights, r_means = _array(mixture.weights), _array(mixture.means)
            r_covs, R, R_mean = _array(mixture.covariances), _array(mixture.covariance()), _array(mixture.mean())
        angles = _array(list(angle_outputs) or [0], np.int32)
        self._keep += [r_weights, r_means, r_covs, R, R_mean, angles]
        rank = process.rank
        # the work buffer: mostly address space (np.zeros of a large array maps zero pages only when touched)
        self.work = np.zeros(lib.abyssal_sir_work_size(n, ld, n_x, n_u, n_y, n_extra, int(has_valid), rank, k,
                                                       self.max_threads))
        if measure is None:
            h, h_ctx = None, None
        else:
            h, h_ctx = measure
            self._keep.append(h_ctx)
        self._struct = _Sir(
            n=n, ld=ld, n_x=n_x, n_u=n_u, n_y=n_y, n_p=p.shape[0], n_extra=n_extra, has_valid=int(has_valid),
            max_threads=self.max_threads, f=f, h=h, h_ctx=None if h_ctx is None else ctypes.addressof(h_ctx),
            p=p.ctypes.data, rank=rank, q_components=1 if process.cumulative is None else len(process.cumulative),
            support=_ptr(process.support), factor=self.factor.ctypes.data, noise_mean=_ptr(process.mean),
            q_cumulative=_ptr(process.cumulative), q_means=_ptr(process.means), q_factors=_ptr(process.factors),
            input_noise=int(input_noise), r_components=k, n_angles=len(angle_outputs), angle_outputs=_ptr(angles),
            r_weights=_ptr(r_weights), r_means=_ptr(r_means), r_covs=_ptr(r_covs), R=_ptr(R), R_mean=_ptr(R_mean),
            invalid_log_lik=invalid_log_lik, max_abs=max_abs,
            particles=(ctypes.c_void_p * 3)(*[a.ctypes.data for a in self.particles]),
            log_w=(ctypes.c_void_p * 2)(*[a.ctypes.data for a in self.log_w]),
            w=(ctypes.c_void_p * 2)(*[a.ctypes.data for a in self.w]),
            report=(ctypes.c_void_p * 2)(*[a.ctypes.data for a in self.report]),
            log_ratio=self.log_ratio.ctypes.data, rng=self.rng.ctypes.data, inputs=self.inputs.ctypes.data,
            work=self.work.ctypes.data, work_size=self.work.shape[0])
        self._arg = ctypes.c_void_p(ctypes.addressof(self._struct))
        #: the C call of a step: abyssal_sir_step, or a stage around it taking the same struct (entry)
        self._fn = getattr(lib, entry)
        # the thread count: chosen by timing (_probed_call) unless set (threads)
        self._probes, self._forced, self._serial, self._split = 0, False, math.inf, math.inf
        self._retime = FIRST_RETIME_STEPS

    # ------------------------------------------------------------------ views of the sides
    def mean(self, side: int) -> np.ndarray:
        """The weighted mean (n_x,) of a side's step (a view)."""
        return self.means[side]

    def cov(self, side: int) -> np.ndarray:
        """The weighted covariance (n_x, n_x) of a side's step (a view)."""
        return self.covs[side]

    def extra(self, side: int) -> np.ndarray:
        """The posterior means of the measurement's extra rows (n_extra,) of a side's step (a view)."""
        return self.extras[side]

    def gated(self, side: int) -> np.ndarray:
        return self.report[side][self._ro.gated:self._ro.gated + self.n_y]

    def innovation(self, side: int) -> tuple[np.ndarray, np.ndarray]:
        """The gate's nu (n_y,) and S (n_y, n_y) of a step (zero where an entry was not present)."""
        r, o = self.report[side], self._ro
        return r[o.nu:o.nu + self.n_y], r[o.S:o.S + self.n_y * self.n_y].reshape(self.n_y, self.n_y)

    @property
    def next_particles(self) -> np.ndarray:
        """Where a step writes (or a proposal wrote) the moved particles: buffer cur + 1."""
        return self.particles[(self.cur + 1) % 3]

    # ------------------------------------------------------------------ settings
    @property
    def count(self) -> int:
        """The active particle number: a step runs over the first `count` columns of every buffer."""
        return int(self._struct.n)

    @count.setter
    def count(self, value: int) -> None:
        """At most the n the buffers were sized for (an adaptive particle number, e.g. KLD-resampling)."""
        if not 1 <= int(value) <= self.n:
            raise ValueError(f"count must be between 1 and {self.n}, got {value!r}")
        self._struct.n = int(value)

    @property
    def threads(self) -> int:
        return int(self.settings[SET_THREADS])

    @threads.setter
    def threads(self, value: int | None) -> None:
        """Threads for every step from now on (1 .. max_threads), or None: chosen by timing (_probed_call)."""
        if value is None:
            self._forced, self._probes, self._retime = False, 0, FIRST_RETIME_STEPS
            return
        if not 1 <= int(value) <= self.max_threads:
            raise ValueError(f"threads must be between 1 and {self.max_threads}, got {value!r}")
        self.settings[SET_THREADS] = int(value)
        self._forced, self._probes = True, 2 * PROBE_STEPS

    @property
    def scheme(self) -> int:
        return int(self.settings[SET_SCHEME])

    @scheme.setter
    def scheme(self, value: int) -> None:
        """SYSTEMATIC, STRATIFIED or CALLER (the caller resamples when the report says R_RESAMPLE)."""
        if value not in (SYSTEMATIC, STRATIFIED, CALLER):
            raise ValueError(f"scheme must be SYSTEMATIC, STRATIFIED or CALLER, got {value!r}")
        self.settings[SET_SCHEME] = value

    @property
    def resample_below(self) -> float:
        return float(self.settings[SET_RESAMPLE_BELOW])

    @resample_below.setter
    def resample_below(self, value: float) -> None:
        """Resample when ESS < this (math.inf: every step, 0: never)."""
        if not value >= 0:
            raise ValueError(f"resample_below must be >= 0, got {value!r}")
        self.settings[SET_RESAMPLE_BELOW] = value

    @property
    def use_log_ratio(self) -> bool:
        return bool(self.settings[SET_RATIO])

    @use_log_ratio.setter
    def use_log_ratio(self, value: bool) -> None:
        """Add ``log_ratio`` (a proposal's log importance ratios) to the log-weights of the next steps."""
        self.settings[SET_RATIO] = bool(value)

    # ------------------------------------------------------------------ the step
    def __call__(self) -> int:
        """One step on the uncommitted side with the inputs as they are; returns the C status (0: ok, message())."""
        self.inputs[IN_CUR:IN_PRIOR + 1] = (self.cur, self.side, self.weights_match)
        return self._go()

    def run(self, values) -> int:
        """One step whose inputs MOVE .. the thresholds are `values` (a sequence of that many numbers, written in
        one go: the fast path of a filter that builds them each step); returns the C status."""
        self._head.pack_into(self._inputs_bytes, 0, self.cur, self.side, self.weights_match, *values)
        return self._go()

    def _go(self) -> int:
        """The C call, on the thread count chosen by timing (re-timed after gaps doubling up to RETIME_STEPS)."""
        if self._probes < 2 * PROBE_STEPS:
            return self._probed_call()
        self._probes += 1
        if self._probes >= self._retime:
            self._probes, self._retime = 0, min(2 * self._retime, RETIME_STEPS)
        return self._fn(self._arg)

    def _probed_call(self) -> int:
        """A step timed to choose the thread count: PROBE_STEPS on one thread, then (when those took at least
        SPLIT_MIN_SECONDS) PROBE_STEPS on every core; the faster count stays until the next timing (_go). The results
        do not depend on the count, so probing never changes them."""
        probe = self._probes
        if self.max_threads == 1 or self._struct.n <= BLOCK or self._forced:
            self._probes = 2 * PROBE_STEPS
            return self._fn(self._arg)
        if probe == 0:
            self._serial = self._split = math.inf
        threads = 1 if probe < PROBE_STEPS else self.max_threads
        self.settings[SET_THREADS] = threads
        start = time.perf_counter()
        status = self._fn(self._arg)
        seconds = time.perf_counter() - start
        if threads == 1:
            self._serial = min(self._serial, seconds)
        else:
            self._split = min(self._split, seconds)
        probe += 1
        if probe == PROBE_STEPS and self._serial < SPLIT_MIN_SECONDS:
            probe = 2 * PROBE_STEPS  # too short a step to gain from a split (batches.SPLIT_MIN_SECONDS)
        if probe == 2 * PROBE_STEPS:
            self.settings[SET_THREADS] = self.max_threads if self._split < self._serial else 1
        self._probes = probe
        return status

    def head(self, side: int) -> tuple:
        """The report's scalars of a side (R_ESS .. R_PASSES) as a tuple of floats."""
        return self._report_head.unpack_from(self._report_bytes[side])

    def commit(self, resampled: bool | None = None) -> None:
        """The step's side becomes the committed one (particles: the resampled buffer when it resampled) and the
        generator's counter advances. `resampled`: the step's R_RESAMPLED when the caller has read it already."""
        nxt = 1 - self.side
        if resampled is None:
            resampled = self.report[nxt].item(R_RESAMPLED) != 0.0
        self.cur = (self.cur + (2 if resampled else 1)) % 3
        self.side = nxt
        self.weights_match = not resampled
        self._counter.value += 1

    def message(self, status: int) -> str:
        return message(status)
