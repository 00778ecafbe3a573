"""Seed 004: the helix truth simulator (spec 5-10), the sensors, and the GP-UKF on the filter contract."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime.experiments.remus import gp_codegen, gp_model
from abyssal.runtime.experiments.remus import scenario

pytest.importorskip("sklearn")


@pytest.fixture(scope="module")
def remus():
    return abyssal.generated.load("remus100")


@pytest.fixture(scope="module")
def helix(remus):
    return scenario.simulate(1, bundle=remus)


def test_closed_loop_helix_matches_the_spec_reference_behaviour(helix):
    """Spec 10 (seed 1): u >= 1.3 m/s at 26 s; after 200 s RMS radial error 0.76 m, depth 0.11 m."""
    t, x = helix.t, helix.x
    assert x[np.searchsorted(t, 26.0), 0] >= 1.3
    late = t >= 200
    radial = np.hypot(x[late, 6], x[late, 7]) - 60.0
    assert 0.66 < np.sqrt(np.mean(radial**2)) < 0.86
    assert 0.08 < np.sqrt(np.mean((x[late, 8] - helix.reference[late, 2]) ** 2)) < 0.14
    assert 1150 < helix.u[:, 0].min() and helix.u[:, 0].max() < 2450
    assert np.degrees(np.abs(x[:, 10]).max()) < 4.0
    assert len(t) == 4001 and t[1] - t[0] == pytest.approx(0.2)


def test_sensors_quantise_clip_wrap_and_hold(helix):
    z = helix.z
    for ch in (0, 1, 2, 6, 7, 8, 9):
        lsb = scenario.SENSOR_LSB[ch]
        np.testing.assert_allclose(z[:, ch] / lsb, np.round(z[:, ch] / lsb), atol=1e-6)
    assert np.all(np.abs(z[:, 7:10]) <= np.pi)
    noise = scenario.sensor_noise(1, scenario.HelixSetup())
    x = helix.x[100]
    z, lsb = scenario.measure(x, noise[3]), scenario.SENSOR_LSB
    # the gyro rates p, q, r (no clip, no wrap): the noisy value rounded to its 12-bit step
    assert np.all(np.abs(z[3:6] - (x[3:6] + noise[3][3:6])) <= np.where(lsb[3:6] > 0, lsb[3:6] / 2, 0) + 1e-15)
    assert not np.array_equal(z, scenario.measure(x, noise[4]))  # another noise sample, another reading
    assert scenario.measure(np.r_[5.0, np.zeros(11)], np.zeros(10))[0] == 3.0         # u clipped to 3 m/s
    # run index = seed: another run has other noise, the same helix
    other = scenario.simulate(2, scenario.HelixSetup(duration=20.0))
    np.testing.assert_allclose(other.x[:5], helix.x[:5], rtol=0, atol=1e-12)
    assert not np.array_equal(other.z[:20], helix.z[:20])


@pytest.fixture(scope="module")
def small_gp(tmp_path_factory):
    short = scenario.simulate(1, scenario.HelixSetup(duration=60.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = gp_model.fit(short, n_train=25)
    compiled = gp_codegen.build_predict(model, tmp_path_factory.mktemp("gp"), name="remus_gpukf_test")
    return short, model, compiled


def _ut_reference(model, x, P, u):
    """NumPy scaled unscented transform (alpha 1, beta 2, kappa 0) through scikit-learn's predictions."""
    n = 12
    L = np.linalg.cholesky(P)
    points = [x] + [x + np.sqrt(n) * L[:, i] for i in range(n)] + [x - np.sqrt(n) * L[:, i] for i in range(n)]
    wm = np.r_[0.0, np.full(2 * n, 1 / (2 * n))]
    wc = np.r_[2.0, np.full(2 * n, 1 / (2 * n))]

    def features(states):
        rows = gp_model.feature_rows(np.atleast_2d(states), np.tile(u, (len(np.atleast_2d(states)), 1)), model.features)
        return (rows - model.feature_mean) / model.feature_std

    F = features(np.array(points))
    Y = np.array(points) + np.column_stack([g.predict(F) for g in model.gprs])
    mean = wm @ Y
    D = Y - mean
    variances = np.array([g.predict(features(x), return_std=True)[1][0] ** 2 for g in model.gprs])
    return mean, (D.T * wc) @ D + np.diag(variances), np.diag(variances)


def test_generated_gp_ukf_predict_equals_a_numpy_unscented_transform(remus, small_gp):
    from abyssal.runtime.filters.kalman.gp_ukf import GPUKF

    short, model, compiled = small_gp
    x0 = short.x[100]
    P0 = np.diag([1e-4] * 6 + [1.0, 1.0, 1e-2, 1e-4, 1e-4, 1e-3])
    f = GPUKF(remus, compiled.library, compiled.name, x0, P0, scenario.SENSOR_R, gp_dt=0.2)
    f.predict(short.u[100], 0.2)
    mean, cov, Q = _ut_reference(model, x0, P0, short.u[100])
    np.testing.assert_allclose(f.x, mean, rtol=0, atol=1e-9 * np.max(np.abs(mean)))
    np.testing.assert_allclose(f.P, cov, rtol=0, atol=1e-9 * np.max(np.abs(cov)))
    # GP variances: to 1e-9 of each GP's prior variance (a noise-free GP's variance near its data is ~0,
    # and the generated kernel expands |x - x_i|^2, which rounds differently from scikit-learn)
    from abyssal.symbolic import gp

    prior = []
    for g in model.gprs:
        signal, _, noise = gp.kernel_hyperparameters(g.kernel_)
        prior.append((signal + noise) * gp.target_normalisation(g)[1][0] ** 2)
    assert np.all(np.abs(np.diag(f.last_Q) - np.diag(Q)) <= 1e-9 * np.array(prior))


def test_gp_ukf_follows_the_filter_contract(remus, small_gp):
    from abyssal.runtime.filters.kalman.gp_ukf import GPUKF

    short, _, compiled = small_gp
    P0 = np.diag([1e-4] * 6 + [1.0, 1.0, 1e-2, 1e-4, 1e-4, 1e-3])
    # gate off: this 12-point GP predicts poorly enough that the innovation gate (tests/runtime/test_gate.py)
    # leaves out some entries, and this test counts the entries NaN leaves out
    f = GPUKF(remus, compiled.library, compiled.name, short.x[0], P0, scenario.SENSOR_R, gp_dt=0.2, gate_probability=0.0)
    assert f.step(short.u[0], 0.2, short.z[1]) is True
    x, P = f.x, f.P
    with pytest.raises(ValueError, match="training step"):
        f.step(short.u[1], 0.1, short.z[2])
    with pytest.raises(ValueError, match="infinite"):
        f.step(short.u[1], 0.2, np.r_[np.inf, short.z[2][1:]])
    with pytest.raises(ValueError):
        f.predict(np.r_[np.nan, 0.0, 0.0], 0.2)
    assert np.array_equal(f.x, x) and np.array_equal(f.P, P)
    assert f.step(short.u[1], 0.2, None) is False           # predict only
    z = short.z[3].copy()
    z[[0, 9]] = np.nan                                      # entries left out one by one
    assert f.update(z) is True and f.nis_dof == 8
    assert f.update(np.full(10, np.nan)) is False
    result = f.run(short.u[3:13], short.z[4:14], 0.2, truth=short.x[4:14])
    assert result.x.shape == (10, 12) and np.all(np.isfinite(result.nis))


def test_run_one_gives_tidy_rows_for_both_filters(remus, small_gp, monkeypatch):
    from abyssal.runtime.experiments.campaign import run_seeds
    from abyssal.runtime.experiments.remus import experiment

    short, _, compiled = small_gp
    monkeypatch.setattr(experiment, "PREDICTION_STARTS", (20, 30))
    config = experiment.RemusConfig(duration=60.0, Q_ukf=tuple(map(tuple, np.eye(12) * 1e-6)),
                                    predict_library=str(compiled.library), predict_name=compiled.name, gp_dt=0.2)
    with pytest.raises(ValueError, match="not prepared"):
        experiment.run_one(experiment.RemusConfig(duration=60.0), run_seeds(0, 1)[0])
    rows = experiment.run_one(config, run_seeds(0, 2)[1])
    assert {r["filter"] for r in rows} == {"UKF", "GP-UKF"}
    assert {r["run"] for r in rows} == {1}
    metrics = {r["metric"] for r in rows}
    assert {"rmse_x", "rmse_psi", "correction", "prediction", "step_ms"} <= metrics
    assert all(np.isfinite(r["value"]) for r in rows)
