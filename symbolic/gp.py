"""Gaussian processes as CasADi Functions whose training data are run-time inputs.

    layout, data = gp_data([gpr_1, ..., gpr_k])    # k fitted scikit-learn GPs on the same N regressors
    mean = mean_function(layout, m)                 # (points (d, m), *data) -> means (k, m)
    var = variance_function(layout)                 # (x (d,), *data) -> variances (k,)
    fn = from_sklearn(gpr)                          # x (d,) -> (mean, variance), the data as constants

Supported kernels (the fitted ``gpr.kernel_``): ``RBF``, ``ConstantKernel * RBF``, either of them
``+ WhiteKernel``; RBF isotropic or ARD; ``normalize_y`` True or False. With c exp(-|(x - x_i)/l|^2 / 2)
the noise-free part of the kernel and s_n^2 the WhiteKernel noise level, scikit-learn predicts

    mean     = y_std * c e_*^T alpha + y_mean                     e_*i = exp(-|(x - x_i)/l|^2 / 2)
    variance = y_std^2 * max(0, c + s_n^2 - |L^-1 c e_*|^2)

(the WhiteKernel adds to k(x, x) but not to k_*: the variance *includes* the learned noise),
where alpha = ``alpha_``, L = ``L_`` (Cholesky factor of K + s_n^2 I), and y_mean, y_std are the
normalisation of the training targets (0 and 1 without ``normalize_y``).

Design. The generated C is a few loops whose size does not depend on the data: a new training
set of the same shape (another draw, other hyperparameters) is a new set of input arrays, not a
recompilation. Each GP has five inputs (DATA_NAMES; k GPs: 5 k inputs, GP by GP):

    training               (N, d+3)        [X/l^2, -|X_i/l|^2/2, 1, 0]: the exponent -|x - x_i|^2/(2 l^2) is
                                           X_i/l^2 . x - |X_i/l|^2/2 - |x/l|^2/2, so the exponents of one or m
                                           points are one matrix product
    inverse_square_scales  (d, 1)          -1/(2 l^2) (the -|x/l|^2/2 term)
    weights                (N, 1)          y_std c alpha
    factor_blocks          (B, (B+1) nb)   y_std c L^-1, its lower triangle cut in nb = b (b+1)/2 dense B x B
                                           blocks (each with a zero column after it)
    scalars                (2, 1)          [y_std^2 (c + s_n^2), y_mean]

so the variance reads N^2/2 numbers per GP (plus N B/2 for the diagonal blocks), not N^2. N is padded to
a multiple of the block size B with regressors of zero weight and zero factor columns, which add exactly
nothing. One GP's mean and variance are MX Functions over its inputs (the factor blocks a ``map``), called
once per GP. The zero columns make the right-hand factor of each product structurally sparse (a structural
zero row), so CasADi emits its column-saxpy kernel (``casadi_mtimes_dense_sparse``: contiguous,
vectorisable) instead of its dense kernel, whose inner loop strides through the data matrix. CasADi keeps
an explicit row index per entry of every pattern, so the inputs of one kind share one Sparsity object and
no input stacks the GPs side by side (a 16-million-entry pattern costs seconds per operation on it).
The expanded distance rounds differently from scikit-learn's direct differences: `abyssal verify`
checks both against ``predict``.

Only ``_y_train_mean`` and ``_y_train_std`` are private in scikit-learn (1.9): they are read in
exactly one place, :func:`target_normalisation`, which fails loudly if a release renames them
(tests/symbolic/test_gp.py checks it against predict()).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

#: the run-time data of a GP, in the order the Functions below take them
DATA_NAMES = ("training", "inverse_square_scales", "weights", "factor_blocks", "scalars")
#: rows per block of the triangular factor (N <= BLOCK: one block of N rows)
BLOCK = 100


class UnsupportedKernelError(ValueError):
    """The fitted kernel is not (Constant *) RBF (+ White)."""


@dataclass(frozen=True)
class GPLayout:
    """The shapes of the run-time data of ``count`` GPs on ``n_regressors`` points of ``n_inputs`` features."""

    n_inputs: int        # d
    n_regressors: int    # N
    count: int = 1       # k GPs sharing the regressors' count and d (their data side by side)
    block: int = BLOCK   # B: the factor's block size (min(N, BLOCK) unless given)

    def __post_init__(self):
        if min(self.n_inputs, self.n_regressors, self.count, self.block) < 1:
            raise ValueError(f"a GP layout needs positive sizes, got {self}")

    @property
    def block_rows(self) -> int:
        return min(self.block, self.n_regressors)

    @property
    def blocks_per_side(self) -> int:
        return -(-self.n_regressors // self.block_rows)

    @property
    def padded(self) -> int:
        """N rounded up to a multiple of the block size."""
        return self.blocks_per_side * self.block_rows

    @property
    def n_blocks(self) -> int:
        b = self.blocks_per_side
        return b * (b + 1) // 2

    def blocks(self) -> list[tuple[int, int]]:
        """(block row I, block column J), I >= J, in the order of ``factor_blocks``."""
        return [(i, j) for i in range(self.blocks_per_side) for j in range(i + 1)]

    def shapes(self) -> dict[str, tuple[int, int]]:
        """DATA_NAMES -> (rows, columns) of one GP's data."""
        d, n, B = self.n_inputs, self.padded, self.block_rows
        return {"training": (n, d + 3), "inverse_square_scales": (d, 1), "weights": (n, 1),
                "factor_blocks": (B, (B + 1) * self.n_blocks), "scalars": (2, 1)}

    def input_names(self) -> list[str]:
        """The names of the data inputs of all ``count`` GPs, GP by GP (``training_0, ..., scalars_<k-1>``)."""
        return [f"{name}_{i}" for i in range(self.count) for name in DATA_NAMES]

    def symbols(self) -> list[ca.MX]:
        """MX symbols of the data of all ``count`` GPs, GP by GP; one Sparsity object per kind of input."""
        patterns = {name: ca.Sparsity.dense(*shape) for name, shape in self.shapes().items()}
        return [ca.MX.sym(f"{name}_{i}", patterns[name]) for i in range(self.count) for name in DATA_NAMES]

    def nbytes(self) -> int:
        return 8 * self.count * sum(r * c for r, c in self.shapes().values())


# ---------------------------------------------------------------------------------------------
# scikit-learn -> data


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


def inverse_cholesky(L: np.ndarray) -> np.ndarray:
    """L^-1 of the lower-triangular Cholesky factor (a triangular solve against I), upper triangle exactly 0."""
    from scipy.linalg import solve_triangular

    inverse = solve_triangular(L, np.eye(L.shape[0]), lower=True)
    return np.tril(inverse)


def _one_gp_data(gpr, layout: GPLayout) -> dict[str, np.ndarray]:
    X, alpha, L = _fitted(gpr)
    n, d = X.shape
    if (n, d) != (layout.n_regressors, layout.n_inputs):
        raise ValueError(f"every GP of one layout needs X_train_ of shape ({layout.n_regressors}, {layout.n_inputs}), "
                         f"got {X.shape}")
    signal, length, noise = kernel_hyperparameters(gpr.kernel_)
    y_mean, y_std = target_normalisation(gpr)
    if y_mean.size != 1:
        raise ValueError("one output per GP: fit one GaussianProcessRegressor per predicted quantity")
    inv_sq_scale = 1.0 / np.broadcast_to(length, (d,)) ** 2
    N, B = layout.padded, layout.block_rows
    training = np.zeros((N, d + 3))
    training[:n, :d] = X * inv_sq_scale
    training[:n, d] = -0.5 * np.sum(X**2 * inv_sq_scale, axis=1)
    training[:, d + 1] = 1.0
    weights = np.zeros(N)
    weights[:n] = y_std[0] * signal * alpha
    factor = np.zeros((N, N))
    factor[:n, :n] = y_std[0] * signal * inverse_cholesky(L)
    blocks = np.hstack([np.hstack([factor[i * B:(i + 1) * B, j * B:(j + 1) * B], np.zeros((B, 1))])
                        for i, j in layout.blocks()])
    scalars = np.array([y_std[0] ** 2 * (signal + noise), y_mean[0]])
    return {"training": training, "inverse_square_scales": -0.5 * inv_sq_scale.reshape(d, 1), "weights": weights.reshape(N, 1),
            "factor_blocks": blocks, "scalars": scalars.reshape(2, 1)}


def gp_data(gprs, block: int = BLOCK) -> tuple[GPLayout, tuple[np.ndarray, ...]]:
    """(layout, data: DATA_NAMES per GP, GP by GP) of fitted GaussianProcessRegressors on the same number of
    regressors and inputs (each its own data and hyperparameters): the run-time inputs of mean_function and
    variance_function. Arrays are float64 in Fortran order (CasADi's column-major), ready to be bound as buffers."""
    gprs = list(gprs) if isinstance(gprs, (list, tuple)) else [gprs]
    if not gprs:
        raise ValueError("gp_data needs at least one fitted GaussianProcessRegressor")
    X, _, _ = _fitted(gprs[0])
    layout = GPLayout(X.shape[1], X.shape[0], len(gprs), block)
    data = []
    for g in gprs:
        part = _one_gp_data(g, layout)
        data += [np.asfortranarray(part[name]) for name in DATA_NAMES]
    return layout, tuple(data)


# ---------------------------------------------------------------------------------------------
# data -> CasADi Functions (MX: loops in the C, not one expression per regressor)


def _exponents(points: ca.MX, training: ca.MX, inv_sq_scale: ca.MX) -> ca.MX:
    """exp(-|(x_j - x_i)/l|^2 / 2) (N, m) for the columns x_j of points (d, m): one product with the data.

    The expanded exponent may round to a tiny positive number next to a training point (exp gives
    1 + ~1e-13 instead of 1: the expansion's own rounding); it is not clamped."""
    m = points.size2()
    augmented = ca.vertcat(points, ca.MX.ones(1, m), ca.mtimes(inv_sq_scale.T, points * points), ca.MX(1, m))
    return ca.exp(ca.mtimes(training, augmented))                       # augmented (d + 3, m): last row 0


def _one_mean(layout: GPLayout, n_points: int, name: str) -> ca.Function:
    points = ca.MX.sym("X", layout.n_inputs, n_points)
    training, inv_sq_scale, weights, _, scalars = replace(layout, count=1).symbols()
    means = ca.mtimes(weights.T, _exponents(points, training, inv_sq_scale)) + scalars[1]
    return ca.Function(name, [points, training, inv_sq_scale, weights, scalars], [means],
                       ["X", "training", "inverse_square_scales", "weights", "scalars"], ["mean"])


def _one_variance(layout: GPLayout, name: str) -> ca.Function:
    x = ca.MX.sym("x", layout.n_inputs, 1)
    training, inv_sq_scale, _, factor_blocks, scalars = replace(layout, count=1).symbols()
    B, b, pairs = layout.block_rows, layout.blocks_per_side, layout.blocks()
    k = ca.reshape(_exponents(x, training, inv_sq_scale), B, b)        # column J: block J of the kernel vector
    # v = (y_std c L^-1) e, block row I = sum over J <= I of F_IJ e_J: gather e_J per block, one mapped B x B
    # product per block, sum per block row (0/1 matrices with one entry per block)
    gather = ca.DM(ca.Sparsity.triplet(b, len(pairs), [j for _, j in pairs], list(range(len(pairs)))), 1.0)
    scatter = ca.DM(ca.Sparsity.triplet(len(pairs), b, list(range(len(pairs))), [i for i, _ in pairs]), 1.0)
    A, e = ca.MX.sym("A", B, B + 1), ca.MX.sym("e", B, 1)
    block_product = ca.Function(f"{name}_block", [A, e], [ca.mtimes(A, ca.vertcat(e, ca.MX(1, 1)))])
    products = block_product.map(len(pairs), "serial")(factor_blocks, ca.mtimes(k, gather))   # (B, blocks)
    v = ca.mtimes(products, scatter)                                                           # (B, b)
    variance = ca.fmax(scalars[0] - ca.sumsqr(v), 0)
    return ca.Function(name, [x, training, inv_sq_scale, factor_blocks, scalars], [variance],
                       ["x", "training", "inverse_square_scales", "factor_blocks", "scalars"], ["variance"])


def mean_function(layout: GPLayout, n_points: int, name: str = "gp_mean") -> ca.Function:
    """(X (d, m), *data (5 k inputs, GP by GP)) -> means (k, m) of the layout's k GPs at m points (the sigma
    points of a filter): per GP one (N, d+3) x (d+3, m) product."""
    one = _one_mean(layout, n_points, f"{name}_one")
    points = ca.MX.sym("X", layout.n_inputs, n_points)
    data = layout.symbols()
    means = [one(points, *(data[5 * i + j] for j in (0, 1, 2, 4))) for i in range(layout.count)]
    return ca.Function(name, [points, *data], [ca.vertcat(*means)], ["X", *layout.input_names()], ["mean"])


def variance_function(layout: GPLayout, name: str = "gp_variance") -> ca.Function:
    """(x (d,), *data (5 k inputs, GP by GP)) -> variances (k,) of the layout's k GPs at one point, the learned
    WhiteKernel noise included."""
    one = _one_variance(layout, f"{name}_one")
    x = ca.MX.sym("x", layout.n_inputs, 1)
    data = layout.symbols()
    variances = [one(x, *(data[5 * i + j] for j in (0, 1, 3, 4))) for i in range(layout.count)]
    return ca.Function(name, [x, *data], [ca.vertcat(*variances)], ["x", *layout.input_names()], ["variance"])


def from_sklearn(gpr, name: str = "gp") -> ca.Function:
    """casadi.Function ``name(x) -> (mean, variance)`` of one fitted GaussianProcessRegressor, its data as
    constants (a small GP inside a model; a filter passes the data at run time: mean_function).

    variance equals ``gpr.predict(x, return_std=True)[1] ** 2`` (the learned WhiteKernel noise
    included); checked to <= 1e-9 relative by `abyssal verify`.
    """
    layout, data = gp_data([gpr])
    x = ca.MX.sym("x", layout.n_inputs)
    constants = [ca.DM(a) for a in data]
    mean = mean_function(layout, 1, f"{name}_mean")(x, *constants)
    variance = variance_function(layout, f"{name}_variance")(x, *constants)
    return ca.Function(name, [x], [mean, variance], ["x"], ["mean", "variance"])


#: CasADi writes, as initialised constant data, a zero array as long as the largest input: what a function
#: reads in place of an input passed as NULL. With the data of 12 GPs of 1600 regressors as inputs that is
#: 130 MB of zeros in the library. The same array uninitialised (static, so zero) lives in .bss: no bytes
#: on disk, no memory until a NULL input is read.
_ZEROS = re.compile(r"static const casadi_real casadi_zeros\[(\d+)\] = \s*\{0\.\};")


def c_source(functions, banner: str = "") -> str:
    """C text of Functions taking GP data as inputs: CasADi's code (the options of abyssal.symbolic.codegen),
    with its NULL-input zero array uninitialised (see _ZEROS)."""
    from .codegen import CODEGEN_OPTIONS

    cg = ca.CodeGenerator("gp.c", CODEGEN_OPTIONS)
    for fn in functions:
        cg.add(fn)
    text, count = _ZEROS.subn(r"static casadi_real casadi_zeros[\1]; /* zero (static): abyssal.symbolic.gp._ZEROS */",
                              cg.dump())
    if count > 1 or (count == 0 and "static const casadi_real casadi_zeros" in text):
        raise RuntimeError("CasADi's casadi_zeros array is not written as _ZEROS expects: update abyssal.symbolic.gp._ZEROS")
    return banner + text
