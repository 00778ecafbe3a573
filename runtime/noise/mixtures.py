"""Gaussian mixtures: log-densities, sampling, moment matching and weighted EM.

Shapes follow the rest of the runtime: a batch of N points in d dimensions is (d, N); a
mixture of K components has ``weights`` (K,), ``means`` (K, d) and ``covariances`` (K, d, d).

Weighted EM (seed 000 eqs. 41-43): the E-step gives responsibilities r_i(x^k) (eq. 42); the
M-step weights them by the normalised importance weights w^k of the particles, so eq. 43's
1/N becomes sum_k w^k (= 1). Decisions where the paper is silent or ambiguous:

* Initialisation: eq. 41 starts from random means and unit covariances; ``weighted_em`` takes
  any initial mixture (the filters warm-start it from the cubature-updated components, which
  converges in a few iterations; random restarts each step were slower and noisier).
* Stopping (|rho - rho_hat| < v): the largest absolute change of any weight, mean or
  covariance entry between two iterations is below ``tol``, or ``max_iter`` is reached.
* Singular covariances never come out: every M-step adds ``reg_covar * I`` (absolute, as in
  scikit-learn's ``reg_covar``) and a component whose total weight falls below
  ``min_component_weight`` is reset to the overall weighted mean and covariance with that
  minimum weight (the mixture is then renormalised), so a component cannot collapse onto one
  particle or vanish.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from abyssal.arrays import real_array

from ..numerics import SYMMETRY_TOLERANCE
LOG_2PI = float(np.log(2.0 * np.pi))


def logsumexp(a: np.ndarray, axis: int | None = None):
    """log(sum(exp(a))) along axis, stable; -inf where every entry is -inf.

    (scipy.special.logsumexp does the same at ~10x the call overhead, which matters per step.)
    """
    peak = np.max(a, axis=axis, keepdims=True)
    peak = np.where(np.isfinite(peak), peak, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(a - peak), axis=axis, keepdims=True)) + peak
    return out.item() if axis is None else np.squeeze(out, axis=axis)


def cholesky_precision(covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(L^-1, log det covariance) of stacked covariances (K, d, d), with cov = L L^T."""
    L = np.linalg.cholesky(covariances)
    inv_L = np.linalg.inv(L)
    log_det = 2.0 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(-1)
    return inv_L, log_det


#: relative symmetry tolerance of a covariance: max |C - C^T| <= tol * max |C| (as the Kalman filters)


@dataclass(frozen=True, eq=False)
class GaussianMixture:
    """sum_k weights[k] N(means[k], covariances[k]).

    Construction checks its arguments and raises ValueError (TypeError for complex or
    non-numeric arrays) naming the one at fault: ``weights`` (K,) finite, non-negative, with a
    positive sum; ``means`` (K, d) finite; ``covariances`` (K, d, d) finite, symmetric (within
    ``SYMMETRY_TOLERANCE`` relative to each matrix's largest entry; the Cholesky factor reads its
    lower triangle) and positive definite (Cholesky succeeds, and the log-normaliser is finite).
    Weights are renormalised to sum to one: unnormalised weights are a documented input (the
    printed sea-state weights, EM masses), not an error. Weights whose sum overflows are scaled by
    their maximum first. The checks cost a few microseconds (one finiteness reduction, one
    symmetry reduction); their diagnosis only runs on failure.
    """

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    _inv_chol: np.ndarray = field(init=False, repr=False)
    _log_norm: np.ndarray = field(init=False, repr=False)
    _log_weights: np.ndarray = field(init=False, repr=False)
    _neg_half_precision: np.ndarray | None = field(init=False, repr=False)

    def __post_init__(self):
        w = real_array(self.weights, "mixture weights").reshape(-1)
        mu = real_array(self.means, "mixture means")
        cov = real_array(self.covariances, "mixture covariances")
        if mu.ndim != 2 or mu.shape[0] == 0 or mu.shape[1] == 0:
            raise ValueError(f"mixture means must have shape (K, d) with K, d >= 1, got {mu.shape}")
        if w.shape != (mu.shape[0],):
            raise ValueError(f"mixture weights must have shape ({mu.shape[0]},) (one per mean), got {w.shape}")
        if cov.shape != (mu.shape[0], mu.shape[1], mu.shape[1]):
            raise ValueError(f"mixture covariances must have shape {(mu.shape[0], mu.shape[1], mu.shape[1])}, got {cov.shape}")
        with np.errstate(over="ignore", invalid="ignore"):  # huge finite entries may overflow the sums
            total = float(w.sum())
            all_finite = np.isfinite(total + mu.sum() + cov.sum())
        if not (all_finite and total > 0 and w.min() >= 0):
            w, total = self._diagnose(w, mu, cov)
        w = w / total
        variances = np.diagonal(cov, axis1=1, axis2=2)
        # symmetric within the tolerance of each matrix's scale (its largest diagonal entry, which is its
        # largest entry when it is positive semi-definite; a matrix that is not fails the Cholesky below)
        asymmetry = np.abs(cov - cov.transpose(0, 2, 1)).max(axis=(1, 2))
        asymmetric = asymmetry > SYMMETRY_TOLERANCE * np.abs(variances).max(axis=1)
        if asymmetric.any():
            k = int(np.argmax(asymmetric))
            raise ValueError(f"mixture covariances[{k}] is not symmetric (max |C - C^T| = {asymmetry[k]:.3g})")
        object.__setattr__(self, "weights", w)
        with np.errstate(divide="ignore"):
            object.__setattr__(self, "_log_weights", np.log(self.weights))
        object.__setattr__(self, "means", mu)
        object.__setattr__(self, "covariances", cov)
        try:
            inv_L, log_det = cholesky_precision(cov)
        except np.linalg.LinAlgError:
            inv_L = log_det = None
        log_norm = None if log_det is None else -0.5 * (log_det + mu.shape[1] * LOG_2PI)
        # log_det is finite exactly when every pivot is positive and finite (NaN pivots give NaN)
        if log_norm is None or not np.isfinite(log_norm.sum()):
            raise ValueError(f"mixture covariances[{self._first_not_positive_definite(cov)}] is not (numerically) "
                             "positive definite")
        object.__setattr__(self, "_inv_chol", inv_L)
        object.__setattr__(self, "_log_norm", log_norm)
        # Zero-mean mixtures with diagonal covariances (the usual noise models): the quadratic forms of
        # all components are one (K, d) @ (d, N) product of the squared points.
        # (not for a subnormal variance, whose -0.5 / variance overflows: -inf * 0 at the mean would be NaN;
        # the Cholesky path's 1 / sqrt(variance) stays finite there)
        diagonal = not mu.any() and np.array_equal(cov, variances[:, :, None] * np.eye(mu.shape[1])) and np.all(
            variances >= np.finfo(np.float64).tiny)
        object.__setattr__(self, "_neg_half_precision", -0.5 / variances if diagonal else None)

    @staticmethod
    def _diagnose(w: np.ndarray, mu: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, float]:
        """The slow path of the checks: raise naming the argument, or return (weights, a finite positive sum)."""
        for name, arr in (("weights", w), ("means", mu), ("covariances", cov)):
            if not np.all(np.isfinite(arr)):
                bad = np.argwhere(~np.isfinite(arr))[0]
                raise ValueError(f"mixture {name} must be finite; {name}[{', '.join(map(str, bad))}] = {arr[tuple(bad)]}")
        if w.min() < 0:
            raise ValueError(f"mixture weights must be non-negative, got {w}")
        if not w.max() > 0:
            raise ValueError("mixture weights must have a positive sum (they are all zero)")
        with np.errstate(over="ignore"):
            total = float(w.sum())
        if not np.isfinite(total):  # finite weights whose sum overflows (never scaled in place: w may be the caller's)
            w = w / w.max()
            total = float(w.sum())
        return w, total  # (finite means or covariances whose sums overflow are fine)

    @staticmethod
    def _first_not_positive_definite(cov: np.ndarray) -> int:
        for k in range(cov.shape[0]):
            try:
                inv_L, log_det = cholesky_precision(cov[k:k + 1])
            except np.linalg.LinAlgError:
                return k
            if not np.all(np.isfinite(log_det)):
                return k
        return 0

    @classmethod
    def gaussian(cls, mean, covariance) -> "GaussianMixture":
        mean = np.asarray(mean, dtype=np.float64)
        return cls(np.ones(1), mean[None, :], np.asarray(covariance, dtype=np.float64)[None, :, :])

    @property
    def n_components(self) -> int:
        return self.weights.shape[0]

    @property
    def dim(self) -> int:
        return self.means.shape[1]

    def component_log_densities(self, points: np.ndarray) -> np.ndarray:
        """log N(x; mean_k, cov_k) for each component k and column x of points (d, N): (K, N).

        A point so far out that its squared distance overflows gets -inf (density 0), silently.
        """
        with np.errstate(over="ignore"):
            if self._neg_half_precision is not None:
                out = self._neg_half_precision @ (points * points)
            else:
                y = self._inv_chol @ (points[None, :, :] - self.means[:, :, None])
                y *= y
                out = -0.5 * y.sum(axis=1)
        out += self._log_norm[:, None]
        return out

    def weighted_component_log_densities(self, points: np.ndarray) -> np.ndarray:
        """log weight_k + log N(x; mean_k, cov_k) per component and column of points: (K, N)."""
        out = self.component_log_densities(points)
        out += self._log_weights[:, None]
        return out

    def log_density(self, points: np.ndarray) -> np.ndarray:
        """log of the mixture density at each column of points (d, N): (N,)."""
        per_component = self.component_log_densities(points)
        if self.n_components == 1:
            return per_component[0]
        per_component += self._log_weights[:, None]
        if self.n_components == 2:
            return np.logaddexp(per_component[0], per_component[1])
        return logsumexp(per_component, axis=0)

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(points (d, n), component label of each point)."""
        labels = rng.choice(self.n_components, size=n, p=self.weights) if self.n_components > 1 else np.zeros(n, int)
        L = np.linalg.cholesky(self.covariances)
        xi = rng.standard_normal((self.dim, n))
        points = self.means[labels].T + np.einsum("nij,jn->in", L[labels], xi)
        return points, labels

    def mean(self) -> np.ndarray:
        return self.weights @ self.means

    def covariance(self) -> np.ndarray:
        """Covariance of the whole mixture (seed 000 eq. 45)."""
        centred = self.means - self.mean()
        return np.einsum("k,kij->ij", self.weights, self.covariances) + np.einsum("k,ki,kj->ij", self.weights, centred, centred)


def weighted_moments(points: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (d,) and covariance (d, d) of the columns of points, weights summing to one."""
    mean = points.dot(weights)  # (ndarray.dot: BLAS, several times faster than @ for a matrix times a vector)
    centred = points - mean[:, None]
    return mean, (centred * weights).dot(centred.T)


@dataclass(frozen=True)
class EMResult:
    mixture: GaussianMixture
    iterations: int
    converged: bool


def weighted_em(points: np.ndarray, weights: np.ndarray, initial: GaussianMixture, tol: float = 1e-4,
                max_iter: int = 50, reg_covar: float = 1e-6, min_component_weight: float = 1e-4) -> EMResult:
    """Fit a mixture with initial.n_components components to weighted points (seed 000 eqs. 41-43).

    points (d, N); weights (N,) non-negative, normalised here. See the module docstring for the
    stopping rule and the regularisation.
    """
    if not (tol > 0 and max_iter >= 1 and reg_covar > 0):
        raise ValueError("weighted_em needs tol > 0, max_iter >= 1 and reg_covar > 0")
    if not isinstance(initial, GaussianMixture):
        raise TypeError(f"initial must be a GaussianMixture, got {type(initial).__name__}")
    points = real_array(points, "points")
    if points.ndim != 2 or points.shape[0] != initial.dim or points.shape[1] == 0:
        raise ValueError(f"points must have shape ({initial.dim}, N) with N >= 1, got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError("points must be finite")
    w = real_array(weights, "weights")
    if w.shape != (points.shape[1],):
        raise ValueError(f"weights must have shape ({points.shape[1]},) (one per point), got {w.shape}")
    if not (np.all(np.isfinite(w)) and w.min() >= 0 and w.sum() > 0):
        raise ValueError("weights must be finite and non-negative with a positive sum")
    w = w / w.sum()
    d = points.shape[0]
    ridge = reg_covar * np.eye(d)
    mixture = initial
    overall = None
    for iteration in range(1, max_iter + 1):
        # E-step, eq. 42: responsibilities in the log domain.
        log_joint = mixture.component_log_densities(points) + np.log(mixture.weights)[:, None]
        resp = np.exp(log_joint - logsumexp(log_joint, axis=0))
        # M-step, eq. 43 with importance weights.
        rw = resp * w
        mass = rw.sum(axis=1)
        safe_mass = np.maximum(mass, np.finfo(float).tiny)
        means = (rw @ points.T) / safe_mass[:, None]
        centred = points[None, :, :] - means[:, :, None]
        covs = np.einsum("kin,kjn->kij", centred * rw[:, None, :], centred) / safe_mass[:, None, None] + ridge
        starved = mass < min_component_weight
        if np.any(starved):
            if overall is None:
                overall = weighted_moments(points, w)
            means[starved] = overall[0]
            covs[starved] = overall[1] + ridge
            mass = np.where(starved, min_component_weight, mass)
        new = GaussianMixture(mass, means, covs)
        change = max(np.max(np.abs(new.weights - mixture.weights)), np.max(np.abs(new.means - mixture.means)),
                     np.max(np.abs(new.covariances - mixture.covariances)))
        mixture = new
        if change < tol:
            return EMResult(mixture, iteration, True)
    return EMResult(mixture, max_iter, False)


def merge_components(weights: np.ndarray, means: np.ndarray, covariances: np.ndarray):
    """Moment-matched single Gaussian (weight, mean, covariance) of weighted components."""
    total = weights.sum()
    mixture = GaussianMixture(weights, means, covariances)
    return total, mixture.mean(), mixture.covariance()


def reduce_mixture(mixture: GaussianMixture, n_components: int) -> GaussianMixture:
    """Keep the n_components - 1 heaviest components; merge the others into one (moment matching)."""
    if isinstance(n_components, (bool, np.bool_)) or not isinstance(n_components, (int, np.integer)) or n_components < 1:
        raise ValueError(f"n_components must be an integer >= 1, got {n_components!r}")
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


