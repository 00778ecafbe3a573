"""abyssal.symbolic.gp: scikit-learn GaussianProcessRegressor -> casadi.Function (mean, variance)."""
from __future__ import annotations

import warnings

import casadi as ca
import numpy as np
import pytest

sklearn_gp = pytest.importorskip("sklearn.gaussian_process")
from sklearn.gaussian_process import GaussianProcessRegressor  # noqa: E402
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, DotProduct, WhiteKernel  # noqa: E402

from abyssal.symbolic import gp  # noqa: E402


def _data(seed=0, n=40, d=3):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, (n, d))
    y = np.cos(X[:, 0]) + X[:, 1] * X[:, 2] + 0.05 * rng.normal(size=n) + 7.0
    test = np.vstack([rng.uniform(-4, 4, (20, d)), X[:3]])
    return X, y, test


def _fit(kernel, normalize, seed=0):
    X, y, test = _data(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return GaussianProcessRegressor(kernel, normalize_y=normalize, random_state=0).fit(X, y), test


KERNELS = {
    "C*RBF_ard+W": lambda: ConstantKernel(1.0) * RBF(np.ones(3)) + WhiteKernel(1e-2),
    "C*RBF_iso+W": lambda: ConstantKernel(1.0) * RBF(1.0) + WhiteKernel(1e-2),
    "W+RBF*C": lambda: WhiteKernel(1e-2) + RBF(1.0) * ConstantKernel(2.0),
    "RBF_ard": lambda: RBF(np.ones(3)),
}


@pytest.mark.parametrize("normalize", [True, False])
@pytest.mark.parametrize("kernel", sorted(KERNELS))
def test_mean_and_variance_equal_sklearn_predict(kernel, normalize):
    gpr, test = _fit(KERNELS[kernel](), normalize)
    fn = gp.from_sklearn(gpr)
    mean_ref, std_ref = gpr.predict(test, return_std=True)
    out = [fn(t) for t in test]
    mean = np.array([float(m) for m, _ in out])
    var = np.array([float(v) for _, v in out])
    assert np.max(np.abs(mean - mean_ref)) <= 1e-9 * np.max(np.abs(mean_ref))
    # relative to the prior variance (a noise-free GP's variance at its training points is ~0)
    prior = float(fn(np.full(3, 1e3))[1])
    assert np.max(np.abs(var - std_ref**2)) <= 1e-9 * prior
    if "W" in kernel:  # with a noise term the variance is never tiny: pointwise relative
        assert np.max(np.abs(var - std_ref**2) / std_ref**2) <= 1e-9


def test_variance_includes_the_learned_white_noise():
    gpr, _ = _fit(KERNELS["C*RBF_iso+W"](), True)
    noise = gpr.kernel_.k2.noise_level * gp.target_normalisation(gpr)[1][0] ** 2
    far = float(gp.from_sklearn(gpr)(np.full(3, 1e3))[1])  # far from the data: prior + noise
    signal = gpr.kernel_.k1.k1.constant_value * gp.target_normalisation(gpr)[1][0] ** 2
    assert far == pytest.approx(signal + noise, rel=1e-12)


def test_private_normalisation_attributes_still_mean_what_we_read():
    """Fails loudly if a scikit-learn release renames or redefines _y_train_mean/_y_train_std."""
    X, y, test = _data(1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gpr = GaussianProcessRegressor(ConstantKernel() * RBF() + WhiteKernel(), normalize_y=True).fit(X, y)
    assert hasattr(gpr, "_y_train_mean") and hasattr(gpr, "_y_train_std"), "scikit-learn changed its private attributes"
    y_mean, y_std = gp.target_normalisation(gpr)
    np.testing.assert_allclose(y_mean, y.mean(), rtol=1e-14)
    np.testing.assert_allclose(y_std, y.std(), rtol=1e-14)
    k = gpr.kernel_.k1(test, gpr.X_train_)
    np.testing.assert_allclose(k @ gpr.alpha_ * y_std + y_mean, gpr.predict(test), rtol=1e-12)
    unnormalised = GaussianProcessRegressor(RBF(), normalize_y=False).fit(X, y)
    assert gp.target_normalisation(unnormalised) == (np.zeros(1), np.ones(1)) or np.all(
        np.concatenate(gp.target_normalisation(unnormalised)) == np.array([0.0, 1.0]))


def test_unfitted_and_unsupported_kernels_are_refused():
    with pytest.raises(ValueError, match="not fitted"):
        gp.from_sklearn(GaussianProcessRegressor())
    gpr, _ = _fit(DotProduct() + WhiteKernel(), False)
    with pytest.raises(gp.UnsupportedKernelError):
        gp.from_sklearn(gpr)


def test_function_expands_to_sx_for_use_inside_a_model():
    gpr, test = _fit(KERNELS["C*RBF_ard+W"](), True)
    fn = gp.from_sklearn(gpr)
    x = ca.SX.sym("x", 3)
    mean, var = fn(x)
    sx = ca.Function("sx", [x], [mean, var])
    for t in test[:5]:
        assert float(sx(t)[0]) == pytest.approx(float(fn(t)[0]), rel=1e-10)  # sums reassociated
        assert float(sx(t)[1]) == pytest.approx(float(fn(t)[1]), rel=1e-9)


def _sklearn_pair():
    """Two GPs on different data with different hyperparameters, 40 regressors each."""
    first, test = _fit(KERNELS["C*RBF_ard+W"](), True)
    X, y, _ = _data(seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        second = GaussianProcessRegressor(ConstantKernel(2.0) * RBF(np.full(3, 0.5)) + WhiteKernel(1e-3),
                                          normalize_y=True, random_state=0).fit(X, -4.0 * y)
    return [first, second], test


@pytest.mark.parametrize("block", [100, 16])  # one block; 40 regressors in blocks of 16, padded to 48
def test_run_time_data_of_several_gps_equal_sklearn(block):
    gprs, test = _sklearn_pair()
    layout, data = gp.gp_data(gprs, block=block)
    assert layout.padded == (40 if block == 100 else 48) and layout.count == 2
    assert [a.shape for a in data] == 2 * list(layout.shapes().values())
    means = np.asarray(gp.mean_function(layout, len(test))(test.T, *data))
    variance = gp.variance_function(layout)
    for i, g in enumerate(gprs):
        m_ref, s_ref = g.predict(test, return_std=True)
        assert np.max(np.abs(means[i] - m_ref)) <= 1e-9 * np.max(np.abs(m_ref))
        var = np.array([float(np.asarray(variance(t, *data))[i, 0]) for t in test])
        assert np.max(np.abs(var - s_ref**2) / s_ref**2) <= 1e-9


def test_layout_stores_half_the_factor_and_refuses_mismatched_gps():
    layout = gp.GPLayout(15, 1600, 12)
    assert layout.block_rows == 100 and layout.n_blocks == 16 * 17 // 2
    factor_numbers = 12 * np.prod(layout.shapes()["factor_blocks"])
    assert factor_numbers < 0.55 * 12 * 1600**2      # the lower triangle (+ the diagonal blocks), not N^2
    gprs, _ = _sklearn_pair()
    X, y, _ = _data(seed=5, n=30)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        other = GaussianProcessRegressor(RBF(), random_state=0).fit(X, y)
    with pytest.raises(ValueError, match="X_train_ of shape"):
        gp.gp_data([gprs[0], other])
    with pytest.raises(ValueError, match="positive sizes"):
        gp.GPLayout(3, 0)


def test_generated_c_does_not_grow_with_the_regressors():
    """The data are inputs: the C of 12 GPs on 1600 regressors is about that of 100, and holds no zero array."""
    sizes = {}
    for n in (100, 1600):
        layout = gp.GPLayout(15, n, 12)
        x, points = ca.MX.sym("x", 15), ca.MX.sym("X", 15, 25)
        data = layout.symbols()
        fn = ca.Function(f"gp{n}", [points, x, *data], [gp.mean_function(layout, 25)(points, *data),
                                                        gp.variance_function(layout)(x, *data)])
        text = gp.c_source([fn])
        assert "static const casadi_real casadi_zeros" not in text and "static casadi_real casadi_zeros[" in text
        sizes[n] = len(text)
    assert sizes[1600] < 100_000 and sizes[1600] < 1.25 * sizes[100]   # the block maps grow with N/B, not N^2
