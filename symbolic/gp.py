"""Gaussian processes as CasADi Functions: a fitted scikit-learn regressor becomes generated C.

    fn = from_sklearn(gpr)            # casadi.Function  x (d,) -> (mean, variance)
    mean, var = fn(x)                 # == gpr.predict([x], return_std=True) with var = std**2
    gp_mean_batch_function(gpr, m)    # X (d, m) -> means (1, m): m points in one matrix product

Supported kernels (the fitted ``gpr.kernel_``): ``RBF``, ``ConstantKernel * RBF``, either of them
``+ WhiteKernel``; RBF isotropic or ARD; ``normalize_y`` True or False. With k the noise-free
part (c exp(-|(x - x_i)/l|^2 / 2)) and s_n^2 the WhiteKernel noise level, scikit-learn predicts

    mean     = y_std * k_*^T alpha + y_mean
    variance = y_std^2 * max(0, c + s_n^2 - |L^-1 k_*|^2)

(the WhiteKernel adds to k(x, x) but not to k_*: the variance *includes* the learned noise),
where alpha = ``alpha_``, L = ``L_`` (Cholesky factor of K + s_n^2 I), and y_mean, y_std are
the normalisation of the training targets (0 and 1 without ``normalize_y``).

Design: the Function is built in MX with the training data as DM constants, so the generated C
keeps them as constant arrays and evaluates with loops: its size grows with N*d + N^2/2 numbers
(the inverse Cholesky factor, triangular), not with an unrolled expression per training point.
The squared distances are expanded, |x - x_i|^2/l^2 = |x_i/l|^2 - 2 x_i/l^2 . x + |x/l|^2, so
the kernel vector of one or many points is one matrix product with a constant that the mean and
the variance share (it rounds differently from scikit-learn's direct differences: checked).
Calling it with SX arguments still works (CasADi expands it), which is how a GP enters an SX
model; the expansion is then O(N^2) instructions, fine for small N only.

Only ``_y_train_mean`` and ``_y_train_std`` are private in scikit-learn (1.9): they are read in
exactly one place, :func:`target_normalisation`, which fails loudly if a release renames them
(tests/symbolic/test_gp.py checks it against predict()).
"""
from __future__ import annotations

import casadi as ca
import numpy as np


class UnsupportedKernelError(ValueError):
    """The fitted kernel is not (Constant *) RBF (+ White)."""


def target_normalisation(gpr) -> tuple[np.ndarray, np.ndarray]:
    """(y_mean, y_std) scikit-learn applied to the training targets; zeros and ones without normalize_y.

    The one place that reads scikit-learn's private attributes ``_y_train_mean``/``_y_train_std``.
    """
    try:
        mean, std = gpr._y_train_mean, gpr._y_train_std
    except AttributeError as exc:  # pragma: no cover - only on a scikit-learn release that changed them
        raise RuntimeError(
            "scikit-learn's GaussianProcessRegressor no longer has _y_train_mean/_y_train_std; "
            "abyssal.symbolic.gp.target_normalisation must be updated for this release"
        ) from exc
    mean, std = np.atleast_1d(np.asarray(mean, dtype=float)), np.atleast_1d(np.asarray(std, dtype=float))
    if not gpr.normalize_y and (np.any(mean != 0) or np.any(std != 1)):
        raise RuntimeError("normalize_y=False but scikit-learn stored a normalisation: update target_normalisation")
    return mean, std


def kernel_hyperparameters(kernel) -> tuple[float, np.ndarray, float]:
    """(signal variance c, length scales (1,) or (d,), noise level s_n^2) of a fitted kernel."""
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, Product, Sum, WhiteKernel

    noise = 0.0
    if isinstance(kernel, Sum):
        if isinstance(kernel.k2, WhiteKernel):
            kernel, noise = kernel.k1, float(kernel.k2.noise_level)
        elif isinstance(kernel.k1, WhiteKernel):
            kernel, noise = kernel.k2, float(kernel.k1.noise_level)
        else:
            raise UnsupportedKernelError(f"a sum kernel must be ... + WhiteKernel, got {kernel}")
    signal = 1.0
    if isinstance(kernel, Product):
        parts = (kernel.k1, kernel.k2)
        constants = [k for k in parts if isinstance(k, ConstantKernel)]
        rbfs = [k for k in parts if isinstance(k, RBF)]
        if len(constants) != 1 or len(rbfs) != 1:
            raise UnsupportedKernelError(f"a product kernel must be ConstantKernel * RBF, got {kernel}")
        signal, kernel = float(constants[0].constant_value), rbfs[0]
    if not isinstance(kernel, RBF):
        raise UnsupportedKernelError(f"expected (ConstantKernel *) RBF (+ WhiteKernel), got {kernel}")
    return signal, np.atleast_1d(np.asarray(kernel.length_scale, dtype=float)), noise


def _fitted(gpr):
    for attribute in ("X_train_", "alpha_", "L_", "kernel_"):
        if not hasattr(gpr, attribute):
            raise ValueError(f"the GaussianProcessRegressor is not fitted (no {attribute}); call fit() first")
    alpha = np.asarray(gpr.alpha_, dtype=float)
    if alpha.ndim == 2 and alpha.shape[1] != 1:
        raise ValueError("one output per GP: fit one GaussianProcessRegressor per predicted quantity")
    return np.asarray(gpr.X_train_, dtype=float), alpha.reshape(-1), np.asarray(gpr.L_, dtype=float)


def _training_matrix(X: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """([-2 X / l^2, |X_i / l|^2] (N, d+1), 1 / l^2 (d,)): the constants of the kernel products.

    |x - x_i|^2 / l^2 = |X_i / l|^2 - 2 X_i / l^2 . x + |x / l|^2, so the kernel vector of a point (or
    of m points) is one product with this matrix; the mean and the variance share it in the C.
    """
    d = X.shape[1]
    inv_sq_scale = 1.0 / np.broadcast_to(length, (d,)) ** 2
    return np.hstack([-2 * X * inv_sq_scale, np.sum(X**2 * inv_sq_scale, axis=1, keepdims=True)]), inv_sq_scale


def _kernel_matrix(points: ca.MX, X: np.ndarray, signal: float, length: np.ndarray) -> ca.MX:
    """k(X_i, x_j) (N, m) for the columns x_j of points (d, m), noise-free part of the kernel."""
    n, m = X.shape[0], points.size2()
    training, inv_sq_scale = _training_matrix(X, length)
    cross = ca.mtimes(ca.DM(training), ca.vertcat(points, ca.MX.ones(1, m)))                # (N, m)
    # + |x_j/l|^2: a horizontal repmat, transposed (a vertical MX repmat would be N separate copies)
    own = ca.mtimes(ca.DM(inv_sq_scale).T, points * points)                                # (1, m)
    theirs = own if n == 1 else ca.repmat(own.T, 1, n).T                                    # (N, m)
    return signal * ca.exp(-0.5 * ca.fmax(cross + theirs, 0))


def gp_mean_function(gpr, name: str = "gp_mean") -> ca.Function:
    """x (d,) -> predictive mean (scalar)."""
    X, alpha, _ = _fitted(gpr)
    signal, length, _ = kernel_hyperparameters(gpr.kernel_)
    y_mean, y_std = target_normalisation(gpr)
    x = ca.MX.sym("x", X.shape[1])
    k = _kernel_matrix(x, X, signal, length)
    mean = y_std[0] * ca.dot(k, ca.DM(alpha)) + y_mean[0]
    return ca.Function(name, [x], [mean], ["x"], ["mean"])


def gp_mean_batch_function(gpr, n_points: int, name: str = "gp_mean_batch") -> ca.Function:
    """X (d, m) -> predictive means (1, m) of m points at once (what a sigma-point filter needs):
    one (N, d+1) x (d+1, m) product instead of m passes over the training data."""
    X, alpha, _ = _fitted(gpr)
    signal, length, _ = kernel_hyperparameters(gpr.kernel_)
    y_mean, y_std = target_normalisation(gpr)
    points = ca.MX.sym("X", X.shape[1], n_points)
    K = _kernel_matrix(points, X, signal, length)
    means = y_std[0] * ca.mtimes(ca.DM(alpha).T, K) + y_mean[0]
    return ca.Function(name, [points], [means], ["X"], ["mean"])


def inverse_cholesky(L: np.ndarray) -> np.ndarray:
    """L^-1 of the lower-triangular Cholesky factor (a triangular solve against I)."""
    from scipy.linalg import solve_triangular

    return solve_triangular(L, np.eye(L.shape[0]), lower=True)


def gp_variance_function(gpr, name: str = "gp_variance") -> ca.Function:
    """x (d,) -> predictive variance including the WhiteKernel noise (scalar)."""
    X, _, L = _fitted(gpr)
    signal, length, noise = kernel_hyperparameters(gpr.kernel_)
    _, y_std = target_normalisation(gpr)
    x = ca.MX.sym("x", X.shape[1])
    k = _kernel_matrix(x, X, signal, length)
    Linv = inverse_cholesky(L)
    Linv[np.triu_indices_from(Linv, 1)] = 0.0
    v = ca.mtimes(ca.sparsify(ca.DM(Linv)), k)  # triangular constant: only its N(N+1)/2 entries are stored
    variance = y_std[0] ** 2 * ca.fmax(signal + noise - ca.dot(v, v), 0)
    return ca.Function(name, [x], [variance], ["x"], ["variance"])


def from_sklearn(gpr, name: str = "gp") -> ca.Function:
    """casadi.Function ``name(x) -> (mean, variance)`` of a fitted GaussianProcessRegressor.

    variance equals ``gpr.predict(x, return_std=True)[1] ** 2`` (the learned WhiteKernel noise
    included); checked to <= 1e-9 relative by `abyssal verify`.
    """
    mean_fn = gp_mean_function(gpr, f"{name}_mean")
    var_fn = gp_variance_function(gpr, f"{name}_variance")
    x = ca.MX.sym("x", mean_fn.size1_in(0))
    return ca.Function(name, [x], [mean_fn(x), var_fn(x)], ["x"], ["mean", "variance"])
