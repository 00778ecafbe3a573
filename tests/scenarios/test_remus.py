"""Seed 004: the helix truth simulator (spec 5-10), the sensors, the GP training sets and the GP-UKF, the campaign rows."""
from __future__ import annotations

import math
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


def test_draws_are_nested_start_heavy_and_named_by_their_seed(helix):
    _, _, times = gp_model.narx_data(helix)
    pool, order = gp_model.draw_order(times, 4)
    assert len(pool) == gp_model.pool_size(800.0) == 1600 and sorted(order) == list(pool)
    again, other = gp_model.draw_order(times, 4), gp_model.draw_order(times, 5)
    assert np.array_equal(again[1], order) and not np.array_equal(other[0], pool)
    early, late = np.sum(times[pool] < 200), np.sum(times[pool] >= 600)
    assert early > 1.6 * late                                 # density 1 at the start, 1/4 at the end
    increments, state = gp_model.narx_data(helix, targets="increments")[1], gp_model.narx_data(helix, targets="state")[1]
    eta = gp_model.narx_state(helix)
    np.testing.assert_allclose(state[:, :11], eta[1:, :11], rtol=0, atol=0)        # next states
    np.testing.assert_allclose(increments[:, :9], eta[1:, :9] - eta[:-1, :9], rtol=0, atol=0)
    np.testing.assert_array_equal(state[:, 11], increments[:, 11])                 # psi: its increment in both
    assert np.all(np.abs(state[:, 11]) < 1.0)                                       # no 2 pi jumps


@pytest.fixture(scope="module")
def short():
    return scenario.simulate(1, scenario.HelixSetup(duration=60.0))


@pytest.fixture(scope="module")
def training_sets(short, tmp_path_factory):
    """Two draws, sizes 20 (hyperparameters optimised) and 60 (conditioned with them), increment targets; and
    next-state targets of one draw. Saved as the campaign saves them."""
    folder = tmp_path_factory.mktemp("gp")
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for draw in (4, 5):
            for n, s in gp_model.fit_draw(short, draw, (20, 60), hyper_max=20).items():
                out[("increments", n, draw)] = (s, s.save(folder / f"increments_{draw}_{n}.npz"))
        for n, s in gp_model.fit_draw(short, 4, (20,), targets="state", hyper_max=20).items():
            out[("state", n, 4)] = (s, s.save(folder / f"state_4_{n}.npz"))
    return out


def test_larger_sets_reuse_the_hyperparameters_and_saved_sets_load_back(training_sets):
    small, _ = training_sets[("increments", 20, 4)]
    large, path = training_sets[("increments", 60, 4)]
    assert small.n_train == 20 and large.n_train == 60 and large.train_seconds == 0.0 < small.train_seconds
    np.testing.assert_array_equal(large.theta, small.theta)
    assert set(map(tuple, small.X)) <= set(map(tuple, large.X))              # nested regressors
    loaded = gp_model.TrainingSet.load(path)
    for field in ("X", "Y", "theta", "feature_mean", "feature_std", "times", "pool_times"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(large, field))
    assert (loaded.dt, loaded.targets, loaded.features, loaded.draw) == (0.2, "increments", "paper", 4)
    # conditioning with fixed hyperparameters reproduces the optimised GP of the smaller set exactly
    gprs = gp_model.regressors(small)
    for g, theta in zip(gprs, small.theta):
        np.testing.assert_array_equal(g.kernel_.theta, theta)


@pytest.fixture(scope="module")
def compiled(training_sets, tmp_path_factory):
    out = tmp_path_factory.mktemp("gpc")
    return {(t, n): gp_codegen.build_predict(n, out, targets=t, name=f"remus_gpukf_test_{t}_{n}")
            for t, n in (("increments", 20), ("increments", 60), ("state", 20))}


def _ut_reference(training, x, P, u):
    """NumPy scaled unscented transform (alpha 1, beta 2, kappa 0) through scikit-learn's predictions."""
    gprs = gp_model.regressors(training)
    n = 12
    L = np.linalg.cholesky(P)
    points = np.array([x] + [x + np.sqrt(n) * L[:, i] for i in range(n)] + [x - np.sqrt(n) * L[:, i] for i in range(n)])
    wm = np.r_[0.0, np.full(2 * n, 1 / (2 * n))]
    wc = np.r_[2.0, np.full(2 * n, 1 / (2 * n))]

    def features(states):
        states = np.atleast_2d(states)
        rows = gp_model.feature_rows(states, np.tile(u, (len(states), 1)), training.features)
        return (rows - training.feature_mean) / training.feature_std

    G = np.column_stack([g.predict(features(points)) for g in gprs])
    kept = np.isin(np.arange(n), gp_model.increments_of(training.targets))
    Y = np.where(kept, points, 0.0) + G
    mean = wm @ Y
    D = Y - mean
    variances = np.array([g.predict(features(x), return_std=True)[1][0] ** 2 for g in gprs])
    return mean, (D.T * wc) @ D + np.diag(variances), np.diag(variances), gprs


@pytest.mark.parametrize("case", [("increments", 20, 4), ("increments", 20, 5), ("increments", 60, 4), ("state", 20, 4)])
def test_generated_gp_ukf_predict_equals_a_numpy_unscented_transform(remus, short, training_sets, compiled, case):
    """Draws 4 and 5 of one size run through the same compiled library: only the data differ."""
    from abyssal.runtime.filters.kalman.gp_ukf import GPUKF
    from abyssal.symbolic import gp

    training, path = training_sets[case]
    c = compiled[case[:2]]
    _, data = gp_model.runtime_data(str(path), gp_model.file_digest(path))
    x0 = short.x[100]
    P0 = np.diag([1e-4] * 6 + [1.0, 1.0, 1e-2, 1e-4, 1e-4, 1e-3])
    f = GPUKF(remus, c.library, c.name, x0, P0, scenario.SENSOR_R, gp_dt=0.2, gp_data=data)
    f.predict(short.u[100], 0.2)
    mean, cov, Q, gprs = _ut_reference(training, x0, P0, short.u[100])
    np.testing.assert_allclose(f.x, mean, rtol=0, atol=1e-9 * np.max(np.abs(mean)))
    np.testing.assert_allclose(f.P, cov, rtol=0, atol=1e-9 * np.max(np.abs(cov)))
    # GP variances: to 1e-9 of each GP's prior variance (a noise-free GP's variance near its data is ~0,
    # and the generated kernel expands |x - x_i|^2, which rounds differently from scikit-learn)
    prior = []
    for g in gprs:
        signal, _, noise = gp.kernel_hyperparameters(g.kernel_)
        prior.append((signal + noise) * gp.target_normalisation(g)[1][0] ** 2)
    assert np.all(np.abs(np.diag(f.last_Q) - np.diag(Q)) <= 1e-9 * np.array(prior))


def test_gp_ukf_follows_the_filter_contract(remus, short, training_sets, compiled):
    from abyssal.runtime.filters.kalman.gp_ukf import GPUKF

    _, path = training_sets[("increments", 20, 4)]
    c = compiled[("increments", 20)]
    _, data = gp_model.runtime_data(str(path), gp_model.file_digest(path))
    P0 = np.diag([1e-4] * 6 + [1.0, 1.0, 1e-2, 1e-4, 1e-4, 1e-3])
    with pytest.raises(ValueError, match="gp_data"):
        GPUKF(remus, c.library, c.name, short.x[0], P0, scenario.SENSOR_R, gp_dt=0.2, gp_data=data[:-1])
    wrong = list(data)
    wrong[3] = wrong[3][:-1]
    with pytest.raises(ValueError, match="gp_data"):
        GPUKF(remus, c.library, c.name, short.x[0], P0, scenario.SENSOR_R, gp_dt=0.2, gp_data=wrong)
    # gate off: this small GP predicts poorly enough that the innovation gate (tests/runtime/test_gate.py)
    # leaves out some entries, and this test counts the entries NaN leaves out
    f = GPUKF(remus, c.library, c.name, short.x[0], P0, scenario.SENSOR_R, gp_dt=0.2, gp_data=data, gate_probability=0.0)
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


@pytest.fixture(scope="module")
def prepared_config(remus, short, training_sets, compiled):
    from abyssal.runtime.experiments.remus import experiment

    Q = experiment.process_noise(short, remus)
    gps = []
    for (targets, n, draw), (_, path) in training_sets.items():
        c = compiled[(targets, n)]
        gps.append(experiment.GPSetup(targets, n, draw, str(path), gp_model.file_digest(path), str(c.library), c.name))
    return experiment.RemusConfig(duration=60.0, draws=(4, 5), ukfs=(experiment.UKFSetup("UKF (oracle)", "remus100",
                                                                                          tuple(map(tuple, Q))),),
                                  gps=tuple(gps))


def test_run_one_gives_tidy_rows_per_reading_size_and_draw(prepared_config, monkeypatch):
    from abyssal.runtime.experiments.campaign import run_seeds
    from abyssal.runtime.experiments.remus import experiment

    monkeypatch.setattr(experiment, "PREDICTION_STARTS", (20, 30))
    with pytest.raises(ValueError, match="not prepared"):
        experiment.run_one(experiment.RemusConfig(duration=60.0), run_seeds(0, 1)[0])
    rows = experiment.run_one(prepared_config, run_seeds(0, 2)[1])      # run 1: draw 5
    assert {r["run"] for r in rows} == {1}
    assert {(r["filter"], r["case"]) for r in rows} == {("UKF (oracle)", "true model"), ("GP-UKF N=20", "draw 5"),
                                                        ("GP-UKF N=60", "draw 5")}
    metrics = {r["metric"] for r in rows}
    assert {"rmse_x", "rmse_psi", "correction", "prediction", "predict_10s", "predict_10s_diverged", "anees",
            "anees_measured", "anees_xy", "step_ms"} <= metrics
    assert all(np.isfinite(r["value"]) for r in rows)
    value = {(r["filter"], r["metric"]): r["value"] for r in rows}
    for name in ("UKF (oracle)", "GP-UKF N=20"):   # prediction: the RMS of the horizontal error (Pythagoras of x, y)
        assert value[(name, "prediction")] == pytest.approx(math.hypot(value[(name, "rmse_x")], value[(name, "rmse_y")]))
    rows0 = experiment.run_one(prepared_config, run_seeds(0, 1)[0])      # run 0: draw 4, with its next-state targets
    assert {r["filter"] for r in rows0} == {"UKF (oracle)", "GP-UKF N=20", "GP-UKF N=60", "GP-UKF (state) N=20"}
    assert {r["case"] for r in rows0 if r["filter"].startswith("GP")} == {"draw 4"}


def _rows(values: dict) -> list[dict]:
    """{(filter, case, run): {metric: value}} -> tidy rows."""
    return [{"run": run, "case": case, "filter": name, "metric": m, "value": v}
            for (name, case, run), metrics in values.items() for m, v in metrics.items()]


def test_report_names_its_statistics_and_computes_the_paper_checks():
    from abyssal.runtime.experiments.remus import experiment, paper

    states = {f"rmse_{s}": paper.TABLE3["UKF"][s] for s in experiment.STATE_NAMES}
    base = {"correction": 1.0, "prediction": 2.0, "predict_10s": 1.0, "predict_10s_diverged": 0.0, "anees": 12.0,
            "anees_measured": 10.0, "anees_xy": 2.0, "step_ms": 1.0}
    values = {}
    for run in range(4):
        values[("UKF (oracle)", "true model", run)] = {**states, **base, "rmse_x": states["rmse_x"] * (1 + run)}
        values[("UKF (Euler, 1 step)", "true model", run)] = {**{k: v * 10 for k, v in states.items()}, **base}
        draw = (4, 5)[run % 2]
        values[("GP-UKF N=100", f"draw {draw}", run)] = {**states, **base, "prediction": float(draw + run)}
    rows = _rows(values)
    s = experiment.statistic(rows, "UKF (oracle)", "rmse_x")
    assert s.mean == pytest.approx(2.5 * states["rmse_x"]) and s.sd == pytest.approx(np.std([1, 2, 3, 4], ddof=1) * states["rmse_x"])
    per = experiment.per_draw(rows, "GP-UKF N=100", "prediction")            # draw 4: runs 0, 2; draw 5: runs 1, 3
    assert per["draw 4"].mean == 5.0 and per["draw 5"].mean == 7.0 and per["draw 4"].n == 2
    between = experiment.statistic(rows, "GP-UKF N=100", "prediction")
    assert (between.mean, between.sd, between.n) == (6.0, pytest.approx(math.sqrt(2)), 2)
    best, scores = experiment.closest_reading(rows)
    assert best == "UKF (oracle)" and scores["UKF (Euler, 1 step)"][0] == pytest.approx(1.0)
    text = experiment.report(rows)
    assert "sd (ddof 1)" in text and "BETWEEN training draws" in text and "ORACLE" in text
    assert "sigma 14.6908 m exceeds sqrt(20) x mean = 10.8 m" in text and "sigma 8.5834 m exceeds" in text
    assert "closest: UKF (oracle); no reading is within a factor 2" in text   # rmse_x is 2.5x the paper's


def test_a_diverged_run_stays_in_the_statistics():
    """A run whose error is inf is counted (mean inf, printed "inf"), never left out of the table."""
    from abyssal.runtime.experiments.remus import experiment

    rows = _rows({("UKF (oracle)", "true model", run): {"prediction": v} for run, v in enumerate([1.0, math.inf, 2.0])})
    s = experiment.statistic(rows, "UKF (oracle)", "prediction")
    assert s.n == 3 and s.mean == math.inf and experiment.cell(s) == "inf"
    assert experiment.cell(experiment.statistic(rows, "UKF (Euler, 1 step)", "prediction")) == "-"


def test_resume_refuses_a_bad_table_before_the_gps_are_trained(tmp_path, monkeypatch):
    import argparse

    from abyssal.runtime.experiments import campaign, reproduce
    from abyssal.runtime.experiments.remus import experiment

    def no_training(*args, **kwargs):
        raise AssertionError("prepare ran: the GPs were trained before the table was checked")

    monkeypatch.setattr(experiment, "prepare", no_training)
    args = argparse.Namespace(runs=1, seed=0, particles=None, workers=0, scheduler=None, resume=True, quick=False,
                              out=str(tmp_path), json=False)
    table = tmp_path / "remus.csv"
    table.write_text("run,case,filter,metric,value\n0,draw 4,GP-UKF N=100,prediction,1.0\n")
    with pytest.raises(campaign.TableRefused, match="no sidecar"):        # a table abyssal did not write
        reproduce.run("remus", args)
    rows = [{"run": 0, "case": "draw 4", "filter": "GP-UKF N=100", "metric": "prediction", "value": 1.0},
            {"run": 0, "case": "draw 4", "filter": "GP-UKF N=100", "metric": "rmse_x", "value": 0.5}]
    campaign.run_campaign(lambda config, seed: rows, "any config", 1, 0, workers=0, csv_path=table, experiment="remus",
                          progress=False)
    campaign.check_resume(table, "remus", 0)                               # as written: accepted
    with pytest.raises(campaign.TableRefused, match="different seed"):
        campaign.check_resume(table, "remus", 1)
    table.write_text(table.read_text().replace("0.5", "0.6"))               # a changed value
    with pytest.raises(campaign.TableRefused, match="line 3"):
        reproduce.run("remus", args)
    args.resume = False                                                     # a fresh start needs no check: prepare runs
    with pytest.raises(AssertionError, match="prepare ran"):
        reproduce.run("remus", args)


def test_a_hyperparameter_fit_keeps_the_best_of_its_starts_and_escapes_a_noise_only_start():
    """fit_gp: from a start at the noise-only optimum (length scales at their bound, everything noise) L-BFGS-B stays
    there; the fit keeps the start whose optimum has the largest log marginal likelihood, and that LML is the GP's."""
    from sklearn.gaussian_process import GaussianProcessRegressor

    rng = np.random.default_rng(0)
    X = rng.uniform(-2.0, 2.0, (60, 2))
    y = np.sin(2.0 * X[:, 0]) + 0.05 * rng.standard_normal(60)
    noise_only = np.log([1.0, 1e4, 1e4, 1.0])  # signal, two length scales at their upper bound, noise
    fit = gp_model.fit_gp(X, y, [noise_only, None, gp_model.kernel(2).theta], seed=0)
    assert math.isnan(fit.start_lml[1]) and fit.chosen == 2
    assert fit.lml == np.nanmax(fit.start_lml) and fit.lml > fit.start_lml[0] + 100.0  # far above the stalled start
    refit = GaussianProcessRegressor(gp_model.kernel(2).clone_with_theta(fit.theta), normalize_y=True,
                                     optimizer=None).fit(X, y)
    assert refit.log_marginal_likelihood_value_ == pytest.approx(fit.lml, rel=1e-9)


def test_every_gp_of_a_draw_records_the_best_of_its_starts(training_sets):
    """fit_draw's starts: the default, the smaller size's optimum (none at the smallest size) and the random ones;
    each GP keeps the largest LML of them and records it."""
    for (targets, n, draw), (s, path) in training_sets.items():
        assert s.start_lml.shape == (12, 2 + gp_model.RESTARTS)
        np.testing.assert_array_equal(s.lml, np.nanmax(s.start_lml, axis=1))
        assert np.isnan(s.start_lml[:, 1]).all()  # the smallest fitted size has no warm start
        loaded = gp_model.TrainingSet.load(path)
        np.testing.assert_array_equal(loaded.lml, s.lml)
