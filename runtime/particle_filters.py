"""Particle filters on the generated C of any model: PF, CPF, MOGCPF, EM-MOGCPF (seed 000), plus
the cubature Kalman filter and a Gaussian-sum CKF used as baselines.

Every filter is built from a ``ModelBundle`` (``abyssal.generated.load``), an initial mean and
covariance, a process noise and a measurement noise given as ``GaussianMixture`` objects (one
component for Gaussian noise), and a ``numpy.random.Generator``. ``step(u, z, dt)`` runs one
predict + update; ``estimate`` (n,) and ``covariance`` (n, n) hold the result. Particles are
(n, N) arrays; all per-particle model and filter evaluations are calls of generated C over the
whole batch (``bind_soa`` for f and h, ``bind_batch`` for ``ckf_predict`` / ``ckf_update``),
never Python loops over particles. Loops over mixture components (a handful) are allowed.

Noise conventions: the process noise is additive on the discrete state, x_{k+1} = f(x_k, u_k)
+ w_k with w_k ~ process_noise (already scaled to one step by the caller); measurement residuals
z - h(x) of angle outputs are wrapped to (-pi, pi]. Likelihoods are Gaussian or Gaussian
mixtures, evaluated in the log domain and normalised by log-sum-exp.

Decisions where seed 000 is ambiguous:

* PF: bootstrap SIR, proposal p(x_k | x_{k-1}), weights the exact (mixture) likelihood.
* Cubature steps inside CPF / MOGCPF / EM-MOGCPF / CKF use the moment-matched (single
  Gaussian) covariance of a mixture noise; the particle weights then use the exact mixture.
* CPF (eqs. 30-33): each particle carries its own covariance P^i, as in van der Merwe's
  unscented PF; the CKF predict+update of (x^i_{k-1}, P^i_{k-1}) gives the proposal
  N(x^i_{k|k}, P^i_{k|k}) (eq. 30), the particle is drawn from it (eq. 31) and weighted by
  p(z|x) p(x|x_{k-1}) / q (eq. 32); P^i_{k|k} is kept (and copied on resampling). The estimate
  is the weighted mean before resampling (eq. 33 after resampling is the same in expectation
  with more Monte-Carlo noise).
* MOGCPF (eqs. 34-40) is implemented as a Gaussian-sum particle filter (Kotecha & Djuric, the
  paper's ref. 22): G posterior components x K process-noise components give G' predicted
  components (eqs. 35-39, the process-noise mean is added to the cubature mean), each updated
  with every one of the M measurement-noise components gives G'' = G' M components (eq. 40)
  weighted by w_i' gamma_m N(z - mu_m; z_hat, S). N/G'' particles are drawn from each, weighted
  by gamma_m p_m(z|x) N(x; predicted_i') / N(x; updated_j); a component's weight is multiplied
  by its mean particle weight and its moments become the weighted particle moments (the
  cubature moments when its effective sample size is below 2n). The reduction G'' -> G keeps
  the G - 1 heaviest components and merges the rest by moment matching (``reduce_mixture``).
* EM-MOGCPF (eqs. 41-45): the same G'' cubature posterior is the importance density q for N
  particles (allocated to components by systematic resampling of the weights), weighted by
  p(z|x) p_G'(x) / q(x) with the exact mixture likelihood and the predicted G'-mixture; weighted
  EM (``mixtures.weighted_em``) refits G components, warm-started from the moment-matched
  children of each predicted component. Estimate and covariance are eq. 45. No resampling is
  needed: the EM refit replaces it, as the paper says.
* Initial mixtures (G > 1): component means drawn from N(x0, P0/2) with covariances P0/2, so
  the mixture's covariance is about P0 and the components are not identical (identical
  components would never separate under EM or Gaussian-sum updates).
* Extra baseline ``GaussianSumCKF``: the Gaussian-sum CKF with the exact mixture measurement
  noise (MOGCPF without particles), reduced to G components by ``reduce_mixture``.
* Outlier gate (not in the paper): a measurement entry more than 100 standard deviations of S
  from its prediction is left out of the cubature update (see ``CubatureUpdateBatch``); the
  particle weights still use the exact likelihood, normalised in the log domain. When the
  likelihood underflows at every particle (below the smallest normal double) the measurement is
  treated as carrying no information for the weights (``informative``): the log domain would
  otherwise hand all the weight to whichever particle lies nearest the outlier.
* A cubature step whose Cholesky guard fails (ok = 0) is rerun after repairing the offending
  input covariances by symmetrising and clipping eigenvalues at 1e-9 (relative).
"""
from __future__ import annotations

import functools
import os
import threading

import numpy as np

from .mixtures import LOG_2PI, GaussianMixture, logsumexp, weighted_em, weighted_moments
from .resampling import ResamplingPolicy, normalise_log_weights, systematic_resample

# ---------------------------------------------------------------------------------------------
# batched generated C


def _f_zeros(*shape) -> np.ndarray:
    return np.zeros(shape, order="F")


#: batches of at least this many slices are split over the cores (ctypes releases the GIL)
PARALLEL_MIN_SLICES = 64


class _Worker:
    """A persistent thread that runs one job at a time, handed over through two locks.

    Cheaper than ``ThreadPoolExecutor.submit`` + ``Future.result`` (no future, queue or condition
    variable; measured ~70-100 us less per parallel batch on the 2-core machine), which matters
    when a whole batch takes ~1 ms.
    """

    def __init__(self, index: int):
        self._go, self._done = threading.Lock(), threading.Lock()
        self._go.acquire()
        self._done.acquire()
        self._job = None
        self._error: BaseException | None = None
        threading.Thread(target=self._loop, daemon=True, name=f"abyssal-batch-{index}").start()

    def _loop(self) -> None:
        while True:
            self._go.acquire()
            job, self._job = self._job, None
            try:
                job()
            except BaseException as error:  # handed to the caller in wait()
                self._error = error
            finally:
                self._done.release()

    def start(self, job) -> None:
        self._job = job
        self._go.release()

    def wait(self) -> None:
        self._done.acquire()
        error, self._error = self._error, None
        if error is not None:
            raise error


_WORKERS: list[_Worker] | None = None
#: held while the workers run a batch; a second thread evaluating at the same time runs its chunks itself
_WORKERS_BUSY = threading.Lock()


def _workers() -> list[_Worker]:
    global _WORKERS
    if _WORKERS is None:
        _WORKERS = [_Worker(i) for i in range(max(1, (os.cpu_count() or 1) - 1))]
    return _WORKERS


def _forget_threads_after_fork() -> None:
    global _WORKERS, _WORKERS_BUSY
    _WORKERS, _WORKERS_BUSY = None, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_threads_after_fork)


class ParallelBatch:
    """A generated function bound over `capacity` slices, evaluated in contiguous chunks on all cores.

    `batched` flags which inputs carry one slice per column of their last axis (the others are
    shared). Each chunk is its own ``bind_batch`` on views of the same buffers, so results land in
    place; the calling thread evaluates the first chunk while persistent worker threads (``_Worker``)
    evaluate the others (when another thread holds the workers, the caller runs every chunk itself). Every slice is the
    same scalar C call whatever the split, so results do not depend on it.
    """

    def __init__(self, fn, inputs, batched, outputs, capacity: int):
        self.capacity = capacity
        n_chunks = min(os.cpu_count() or 1, 4) if capacity >= PARALLEL_MIN_SLICES else 1
        bounds = np.linspace(0, capacity, n_chunks + 1).astype(int)
        self._chunks = []
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            ins = [a[..., lo:hi] if b else a for a, b in zip(inputs, batched)]
            outs = [a[..., lo:hi] for a in outputs]
            self._chunks.append((lo, hi, fn.bind_batch(ins, outs, hi - lo)))

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
        lo, hi, first = self._chunks[0]
        rest = [(binding, lo_, min(count, hi_)) for lo_, hi_, binding in self._chunks[1:] if count > lo_]
        if len(rest) <= len(_workers()) and _WORKERS_BUSY.acquire(blocking=False):
            try:
                workers = _workers()
                started = []
                try:
                    for worker, (binding, lo_, hi_) in zip(workers, rest):
                        worker.start(functools.partial(_run_chunk, binding, lo_, hi_, then))
                        started.append(worker)
                    _run_chunk(first, lo, min(count, hi), then)
                finally:
                    errors = []
                    for worker in started:  # every started chunk must finish before the buffers are reused
                        try:
                            worker.wait()
                        except BaseException as error:
                            errors.append(error)
                if errors:
                    raise errors[0]
            finally:
                _WORKERS_BUSY.release()
            return
        _run_chunk(first, lo, min(count, hi), then)
        for binding, lo_, hi_ in rest:
            _run_chunk(binding, lo_, hi_, then)


def _run_chunk(binding, lo: int, hi: int, then) -> None:
    binding(hi - lo)
    if then is not None:
        then(lo, hi)


def nearest_positive_definite(covariances: np.ndarray, relative_floor: float = 1e-9) -> np.ndarray:
    """Symmetrised copies of (n, n, k) covariances with eigenvalues clipped at relative_floor * max."""
    A = np.moveaxis(covariances, -1, 0)
    A = 0.5 * (A + np.swapaxes(A, -1, -2))
    vals, vecs = np.linalg.eigh(A)
    floor = relative_floor * np.maximum(np.abs(vals).max(axis=-1, keepdims=True), 1e-300)
    vals = np.maximum(vals, floor)
    return np.moveaxis((vecs * vals[:, None, :]) @ np.swapaxes(vecs, -1, -2), 0, -1)


def _repair_failed_slices(ok: np.ndarray, cov: np.ndarray, evaluate, count: int) -> None:
    """Slices whose Cholesky guard failed (ok = 0): repair their input covariance, evaluate again."""
    if count and ok[0, :count].min() == 0:  # ok is 0 or 1
        failed = np.flatnonzero(ok[0, :count] == 0)
        cov[:, :, failed] = nearest_positive_definite(cov[:, :, failed])
        evaluate(count)


class CubaturePredictBatch:
    """``ckf_predict`` (eqs. 22-24) over up to `capacity` Gaussians held in preallocated buffers.

    Inputs: mean (n, cap), cov (n, n, cap), Q (n, n, cap) (all Fortran-ordered), u (n_u,), dt;
    outputs mean_pred, cov_pred, ok (1, cap).
    """

    def __init__(self, bundle, capacity: int, p: np.ndarray):
        n = bundle.n_x
        self.capacity = capacity
        self.mean, self.cov, self.Q = _f_zeros(n, capacity), _f_zeros(n, n, capacity), _f_zeros(n, n, capacity)
        self.u, self.p, self.dt = np.zeros(bundle.n_u), np.array(p, dtype=np.float64), np.zeros(1)
        self.mean_pred, self.cov_pred, self.ok = _f_zeros(n, capacity), _f_zeros(n, n, capacity), _f_zeros(1, capacity)
        self._eval = ParallelBatch(bundle.function("ckf_predict"), [self.mean, self.cov, self.u, self.p, self.dt, self.Q],
                                   [True, True, False, False, False, True], [self.mean_pred, self.cov_pred, self.ok], capacity)

    def __call__(self, count: int) -> None:
        self._eval(count)
        _repair_failed_slices(self.ok, self.cov, self._eval, count)


class CubatureUpdateBatch:
    """``ckf_update`` (eqs. 25-29) over up to `capacity` Gaussians.

    Inputs: mean (n, cap), cov (n, n, cap) -- pass the predict batch's outputs to chain without
    copying -- z (n_y, cap), R (n_y, n_y, cap); outputs mean_post, cov_post, innovation, S, ok.

    Outlier gate: a measurement entry whose innovation exceeds ``gate_sigma`` standard deviations
    of S is masked out of that slice's update (all slices when ``gate_jointly``, so mixture
    components stay comparable) and the batch is re-evaluated. At the default 100 sigma this only
    fires on absurd measurements; it keeps an outlier far beyond every particle from throwing the
    cubature means (and the nonlinear model after them) to overflow. For the particle filters it
    changes only the proposal, never the weights, which keep the exact likelihood.
    """

    def __init__(self, bundle, capacity: int, p: np.ndarray, mean: np.ndarray | None = None,
                 cov: np.ndarray | None = None, gate_sigma: float = 100.0, gate_jointly: bool = False):
        n, m = bundle.n_x, bundle.n_y
        self.capacity = capacity
        self.mean = _f_zeros(n, capacity) if mean is None else mean
        self.cov = _f_zeros(n, n, capacity) if cov is None else cov
        self.z, self.R, self.mask = _f_zeros(m, capacity), _f_zeros(m, m, capacity), np.ones((m, capacity), order="F")
        self.p = np.array(p, dtype=np.float64)
        self.gate_sigma, self.gate_jointly = gate_sigma, gate_jointly
        self.gated = 0  # number of measurement entries masked by the gate in the last call
        self.mean_post, self.cov_post = _f_zeros(n, capacity), _f_zeros(n, n, capacity)
        self.innovation, self.S, self.ok = _f_zeros(m, capacity), _f_zeros(m, m, capacity), _f_zeros(1, capacity)
        self._eval = ParallelBatch(bundle.function("ckf_update"), [self.mean, self.cov, self.z, self.p, self.R, self.mask],
                                   [True, True, True, False, True, True],
                                   [self.mean_post, self.cov_post, self.innovation, self.S, self.ok], capacity)

    def __call__(self, count: int) -> None:
        if self.gated:
            self.mask.fill(1.0)
            self.gated = 0
        self._eval(count)
        _repair_failed_slices(self.ok, self.cov, self._eval, count)
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
        return np.abs(self.innovation[:, :count]) > self.gate_sigma * np.sqrt(variances)

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
    and gating logic. Only valid when nothing is added between predict and update (zero-mean
    process noise).
    """

    def __init__(self, bundle, predict: CubaturePredictBatch, update: CubatureUpdateBatch):
        if update.mean is not predict.mean_pred or update.cov is not predict.cov_pred:
            raise ValueError("CubatureStepBatch needs an update batch chained to the predict batch")
        self.predict, self.update = predict, update
        self.capacity = min(predict.capacity, update.capacity)
        self.mask = np.ones_like(update.mask)  # never gated: a gated step goes through the two-stage path
        self._eval = ParallelBatch(
            bundle.function("ckf_step"),
            [predict.mean, predict.cov, predict.u, predict.p, predict.dt, predict.Q, update.z, update.R, self.mask],
            [True, True, False, False, False, True, True, True, True],
            [update.mean_post, update.cov_post, update.innovation, update.S, update.ok], self.capacity)

    def __call__(self, count: int, then=None) -> bool:
        """Predict + update slices 0..count-1. `then(lo, hi)` is passed to ``ParallelBatch`` (it
        sees the fused results). Returns False when the step was redone by the two-stage path (the
        results `then` saw are stale)."""
        self._eval(count, then)
        if count == 0 or (self.update.ok[0, :count].min() != 0 and not self.update.outliers(count).any()):
            return True  # every slice passed its guards (ok is 0 or 1) and nothing was gated
        self.predict(count)
        self.update(count)
        return False


class ModelBatch:
    """f and h of a bundle over (n, N) C-ordered particle batches (SIMD kernels, ``bind_soa``)."""

    def __init__(self, bundle, capacity: int, p: np.ndarray):
        n = bundle.n_x
        self.capacity = capacity
        self.x = np.zeros((n, capacity))
        self.u = np.zeros((bundle.n_u, capacity))
        self.p, self.dt = np.array(p, dtype=np.float64), np.zeros(1)
        self.x_next = np.zeros((n, capacity))
        self.y = np.zeros((bundle.n_y, capacity))
        self._f = bundle.function("f").bind_soa([self.x, self.u, self.p, self.dt], [self.x_next])
        self._h = bundle.function("h").bind_soa([self.x, self.p], [self.y])

    def propagate(self, u: np.ndarray, dt: float) -> np.ndarray:
        """x_next = f(x, u) for every column of self.x (fill self.x first)."""
        self.u[...] = u[:, None]
        self.dt[0] = dt
        self._f(self.capacity)
        return self.x_next

    def measure(self) -> np.ndarray:
        """y = h(x) for every column of self.x."""
        self._h(self.capacity)
        return self.y


def measurement_residuals(z: np.ndarray, y: np.ndarray, angle_outputs) -> np.ndarray:
    """z - y for each column of y (n_y, N), angle rows wrapped to (-pi, pi]."""
    r = z[:, None] - y
    for i in angle_outputs:
        if np.abs(r[i]).max() > np.pi:
            r[i] = -np.remainder(-r[i] + np.pi, 2 * np.pi) + np.pi
    return r


#: log of the smallest normal double: a likelihood below it at every particle underflows to zero
LOG_UNDERFLOW = float(np.log(np.finfo(np.float64).tiny))


def informative(log_likelihoods: np.ndarray) -> np.ndarray:
    """The log-likelihoods, or zeros when every one underflows (the measurement carries no usable
    information: all-zero likelihoods would give 0/0 weights, so the weights are left as they were)."""
    if log_likelihoods.max() < LOG_UNDERFLOW:
        return np.zeros_like(log_likelihoods)
    return log_likelihoods


def _check_problem(bundle, x0, P0, process_noise: GaussianMixture, measurement_noise: GaussianMixture):
    x0 = np.asarray(x0, dtype=np.float64)
    P0 = np.asarray(P0, dtype=np.float64)
    if x0.shape != (bundle.n_x,) or P0.shape != (bundle.n_x, bundle.n_x):
        raise ValueError(f"x0 must be ({bundle.n_x},) and P0 ({bundle.n_x}, {bundle.n_x}); got {x0.shape}, {P0.shape}")
    if process_noise.dim != bundle.n_x:
        raise ValueError(f"process noise must be {bundle.n_x}-dimensional (additive on the discrete state)")
    if measurement_noise.dim != bundle.n_y:
        raise ValueError(f"measurement noise must be {bundle.n_y}-dimensional")
    return x0, P0


# ---------------------------------------------------------------------------------------------
# Gaussian-mixture bookkeeping shared by the mixture filters


def merge_components(weights: np.ndarray, means: np.ndarray, covariances: np.ndarray):
    """Moment-matched single Gaussian (weight, mean, covariance) of weighted components."""
    total = weights.sum()
    mixture = GaussianMixture(weights, means, covariances)
    return total, mixture.mean(), mixture.covariance()


def reduce_mixture(mixture: GaussianMixture, n_components: int) -> GaussianMixture:
    """Keep the n_components - 1 heaviest components; merge the others into one (moment matching)."""
    if mixture.n_components <= n_components:
        return mixture
    order = np.argsort(-mixture.weights)
    keep, rest = order[: n_components - 1], order[n_components - 1:]
    w_rest, m_rest, c_rest = merge_components(mixture.weights[rest], mixture.means[rest], mixture.covariances[rest])
    return GaussianMixture(np.append(mixture.weights[keep], w_rest), np.vstack([mixture.means[keep], m_rest]),
                           np.concatenate([mixture.covariances[keep], c_rest[None]]))


def initial_mixture(x0: np.ndarray, P0: np.ndarray, n_components: int, rng: np.random.Generator) -> GaussianMixture:
    """G components whose mixture is about N(x0, P0): means from N(x0, P0/2), covariances P0/2."""
    if n_components == 1:
        return GaussianMixture.gaussian(x0, P0)
    L = np.linalg.cholesky(P0 / 2)
    means = x0[None, :] + (L @ rng.standard_normal((x0.shape[0], n_components))).T
    return GaussianMixture(np.full(n_components, 1.0 / n_components), means, np.repeat((P0 / 2)[None], n_components, 0))


class _GaussianSumCubature:
    """Predict (G -> G' = G K) and update (G' -> G'' = G' M) of a Gaussian sum by batched cubature steps."""

    def __init__(self, bundle, n_components: int, process_noise: GaussianMixture, measurement_noise: GaussianMixture,
                 p: np.ndarray):
        self.bundle = bundle
        self.G, self.K, self.M = n_components, process_noise.n_components, measurement_noise.n_components
        self.process_noise, self.measurement_noise = process_noise, measurement_noise
        g1, g2 = self.G * self.K, self.G * self.K * self.M
        self.predict_batch = CubaturePredictBatch(bundle, g1, p)
        self.update_batch = CubatureUpdateBatch(bundle, g2, p, gate_jointly=True)
        # process component r of posterior component i sits at slice i K + r (eq. 35)
        self.predict_batch.Q[...] = np.moveaxis(np.tile(process_noise.covariances, (self.G, 1, 1)), 0, -1)
        # measurement component m of predicted component i' sits at slice i' M + m (eq. 40)
        self.update_batch.R[...] = np.moveaxis(np.tile(measurement_noise.covariances, (g1, 1, 1)), 0, -1)

    def predict(self, posterior: GaussianMixture, u: np.ndarray, dt: float) -> GaussianMixture:
        pb, K, G = self.predict_batch, self.K, posterior.n_components
        if G > self.G:
            raise ValueError(f"posterior has {G} components; the cubature bank holds {self.G}")
        count = G * K
        pb.mean[:, :count] = np.repeat(posterior.means, K, axis=0).T
        pb.cov[:, :, :count] = np.moveaxis(np.repeat(posterior.covariances, K, axis=0), 0, -1)
        pb.u[...] = u
        pb.dt[0] = dt
        pb(count)
        means = pb.mean_pred[:, :count].T + np.tile(self.process_noise.means, (G, 1))  # f(X) + u_v (eq. 38)
        weights = np.outer(posterior.weights, self.process_noise.weights).reshape(-1)  # eq. 36
        return GaussianMixture(weights, means, np.moveaxis(pb.cov_pred[:, :, :count], -1, 0).copy())

    def update(self, predicted: GaussianMixture, z: np.ndarray) -> GaussianMixture:
        ub, M, G1 = self.update_batch, self.M, predicted.n_components
        g2 = G1 * M
        ub.mean[:, :g2] = np.repeat(predicted.means, M, axis=0).T
        ub.cov[:, :, :g2] = np.moveaxis(np.repeat(predicted.covariances, M, axis=0), 0, -1)
        ub.z[:, :g2] = (z[None, :] - np.tile(self.measurement_noise.means, (G1, 1))).T
        ub(g2)
        log_w = (np.log(np.repeat(predicted.weights, M)) + np.log(np.tile(self.measurement_noise.weights, G1))
                 + ub.log_evidence(g2))  # eq. 40: w_i' gamma_m N(z - mu_m; z_hat, S)
        weights = np.exp(log_w - logsumexp(log_w))
        return GaussianMixture(np.maximum(weights, 1e-300), ub.mean_post[:, :g2].T.copy(),
                               np.moveaxis(ub.cov_post[:, :, :g2], -1, 0).copy())


# ---------------------------------------------------------------------------------------------
# filters


class CubatureKalmanFilter:
    """CKF (eqs. 22-29) on the generated steps; mixture noises enter by their moment-matched Gaussian."""

    name = "CKF"

    def __init__(self, bundle, x0, P0, process_noise: GaussianMixture, measurement_noise: GaussianMixture, p=None):
        x0, P0 = _check_problem(bundle, x0, P0, process_noise, measurement_noise)
        p = bundle.params(p)
        self._predict = CubaturePredictBatch(bundle, 1, p)
        self._update = CubatureUpdateBatch(bundle, 1, p, self._predict.mean_pred, self._predict.cov_pred)
        self._predict.Q[:, :, 0] = process_noise.covariance()
        self._q_mean = process_noise.mean()
        self._update.R[:, :, 0] = measurement_noise.covariance()
        self._r_mean = measurement_noise.mean()
        self.estimate, self.covariance = x0.copy(), P0.copy()

    def step(self, u, z, dt) -> None:
        pb, ub = self._predict, self._update
        pb.mean[:, 0], pb.cov[:, :, 0] = self.estimate, self.covariance
        pb.u[...] = u
        pb.dt[0] = dt
        pb(1)
        pb.mean_pred[:, 0] += self._q_mean
        ub.z[:, 0] = np.asarray(z) - self._r_mean
        ub(1)
        self.estimate, self.covariance = ub.mean_post[:, 0].copy(), ub.cov_post[:, :, 0].copy()


class ParticleFilter:
    """Bootstrap SIR particle filter (PF): proposal p(x_k|x_{k-1}), weights p(z|x) in the log domain."""

    name = "PF"

    def __init__(self, bundle, x0, P0, process_noise: GaussianMixture, measurement_noise: GaussianMixture,
                 n_particles: int, rng: np.random.Generator, policy: ResamplingPolicy = ResamplingPolicy(), p=None):
        x0, P0 = _check_problem(bundle, x0, P0, process_noise, measurement_noise)
        self.bundle, self.rng, self.policy = bundle, rng, policy
        self.n = n_particles
        self.process_noise, self.measurement_noise = process_noise, measurement_noise
        self.angle_outputs = bundle.angle_outputs
        self.model = ModelBatch(bundle, n_particles, bundle.params(p))
        self.particles = self.model.x  # (n, N) C-ordered, the input buffer of f and h
        self.particles[...] = GaussianMixture.gaussian(x0, P0).sample(rng, n_particles)[0]
        self.log_weights = np.full(n_particles, -np.log(n_particles))
        self.weights = np.full(n_particles, 1.0 / n_particles)
        gaussian_q = process_noise.n_components == 1
        q_cov = process_noise.covariances[0]
        self._q_diagonal_std = np.sqrt(np.diag(q_cov)) if gaussian_q and np.count_nonzero(q_cov - np.diag(np.diag(q_cov))) == 0 else None
        self._q_diagonal_std_col = None if self._q_diagonal_std is None else self._q_diagonal_std[:, None].copy()
        self._q_mean_col = process_noise.means[0][:, None].copy() if process_noise.means[0].any() else None
        self._noise = np.empty((bundle.n_x, n_particles))
        self._uniform_log_weight = -np.log(n_particles)
        self._log_n = float(np.log(n_particles))
        self._resample_always = policy.threshold >= 1.0
        self._resample_below = policy.threshold * n_particles
        self.estimate, self.covariance = x0.copy(), P0.copy()
        self.ess = float(n_particles)

    def _process_noise_sample(self) -> np.ndarray:
        if self._q_diagonal_std is not None:
            noise = self.rng.standard_normal(out=self._noise)
            noise *= self._q_diagonal_std_col
            if self._q_mean_col is not None:
                noise += self._q_mean_col
            return noise
        return self.process_noise.sample(self.rng, self.n)[0]

    def _log_likelihoods(self, z: np.ndarray) -> np.ndarray:
        """informative(log p(z | x)) of every particle (h evaluated on self.particles)."""
        residuals = measurement_residuals(z, self.model.measure(), self.angle_outputs)
        return informative(self.measurement_noise.log_density(residuals))

    def step(self, u, z, dt) -> None:
        x_next = self.model.propagate(np.asarray(u, dtype=np.float64), dt)
        np.add(x_next, self._process_noise_sample(), out=self.particles)
        log_w = self._log_likelihoods(np.asarray(z, dtype=np.float64))
        log_w += self.log_weights
        self._reweight(log_w)

    def _reweight(self, log_weights: np.ndarray) -> None:
        """Normalise, publish the moments, resample when the ESS is low. log_weights may be modified."""
        self.weights, log_mean = normalise_log_weights(log_weights)
        self.ess = 1.0 / float(self.weights @ self.weights)
        self.estimate, self.covariance = weighted_moments(self.particles, self.weights)  # before resampling
        if self._resample_always or self.ess < self._resample_below:
            ancestors = self.policy.ancestors(self.weights, self.rng)
            self.particles[...] = self.particles[:, ancestors]
            self._resampled(ancestors)
            self.log_weights = np.full(self.n, self._uniform_log_weight)
        else:
            self._kept()
            if np.isfinite(log_mean):
                log_weights -= log_mean + self._log_n  # normalised, in the log domain
                self.log_weights = log_weights
            else:
                self.log_weights = np.full(self.n, self._uniform_log_weight)

    def _resampled(self, ancestors: np.ndarray) -> None:
        """Hook for per-particle state carried beside the particles."""

    def _kept(self) -> None:
        """Hook: the step ended without resampling."""


class CubatureParticleFilter(ParticleFilter):
    """CPF (eqs. 30-33): per-particle cubature proposal, weights p(z|x) p(x|x_prev) / q."""

    name = "CPF"

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_particles, rng,
                 policy: ResamplingPolicy = ResamplingPolicy(), p=None):
        super().__init__(bundle, x0, P0, process_noise, measurement_noise, n_particles, rng, policy, p)
        p = bundle.params(p)
        n = bundle.n_x
        self._predict = CubaturePredictBatch(bundle, n_particles, p)
        self._update = CubatureUpdateBatch(bundle, n_particles, p, self._predict.mean_pred, self._predict.cov_pred)
        self._predict.Q[...] = process_noise.covariance()[:, :, None]
        self._update.R[...] = measurement_noise.covariance()[:, :, None]
        self._q_mean, self._r_mean = process_noise.mean(), measurement_noise.mean()
        self._q_mean_col = self._q_mean[:, None].copy()
        # zero-mean process noise: nothing happens between predict and update, so they run fused
        self._step = None if self._q_mean.any() else CubatureStepBatch(bundle, self._predict, self._update)
        self._predict.cov[...] = P0[:, :, None]  # P^i_0
        self._gaussian_process = process_noise.n_components == 1
        self._n_log_2pi = n * LOG_2PI
        # views and scratch reused every step
        self._cov_post_stack = np.moveaxis(self._update.cov_post, -1, 0)  # (N, n, n) view, each matrix contiguous
        self._xi = np.empty((n, n_particles))
        self._xi_columns = self._xi.T[:, :, None]  # (N, n, 1) view
        self._offsets = np.empty((n_particles, n, 1))  # L^i xi^i
        self._log_det = np.empty(n_particles)  # log det L^i
        self._factor_failed = False

    def _factor(self, lo: int, hi: int) -> None:
        """Slices lo..hi-1: L^i = chol(P^i_{k|k}), the draw offsets L^i xi^i and log det L^i."""
        L = np.linalg.cholesky(self._cov_post_stack[lo:hi])
        np.matmul(L, self._xi_columns[lo:hi], out=self._offsets[lo:hi])
        self._log_det[lo:hi] = _log_det_triangular(L)

    def _factor_chunk(self, lo: int, hi: int) -> None:
        """``_factor`` run beside the generated step on each core; a failure is redone (and raised) later."""
        try:
            self._factor(lo, hi)
        except np.linalg.LinAlgError:
            self._factor_failed = True

    def step(self, u, z, dt) -> None:
        u = np.asarray(u, dtype=np.float64)
        z = np.asarray(z, dtype=np.float64)
        pb, ub, N = self._predict, self._update, self.n
        # transition means f(x_{k-1}) for p(x_k | x_{k-1}) in eq. 32
        f_prev = self.model.propagate(u, dt)  # x_next buffer: untouched until the next step
        # the standard normal draws of eq. 31 (no other draw happens before them in this step)
        xi = self.rng.standard_normal(out=self._xi)
        # eq. 30: the cubature importance density of every particle, one batched C call
        pb.mean[...] = self.particles
        pb.u[...] = u
        pb.dt[0] = dt
        ub.z[...] = (z - self._r_mean)[:, None]
        self._factor_failed = False
        if self._step is not None:
            # predict + update fused; each core factors its own chunk's P^i_{k|k} right after
            factored = self._step(N, then=self._factor_chunk)
        else:
            pb(N)
            pb.mean_pred += self._q_mean_col
            ub(N)
            factored = False
        if not factored or self._factor_failed:
            self._factor(0, N)
        # eq. 31: x^i ~ N(x^i_{k|k}, P^i_{k|k}) = x^i_{k|k} + L^i xi^i
        np.add(ub.mean_post, self._offsets[:, :, 0].T, out=self.particles)
        # -log q = 0.5 |xi|^2 + log det L + n/2 log 2 pi
        log_w = np.einsum("ij,ij->j", xi, xi)
        log_w *= 0.5
        log_w += self._log_det
        # eq. 32: p(z|x) p(x|x_prev) / q
        log_w += self.process_noise.log_density(self.particles - f_prev)
        log_w += self._log_likelihoods(z)
        log_w += self.log_weights
        log_w += 0.5 * self._n_log_2pi
        self._reweight(log_w)

    def _resampled(self, ancestors: np.ndarray) -> None:
        self._predict.cov[...] = self._update.cov_post[:, :, ancestors]  # P^i_{k|k} travels with its particle

    def _kept(self) -> None:
        self._predict.cov[...] = self._update.cov_post


def _log_det_triangular(L: np.ndarray) -> np.ndarray:
    """sum_i log L_ii of stacked triangular factors (K, n, n): (K,). Computed matrix by matrix, so the
    result does not depend on how a batch is split over the cores."""
    n = L.shape[-1]
    diag = L.reshape(L.shape[0], n * n)[:, :: n + 1] if L.flags.c_contiguous else np.diagonal(L, axis1=1, axis2=2)
    return np.log(diag).sum(axis=1)


class _MixtureFilterBase:
    """Common set-up of the Gaussian-sum filters: G-component posterior, cubature bank, estimate (eq. 45)."""

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_components, rng, p):
        x0, P0 = _check_problem(bundle, x0, P0, process_noise, measurement_noise)
        self.bundle, self.rng, self.G = bundle, rng, n_components
        self.process_noise, self.measurement_noise = process_noise, measurement_noise
        self.angle_outputs = bundle.angle_outputs
        self.cubature = _GaussianSumCubature(bundle, n_components, process_noise, measurement_noise, bundle.params(p))
        self.posterior = initial_mixture(x0, P0, n_components, rng)
        self.estimate, self.covariance = x0.copy(), P0.copy()

    def _publish(self, mixture: GaussianMixture) -> None:
        self.estimate, self.covariance = mixture.mean(), mixture.covariance()  # eq. 45


class GaussianSumCKF(_MixtureFilterBase):
    """Gaussian-sum CKF with the exact mixture measurement noise (extra baseline, no particles)."""

    name = "GS-CKF"

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_components: int = 2,
                 rng: np.random.Generator | None = None, p=None):
        if rng is None and n_components > 1:
            raise ValueError("GaussianSumCKF with n_components > 1 needs rng (it spreads the initial components)")
        super().__init__(bundle, x0, P0, process_noise, measurement_noise, n_components, rng, p)

    def step(self, u, z, dt) -> None:
        predicted = self.cubature.predict(self.posterior, np.asarray(u, dtype=np.float64), dt)
        updated = self.cubature.update(predicted, np.asarray(z, dtype=np.float64))
        self._publish(updated)
        self.posterior = reduce_mixture(updated, self.G)


class _SampledMixtureFilter(_MixtureFilterBase):
    """Particles drawn from the G'' cubature posterior and weighted with the exact likelihood."""

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_particles, n_components, rng, p):
        super().__init__(bundle, x0, P0, process_noise, measurement_noise, n_components, rng, p)
        self.n = n_particles
        self.model = ModelBatch(bundle, n_particles, bundle.params(p))
        self.particles = self.model.x
        self.ess = float(n_particles)

    def _draw(self, proposal: GaussianMixture, labels: np.ndarray) -> np.ndarray:
        """Fill self.particles with draws from the proposal components named by labels; returns xi."""
        L = np.linalg.cholesky(proposal.covariances)
        xi = self.rng.standard_normal((self.bundle.n_x, self.n))
        self.particles[...] = proposal.means[labels].T + (L[labels] @ xi.T[:, :, None])[:, :, 0].T
        return xi

    def _log_likelihoods_by_component(self, z: np.ndarray) -> np.ndarray:
        """log gamma_m p_m(z | x) of every particle, (M, N)."""
        residuals = measurement_residuals(z, self.model.measure(), self.angle_outputs)
        return informative(self.measurement_noise.weighted_component_log_densities(residuals))


class MixtureCubatureParticleFilter(_SampledMixtureFilter):
    """MOGCPF (eqs. 34-40) as a Gaussian-sum particle filter over cubature-updated components."""

    name = "MOGCPF"

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_particles: int, rng,
                 n_components: int = 2, p=None):
        super().__init__(bundle, x0, P0, process_noise, measurement_noise, n_particles, n_components, rng, p)
        g2 = n_components * process_noise.n_components * measurement_noise.n_components
        if n_particles < g2:
            raise ValueError(f"MOGCPF needs at least G'' = {g2} particles")
        # equal allocation: particle j belongs to component j mod G'' (N/G'' each, remainder spread)
        self._labels = np.arange(n_particles) % g2

    def step(self, u, z, dt) -> None:
        z = np.asarray(z, dtype=np.float64)
        predicted = self.cubature.predict(self.posterior, np.asarray(u, dtype=np.float64), dt)
        updated = self.cubature.update(predicted, z)
        M, n = self.cubature.M, self.bundle.n_x
        labels = self._labels
        xi = self._draw(updated, labels)
        parent, noise = labels // M, labels % M
        L_diag = np.log(np.diagonal(np.linalg.cholesky(updated.covariances), axis1=1, axis2=2)).sum(1)
        log_q = -0.5 * (np.einsum("ij,ij->j", xi, xi) + n * LOG_2PI) - L_diag[labels]
        log_prior = predicted.component_log_densities(self.particles)[parent, np.arange(self.n)]
        log_lik = self._log_likelihoods_by_component(z)[noise, np.arange(self.n)]
        log_w = log_lik + log_prior - log_q
        # per-component evidence, weights and moments
        g2 = updated.n_components
        weights = np.empty(g2)
        means, covs = updated.means.copy(), updated.covariances.copy()
        for j in range(g2):  # loop over the few components, each a vectorised batch of particles
            members = labels == j
            lw = log_w[members]
            log_mean_w = logsumexp(lw) - np.log(lw.shape[0])
            weights[j] = np.log(predicted.weights[j // M]) + np.log(self.measurement_noise.weights[j % M]) + log_mean_w
            w, _ = normalise_log_weights(lw)
            if 1.0 / (w @ w) >= 2 * n:
                means[j], covs[j] = weighted_moments(self.particles[:, members], w)
                covs[j] += 1e-9 * np.eye(n)
        weights = np.exp(weights - logsumexp(weights)) if np.isfinite(logsumexp(weights)) else updated.weights
        refit = GaussianMixture(np.maximum(weights, 1e-300), means, covs)
        self.ess = 1.0 / float(np.sum(normalise_log_weights(log_w)[0] ** 2))
        self._publish(refit)
        self.posterior = reduce_mixture(refit, self.G)


class EMMixtureCubatureParticleFilter(_SampledMixtureFilter):
    """EM-MOGCPF (eqs. 41-45): cubature Gaussian-sum proposal, exact weights, weighted-EM refit to G."""

    name = "EM-MOGCPF"

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_particles: int, rng,
                 n_components: int = 2, em_tol: float = 1e-3, em_max_iter: int = 20, reg_covar: float = 1e-6, p=None):
        super().__init__(bundle, x0, P0, process_noise, measurement_noise, n_particles, n_components, rng, p)
        self.em_tol, self.em_max_iter, self.reg_covar = em_tol, em_max_iter, reg_covar
        self.em_iterations = 0

    def _warm_start(self, updated: GaussianMixture) -> GaussianMixture:
        """G components: the moment-matched children of each posterior component of the last step."""
        per_parent = updated.n_components // self.G
        weights, means, covs = [], [], []
        for i in range(self.G):
            block = slice(i * per_parent, (i + 1) * per_parent)
            w, m, c = merge_components(updated.weights[block], updated.means[block], updated.covariances[block])
            weights.append(w), means.append(m), covs.append(c)
        return GaussianMixture(np.maximum(weights, 1e-12), np.array(means), np.array(covs))

    def step(self, u, z, dt) -> None:
        z = np.asarray(z, dtype=np.float64)
        predicted = self.cubature.predict(self.posterior, np.asarray(u, dtype=np.float64), dt)  # G -> G'
        updated = self.cubature.update(predicted, z)  # G' -> G''
        labels = systematic_resample(updated.weights, self.rng, self.n)
        self._draw(updated, labels)
        log_lik = logsumexp(self._log_likelihoods_by_component(z), axis=0)
        log_w = log_lik + predicted.log_density(self.particles) - updated.log_density(self.particles)
        weights, _ = normalise_log_weights(log_w)
        self.ess = 1.0 / float(weights @ weights)
        fit = weighted_em(self.particles, weights, self._warm_start(updated), tol=self.em_tol,
                          max_iter=self.em_max_iter, reg_covar=self.reg_covar)  # eqs. 41-44
        self.em_iterations = fit.iterations
        self.posterior = fit.mixture
        self._publish(fit.mixture)  # eq. 45
