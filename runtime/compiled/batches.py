"""Batched calls of compiled C over particles or mixture components, on preallocated buffers.

``ModelBatch`` runs the model's generated SIMD structure-of-arrays kernels of f and h over (n, N)
particle batches; ``PredictBatch`` / ``UpdateBatch`` run a sigma-point predict or update of the C
runtime (``kalman.BatchStep``: the algebra every Kalman filter runs)
(cubature: ``CubaturePredictBatch`` / ``CubatureUpdateBatch`` / ``CubatureStepBatch``; unscented
and robust: ``UnscentedPredictBatch`` / ``UnscentedUpdateBatch``) over (n, cap) means and
(n, n, cap) covariances through the ``<name>_batch`` entry points, split over the cores by
``ParallelBatch``. Every call takes the number of slices to evaluate (a particle filter's active
count), never more than the capacity its buffers were sized for.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..noise.mixtures import LOG_2PI
from ..numerics import repair_covariance
from .kalman import BatchStep

# ---------------------------------------------------------------------------------------------
# batched generated C


def _f_zeros(*shape) -> np.ndarray:
    return np.zeros(shape, order="F")


#: batches of at least this many slices may be split over the cores (ctypes releases the GIL) ...
PARALLEL_MIN_SLICES = 64
#: ... when their serial work is estimated above this many seconds: a hand-off to the thread pool costs
#: ~20-90 us per batch (benchmarks/README.md, the threads measurement), more than cheap slices save by splitting
SPLIT_MIN_SECONDS = 200e-6


_POOL: ThreadPoolExecutor | None = None


def _pool() -> ThreadPoolExecutor:
    """One process-wide pool of cpu_count - 1 threads (the calling thread runs the first chunk)."""
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=max(1, (os.cpu_count() or 1) - 1), thread_name_prefix="abyssal-batch")
    return _POOL


def _forget_pool_after_fork() -> None:
    global _POOL
    _POOL = None  # the parent's threads do not exist in the child


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool_after_fork)


class ParallelBatch:
    """A generated function bound over `capacity` slices, evaluated in contiguous chunks on all cores.

    `batched` flags which inputs carry one slice per column of their last axis (the others are
    shared). Each chunk is its own ``bind_batch`` on views of the same buffers, so results land in
    place; the calling thread evaluates the first chunk while a process-wide
    ``concurrent.futures.ThreadPoolExecutor`` evaluates the others (ctypes releases the GIL).

    A batch is split only when it is worth the hand-off: the first calls run serially and time
    themselves, and a batch is split when count x (the cheapest serial time per slice seen) exceeds
    SPLIT_MIN_SECONDS. Every slice is the same scalar C call whatever the split, so results do not
    depend on it (nor on the timing that chooses it).

    OpenMP in the generated ``_batch`` instead of this pool was measured (benchmarks/README.md,
    "bench_threads"): at most ~9 % faster per filter step on two idle cores, and only while
    libgomp's idle threads spin, which makes two concurrent processes (a 2-worker campaign) 1.7x
    slower or more; a forked child's OpenMP call hangs. So the pool stays.
    """

    def __init__(self, fn, inputs, batched, outputs, capacity: int):
        self.capacity = capacity
        inputs = [_as_slices(a) if b else a for a, b in zip(inputs, batched)]
        outputs = [_as_slices(a) for a in outputs]
        n_chunks = min(os.cpu_count() or 1, 4) if capacity >= PARALLEL_MIN_SLICES else 1
        bounds = np.linspace(0, capacity, n_chunks + 1).astype(int)
        self._chunks = []
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            ins = [a[..., lo:hi] if b else a for a, b in zip(inputs, batched)]
            outs = [a[..., lo:hi] for a in outputs]
            self._chunks.append((lo, hi, fn.bind_batch(ins, outs, hi - lo)))
        self._whole = fn.bind_batch(inputs, outputs, capacity) if n_chunks > 1 else self._chunks[0][2]
        #: cheapest serial seconds per slice measured so far (None: not yet measured)
        self.slice_seconds: float | None = None

    def __call__(self, count: int, then=None) -> None:
        """Evaluate slices 0..count-1. `then(lo, hi)`, if given, runs right after each chunk's
        evaluation in the same thread (NumPy work on that chunk's results, overlapped across cores)."""
        if not 0 <= count <= self.capacity:
            raise ValueError(f"batch size {count} outside 0..{self.capacity} of the bound buffers")
        if count <= self._chunks[0][1]:
            self._chunks[0][2](count)  # fits the first chunk: no thread hand-off
            if then is not None:
                then(0, count)
            return
        if self.slice_seconds is None or count * self.slice_seconds < SPLIT_MIN_SECONDS:
            start = time.perf_counter()
            self._whole(count)
            per_slice = (time.perf_counter() - start) / count
            self.slice_seconds = per_slice if self.slice_seconds is None else min(self.slice_seconds, per_slice)
            if then is not None:
                then(0, count)
            return
        lo, hi, first = self._chunks[0]
        rest = [(binding, lo_, min(count, hi_)) for lo_, hi_, binding in self._chunks[1:] if count > lo_]
        futures = [_pool().submit(_run_chunk, binding, lo_, hi_, then) for binding, lo_, hi_ in rest]
        try:
            _run_chunk(first, lo, min(count, hi), then)
        finally:
            errors = [f.exception() for f in futures]  # every chunk must finish before the buffers are reused
        for error in errors:
            if error is not None:
                raise error


def _as_slices(a: np.ndarray) -> np.ndarray:
    """A stack of (r, 1) slices (r, 1, cap) as the (r, cap) view a generated batch binds (an (r, 1) argument
    batches as a vector: e.g. S or R of a model with one output)."""
    return a.reshape(a.shape[0], a.shape[2], order="F") if a.ndim == 3 and a.shape[1] == 1 else a


def _run_chunk(binding, lo: int, hi: int, then) -> None:
    binding(hi - lo)
    if then is not None:
        then(lo, hi)


def nearest_positive_definite(covariances: np.ndarray) -> np.ndarray:
    """``numerics.repair_covariance`` of each (n, n) slice of an (n, n, k) stack."""
    return np.moveaxis(repair_covariance(np.moveaxis(covariances, -1, 0)), 0, -1)


def _repair_failed_slices(ok: np.ndarray, cov: np.ndarray, evaluate, count: int) -> None:
    """Slices whose Cholesky guard failed (ok = 0): evaluate again on their repaired input covariance (a covariance
    that is not finite cannot be repaired: its slice keeps ok = 0). The input buffer is given back as it was (a call
    reads its inputs, never changes them: a caller's refused step has nothing of the batch's to undo)."""
    if count and ok[0, :count].min() == 0:  # ok is 0 or 1
        failed = np.flatnonzero(ok[0, :count] == 0)
        original = cov[:, :, failed]  # fancy indexing: a copy
        finite = np.isfinite(original).all(axis=(0, 1))
        if not finite.all():  # nothing to repair: the caller sees ok = 0 and the non-finite result
            failed, original = failed[finite], original[:, :, finite]
            if not failed.size:
                return
        cov[:, :, failed] = nearest_positive_definite(original)
        try:
            evaluate(count)
        finally:
            cov[:, :, failed] = original


class PredictBatch:
    """A generated sigma-point predict (x, P, u, p, dt, Q, *rule) -> (x_pred, P_pred, ok) over up to `capacity`
    Gaussians held in preallocated buffers: mean (n, cap), cov (n, n, cap) (Fortran-ordered), u (n_u,), dt; Q is
    one (n, n, cap) process noise per slice (``Q=None``: the Gaussian-sum filters) or one shared (n, n) matrix.
    A slice whose Cholesky guard fails is evaluated again on its repaired input covariance (the input is given
    back as it was)."""

    def __init__(self, bundle, function: str, capacity: int, p: np.ndarray, *, Q: np.ndarray | None = None, rule=()):
        n = bundle.n_x
        self.capacity = capacity
        self.mean, self.cov = _f_zeros(n, capacity), _f_zeros(n, n, capacity)
        self.Q = _f_zeros(n, n, capacity) if Q is None else np.array(Q, dtype=np.float64, order="F")
        self.u, self.p, self.dt = np.zeros(bundle.n_u), _parameter_buffer(p), np.zeros(1)
        self.mean_pred, self.cov_pred, self.ok = _f_zeros(n, capacity), _f_zeros(n, n, capacity), _f_zeros(1, capacity)
        rule = [np.asarray(r, dtype=np.float64) for r in rule]
        self._eval = ParallelBatch(BatchStep(bundle, function), [self.mean, self.cov, self.u, self.p, self.dt, self.Q, *rule],
                                   [True, True, False, False, False, Q is None] + [False] * len(rule),
                                   [self.mean_pred, self.cov_pred, self.ok], capacity)

    def __call__(self, count: int) -> None:
        self._eval(count)
        _repair_failed_slices(self.ok, self.cov, self._eval, count)


class CubaturePredictBatch(PredictBatch):
    """``ckf_predict`` (seed 000 eqs. 22-24) with one process noise Q (n, n, cap) per slice."""

    def __init__(self, bundle, capacity: int, p: np.ndarray):
        super().__init__(bundle, "ckf_predict", capacity, p)


class UnscentedPredictBatch(PredictBatch):
    """``ukf_predict`` with the scaled unscented rule abk = (alpha, beta, kappa) and one shared Q."""

    def __init__(self, bundle, capacity: int, p: np.ndarray, Q: np.ndarray, abk: np.ndarray):
        super().__init__(bundle, "ukf_predict", capacity, p, Q=Q, rule=(abk,))


class UpdateBatch:
    """A generated sigma-point update (x, P, z, p, R, mask, *rule) -> (x_post, P_post, innovation, S, ok) over up
    to `capacity` Gaussians: mean (n, cap), cov (n, n, cap) -- pass a predict batch's outputs to chain without
    copying; outputs mean_post, cov_post, innovation (n_y, cap), S (n_y, n_y, cap), ok (1, cap).

    The measurement z, R and mask are one per slice (``per_slice``: (n_y, cap), (n_y, n_y, cap)) or shared by
    all slices ((n_y,), (n_y, n_y)); ``set_measurement(z)`` writes z either way. ``present`` (n_y,) is the
    caller's mask of this measurement (0: left out of every slice, z there anything finite). A slice whose
    Cholesky guard fails is evaluated again on its repaired input covariance (given back as it was).
    """

    def __init__(self, bundle, function: str, capacity: int, p: np.ndarray, mean: np.ndarray | None = None,
                 cov: np.ndarray | None = None, *, per_slice: bool, R: np.ndarray | None = None, rule=()):
        n, m = bundle.n_x, bundle.n_y
        self.capacity = capacity
        self.mean = _f_zeros(n, capacity) if mean is None else mean
        self.cov = _f_zeros(n, n, capacity) if cov is None else cov
        if per_slice:
            self.z, self.R, self.mask = _f_zeros(m, capacity), _f_zeros(m, m, capacity), np.ones((m, capacity), order="F")
        else:
            self.z, self.mask = np.zeros(m), np.ones(m)
            self.R = _f_zeros(m, m) if R is None else np.array(R, dtype=np.float64, order="F")
        self.p = _parameter_buffer(p)
        #: (n_y,) entries present in this measurement (0: left out of every slice), set by the caller
        self.present = np.ones(m)
        self.mean_post, self.cov_post = _f_zeros(n, capacity), _f_zeros(n, n, capacity)
        self.innovation, self.S, self.ok = _f_zeros(m, capacity), _f_zeros(m, m, capacity), _f_zeros(1, capacity)
        rule = [np.asarray(r, dtype=np.float64) for r in rule]
        self._eval = ParallelBatch(BatchStep(bundle, function), [self.mean, self.cov, self.z, self.p, self.R, self.mask, *rule],
                                   [True, True, per_slice, False, per_slice, per_slice] + [False] * len(rule),
                                   [self.mean_post, self.cov_post, self.innovation, self.S, self.ok], capacity)

    def set_measurement(self, z: np.ndarray) -> None:
        """z (n_y,) for every slice (absent entries: anything finite)."""
        if self.z.ndim == 2:
            self.z[...] = z[:, None]
        else:
            self.z[:] = z

    def __call__(self, count: int) -> None:
        self.mask[...] = self.present[:, None] if self.mask.ndim == 2 else self.present
        self._eval(count)
        _repair_failed_slices(self.ok, self.cov, self._eval, count)


class UnscentedUpdateBatch(UpdateBatch):
    """``ukf_update``, ``huber_ukf_update`` (extra: gamma) or ``mcukf_update`` (extra: sigma), with the scaled
    unscented rule abk and one shared z, R and mask."""

    def __init__(self, bundle, function: str, capacity: int, p: np.ndarray, mean: np.ndarray, cov: np.ndarray,
                 R: np.ndarray, abk: np.ndarray, extra=()):
        super().__init__(bundle, function, capacity, p, mean, cov, per_slice=False, R=R, rule=(abk, *extra))


class CubatureUpdateBatch(UpdateBatch):
    """``ckf_update`` (seed 000 eqs. 25-29) with z (n_y, cap), R (n_y, n_y, cap) and the mask per slice.

    Outlier gate: a measurement entry whose innovation exceeds ``gate_sigma`` standard deviations
    of S is masked out of that slice's update (all slices when ``gate_jointly``, so mixture
    components stay comparable) and the batch is re-evaluated. At the default 100 sigma this only
    fires on absurd measurements; it keeps an outlier far beyond every component from throwing the
    cubature means (and the nonlinear model after them) to overflow (``gate_sigma=inf``: no gate; the
    particle filters gate the whole cloud's predicted measurement instead, engine.py).
    """

    def __init__(self, bundle, capacity: int, p: np.ndarray, mean: np.ndarray | None = None,
                 cov: np.ndarray | None = None, gate_sigma: float = 100.0, gate_jointly: bool = False):
        super().__init__(bundle, "ckf_update", capacity, p, mean, cov, per_slice=True)
        self.gate_sigma, self.gate_jointly = gate_sigma, gate_jointly
        self.gated = 0  # number of measurement entries masked by the gate in the last call

    def __call__(self, count: int) -> None:
        self.gated = 0
        super().__call__(count)
        if self.gate_sigma == np.inf:
            return
        outliers = self.outliers(count)
        if outliers.any():
            if self.gate_jointly:
                outliers[...] = outliers.any(axis=1, keepdims=True)
            self.mask[:, :count][outliers] = 0.0
            self.gated = int(outliers.sum())
            self._eval(count)

    def outliers(self, count: int) -> np.ndarray:
        """(n_y, count) flags of the innovations beyond gate_sigma standard deviations of S."""
        variances = np.einsum("iik->ik", self.S[:, :, :count])
        return (np.abs(self.innovation[:, :count]) > self.gate_sigma * np.sqrt(variances)) & (self.present[:, None] > 0)

    def log_evidence(self, count: int) -> np.ndarray:
        """log N(innovation; 0, S) of the first `count` slices."""
        S = np.moveaxis(self.S[:, :, :count], -1, 0)
        L = np.linalg.cholesky(S)
        y = np.linalg.solve(L, self.innovation[:, :count].T[:, :, None])[:, :, 0]
        return -0.5 * (np.einsum("ki,ki->k", y, y) + 2 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(1)
                       + S.shape[1] * LOG_2PI)


class CubatureStepBatch:
    """``ckf_step`` (predict then update fused, one generated call per slice) over the buffers of a
    chained ``CubaturePredictBatch`` / ``CubatureUpdateBatch`` pair: inputs are the predict batch's
    mean, cov, u, p, dt, Q and the update batch's z, R; outputs land in the update batch's
    mean_post, cov_post, innovation, S, ok.

    One call (and one hand-off to the worker threads) instead of two. It is the same computation
    (``ckf_step`` is the composition of ``ckf_predict`` and ``ckf_update``), so when every slice
    passes its Cholesky guards and no innovation trips the outlier gate the results are those of
    the two-stage path; otherwise the step is redone by the two-stage path, which owns the repair
    and gating logic. The update's present entries are the fused mask (with a per-slice outlier
    gate, a measurement with missing entries goes the two-stage path). Only valid when nothing is
    added between predict and update (zero-mean process noise).
    """

    def __init__(self, bundle, predict: CubaturePredictBatch, update: CubatureUpdateBatch):
        if update.mean is not predict.mean_pred or update.cov is not predict.cov_pred:
            raise ValueError("CubatureStepBatch needs an update batch chained to the predict batch")
        self.predict, self.update = predict, update
        self.capacity = min(predict.capacity, update.capacity)
        self.mask = np.ones_like(update.mask)  # never gated: a gated step goes through the two-stage path
        self._eval = ParallelBatch(
            BatchStep(bundle, "ckf_step"),
            [predict.mean, predict.cov, predict.u, predict.p, predict.dt, predict.Q, update.z, update.R, self.mask],
            [True, True, False, False, False, True, True, True, True],
            [update.mean_post, update.cov_post, update.innovation, update.S, update.ok], self.capacity)

    def __call__(self, count: int, then=None) -> bool:
        """Predict + update slices 0..count-1. `then(lo, hi)` is passed to ``ParallelBatch`` (it
        sees the fused results). Returns False when the step was redone by the two-stage path (the
        results `then` saw are stale)."""
        update = self.update
        gate = update.gate_sigma != np.inf
        if count and gate and not update.present.all():
            self.predict(count)  # missing entries and a per-slice gate: the two-stage path owns the mask
            update(count)
            return False
        self.mask[...] = update.present[:, None]
        self._eval(count, then)
        if count == 0 or (update.ok[0, :count].min() != 0 and not (gate and update.outliers(count).any())):
            return True  # every slice passed its guards (ok is 0 or 1) and nothing was gated
        self.predict(count)
        update(count)
        return False


def _parameter_buffer(p) -> np.ndarray:
    """p itself when it is a contiguous float64 vector (so several batches share one parameter buffer
    that the filter rewrites each step), else a float64 copy."""
    if isinstance(p, np.ndarray) and p.dtype == np.float64 and p.ndim == 1 and p.flags.c_contiguous and p.flags.writeable:
        return p
    return np.array(p, dtype=np.float64)


class MeasureBatch:
    """h over a caller's (n, capacity) C-ordered state buffer (SIMD kernel): ``y = batch(count)``."""

    def __init__(self, bundle, x: np.ndarray, p: np.ndarray):
        self.x, self.p = x, _parameter_buffer(p)
        self.y = np.zeros((bundle.n_y, x.shape[1]))
        self._h = bundle.function("h").bind_soa([self.x, self.p], [self.y])

    def __call__(self, count: int) -> np.ndarray:
        """h at the first `count` columns of x: the (n_y, count) view of y."""
        self._h(count)
        return self.y if count == self.y.shape[1] else self.y[:, :count]


class ModelBatch:
    """f and h of a bundle over (n, N) C-ordered particle batches (SIMD kernels, ``bind_soa``)."""

    def __init__(self, bundle, capacity: int, p: np.ndarray):
        n = bundle.n_x
        self.capacity = capacity
        self.x = np.zeros((n, capacity))
        self.u = np.zeros((bundle.n_u, capacity))
        self.p, self.dt = _parameter_buffer(p), np.zeros(1)
        self.x_next = np.zeros((n, capacity))
        self.y = np.zeros((bundle.n_y, capacity))
        self._f = bundle.function("f").bind_soa([self.x, self.u, self.p, self.dt], [self.x_next])
        self._h = bundle.function("h").bind_soa([self.x, self.p], [self.y])

    def propagate(self, u: np.ndarray, dt: float, count: int | None = None) -> np.ndarray:
        """x_next = f(x, u) for the first `count` columns of self.x (default: all; fill self.x first).
        Returns the (n, count) view of x_next."""
        count = self.capacity if count is None else count
        if count == self.capacity:
            self.u[...] = u[:, None]
        else:
            self.u[:, :count] = u[:, None]
        self.dt[0] = dt
        self._f(count)
        return self.x_next if count == self.capacity else self.x_next[:, :count]

    def measure(self, count: int | None = None) -> np.ndarray:
        """y = h(x) for the first `count` columns of self.x (default: all); the (n_y, count) view of y."""
        count = self.capacity if count is None else count
        self._h(count)
        return self.y if count == self.capacity else self.y[:, :count]

