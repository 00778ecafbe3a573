"""The seed-000 ROV scenario: noise models as data, the process-noise readings, the RK4 substep
margin of rov4dof, the catenary path, the truth simulator, the experiment on the campaign harness
and `abyssal reproduce rov` output."""
import argparse
import json

import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime.experiments import campaign, reproduce
from abyssal.runtime.experiments.rov import experiment, paper
from abyssal.runtime.experiments.rov.scenario import SEA_STATES, RovScenario, mass_diagonal, simulate


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


def test_sea_states_are_data_with_renormalised_weights():
    assert SEA_STATES["0"].measurement_noise().n_components == 1
    sea12 = SEA_STATES["1-2"]
    # the printed weights (1.875, 0.04) sum to 1.915: renormalised, keeping their ratio
    assert sum(sea12.printed_weights) != pytest.approx(1.0)
    assert sum(sea12.weights) == pytest.approx(1.0, abs=1e-15)
    assert sea12.weights[0] / sea12.weights[1] == pytest.approx(sea12.printed_weights[0] / sea12.printed_weights[1])
    # the readings of the printed formulas, as relations between the components (not the literals again):
    # "N(0.357*R)" is 0.357 times sea state 1-2's R, and sea state 3's R1 is that same R
    c12 = sea12.measurement_noise().covariances
    np.testing.assert_allclose(c12[1], 0.357 * c12[0], rtol=1e-15)
    np.testing.assert_array_equal(SEA_STATES["3"].measurement_noise().covariances[0], c12[0])
    rng = np.random.default_rng(11)
    for sea in SEA_STATES.values():
        noise = sea.measurement_noise()
        np.testing.assert_array_equal(noise.weights, sea.weights)
        assert np.isclose(sea.weights.sum(), 1.0)
        for cov, diagonal in zip(noise.covariances, sea.diagonal_covariances):
            np.testing.assert_array_equal(cov, np.diag(diagonal))
        # the mixture the truth samples has the moment-matched covariance the CKF is given
        draws = noise.sample(rng, 200_000)[0]
        sample = np.cov(draws)
        np.testing.assert_allclose(np.diag(sample), np.diag(noise.covariance()), rtol=0.03)
        assert np.all(np.abs(sample / np.sqrt(np.outer(np.diag(sample), np.diag(sample))) - np.eye(4)) < 0.02)  # uncorrelated
        assert np.all(np.abs(draws.mean(axis=1)) < 4 * np.sqrt(np.diag(noise.covariance()) / 200_000))  # zero mean


def test_sea_state_kurtosis_is_the_mixtures_and_the_wide_reading_keeps_the_paper_non_gaussian():
    """The excess kurtosis the report prints per sea state is the mixture's (checked against 400 000 draws), and
    the two readings of the misprinted sea 1-2 mixture differ in the direction the case is about: narrow second
    component (ours) Gaussian in effect, wide second component heavier-tailed."""
    rng = np.random.default_rng(5)
    for sea in SEA_STATES.values():
        draws = sea.measurement_noise().sample(rng, 400_000)[0]
        sample = np.mean(draws**4, axis=1) / np.mean(draws**2, axis=1) ** 2 - 3.0
        np.testing.assert_allclose(sample, sea.excess_kurtosis(), atol=0.05)
    narrow, wide = SEA_STATES["1-2"], SEA_STATES["1-2 wide"]
    np.testing.assert_array_equal(narrow.weights, wide.weights)  # the same renormalised weights
    c = wide.measurement_noise().covariances
    np.testing.assert_allclose(c[1], c[0] / 0.357, rtol=1e-15)  # R / 0.357: the rare component wider
    assert np.all(narrow.excess_kurtosis() < 0.05) and np.all(wide.excess_kurtosis() > 0.15)
    assert SEA_STATES["0"].excess_kurtosis() == pytest.approx(0.0, abs=1e-12)


def test_the_papers_ckf_is_ungated_and_the_gated_one_is_a_labelled_variant(rov):
    """The paper's CKF has no innovation gate: both CKF rows are built ungated; the gated CKF is a row of its own."""
    from abyssal.runtime.experiments.rov.scenario import make_filter

    sea, scenario = SEA_STATES["0"], RovScenario()
    specs = {spec.label: spec for spec in experiment.MAIN_FILTERS}
    outlier = np.array([50.0, -50.0, 50.0, 0.0])  # ~90 sigma of R on x, y, z: any gate leaves them out

    def gated(label):
        filt = make_filter("CKF", rov, scenario, sea, 10, 0, **dict(specs[label].options))
        filt.step(np.zeros(4), scenario.dt, outlier)
        return filt.gated

    assert gated("CKF (matched model)") == 0 and gated("CKF (mismatched Q)") == 0
    assert gated("CKF (mismatched Q, gated)") == 3
    assert "CKF (mismatched Q, gated)" not in experiment.PAPER_COLUMN  # never printed as the paper's CKF


def test_process_noise_readings_give_q_k_as_documented(rov):
    printed = np.array([0, 0, 0, 0, 3, 4, 5, 0.02, 2, 2, 2, 0.5])
    plain = RovScenario(process_noise_reading="plain")
    assert np.array_equal(plain.process_covariance(rov), np.diag(printed))  # Q_k = Q, as printed
    density = plain.with_reading("density")
    Q = density.process_covariance(rov)
    mass = mass_diagonal(rov)
    assert np.allclose(mass, [26 + 24.56, 26 + 34.27, 26 + 39.19, 1.04 + 2.01])
    e = np.concatenate([np.ones(4), 1 / mass, np.ones(4)])
    floor = np.array([1e-3, 1e-3, 1e-3, 1e-4] + [0] * 8)
    assert np.allclose(Q, np.diag(0.1 * e**2 * (printed + floor)), rtol=1e-15, atol=0)  # dt E Q E^T + floor
    assert np.all(np.linalg.eigvalsh(Q) > 0)
    assert np.array_equal(plain.process_covariance(rov, "density"), Q)  # a reading can be asked for explicitly
    with pytest.raises(ValueError, match="process_noise_reading"):
        RovScenario(process_noise_reading="per-second")


def test_truth_noise_follows_the_reading(rov):
    """The simulated truth's one-step velocity noise has the variance of the chosen Q_k."""
    for reading in ("plain", "density"):
        scenario = RovScenario(duration=30.0, process_noise_reading=reading)
        truth = simulate(rov, scenario, SEA_STATES["0"], np.random.default_rng(5))
        previous = np.vstack([truth.initial_state, truth.states[:-1]])
        predicted = rov.f_batch(previous.T, truth.inputs.T, None, scenario.dt).T
        residual = truth.states - predicted
        expected = np.diag(scenario.process_covariance(rov))
        assert np.allclose(residual[:, 4:].var(axis=0), expected[4:], rtol=0.2)
        assert np.allclose(residual[:, :4], 0, atol=1e-9 if reading == "plain" else 0.1)


def test_rk4_substeps_keep_the_generated_step_stable_over_the_sigma_point_box(rov):
    """No blow-up for |u|,|v|,|w| <= 10 m/s, |r| <= 5 rad/s with thrust at 0 and the limits (100 steps
    from every corner), and a 2x margin: one step from 20 m/s (or 10 rad/s) still shrinks the speed."""
    corners = np.array(np.meshgrid([-10, 10], [-10, 10], [-10, 10], [-5, 5])).reshape(4, -1)
    X0 = np.zeros((12, corners.shape[1]))
    X0[4:8] = corners
    X0[3] = np.linspace(-3, 3, corners.shape[1])
    limit = np.array(RovScenario().thrust_limit)
    for tau in (np.zeros(4), limit, -limit):
        U = np.tile(tau[:, None], (1, X0.shape[1]))
        X = X0.copy()
        for _ in range(100):
            X = rov.f_batch(X, U, None, 0.1)
            assert np.all(np.isfinite(X)) and np.abs(X[4:8]).max() <= 10.0 + 1e-9
    for axis, speed in ((4, 20.0), (5, 20.0), (6, 20.0), (7, 10.0)):
        X = np.zeros((12, 2))
        X[axis] = (speed, -speed)
        Y = rov.f_batch(X, np.zeros((4, 2)), None, 0.1)
        assert np.all(np.abs(Y[axis]) < speed)


def test_reference_follows_the_catenary():
    scenario = RovScenario()
    pose, rate = scenario.reference(100.0)
    s = scenario.climb_speed * 100.0
    assert np.isclose(np.hypot(pose[0], pose[1]), s)
    assert np.isclose(pose[2], -60.845 * (np.cosh(s / 60.845) - 1))
    h = 1e-6
    numeric = (scenario.reference(100.0 + h)[0] - scenario.reference(100.0 - h)[0]) / (2 * h)
    assert np.allclose(rate, numeric, atol=1e-6)


def test_truth_tracks_the_path_and_is_reproducible(rov):
    """Under the density reading the controller tracks the path; under the plain one (the default) the
    printed Q shakes the vehicle by ~1.7 m/s per step, the thrust saturates and it drifts metres off
    the path (a property of that reading, reported in the experiment's notes), but the truth stays finite."""
    for reading, tolerance in (("density", 1.0), ("plain", 40.0)):
        scenario = RovScenario(process_noise_reading=reading)
        a = simulate(rov, scenario, SEA_STATES["0"], np.random.default_rng(3))
        b = simulate(rov, scenario, SEA_STATES["0"], np.random.default_rng(3))
        assert np.array_equal(a.states, b.states) and np.array_equal(a.measurements, b.measurements)
        assert a.states.shape == (2000, 12) and a.inputs.shape == (2000, 4) and np.all(np.isfinite(a.states))
        end, _ = scenario.reference(a.times[-1])
        assert np.linalg.norm(a.states[-1, :3] - end[:3]) < tolerance
        residual = a.measurements - a.states[:, :4]
        assert np.allclose(residual.var(axis=0), [0.3, 0.2, 0.3, 0.05], rtol=0.15)


def _short(**changes):
    return experiment.short_config(duration=3.0, n_particles=20, **changes)


def test_run_one_gives_tidy_rows_for_every_case_and_filter():
    config = _short(sea_states=("0", "3"))
    rows = experiment.run_one(config, campaign.run_seeds(0, 1)[0])
    assert all(set(r) == {"run", "case", "filter", "metric", "reading", "value"} for r in rows)
    assert {r["case"] for r in rows} == {"0", "3"} and {r["reading"] for r in rows} == {"plain", "density"}
    labels = {r["filter"] for r in rows}
    assert {"PF", "CKF (matched model)", "CKF (mismatched Q)", "CPF", "EM-MOGCPF", "GS-CKF"} <= labels
    assert "EM-MOGCPF N=3000" in {r["filter"] for r in rows if r["case"] == "3" and r["reading"] == "plain"}
    assert "EM-MOGCPF N=3000" not in {r["filter"] for r in rows if r["case"] == "0"}
    assert all(r["value"] == 0.0 for r in rows if r["metric"] == "refused")
    ess = {(r["case"], r["filter"], r["reading"]): r["value"] for r in rows if r["metric"] == "ess_mean"}
    for r in rows:
        collapsed = ess.get((r["case"], r["filter"], r["reading"]), np.nan) < 2.0  # (the carried-P^i CPF as printed)
        if r["metric"] == "anees" and collapsed:  # a cloud of one particle: its covariance is singular, NEES inf
            assert r["value"] > 1e6, r
        elif r["metric"].startswith("mse_") or r["metric"] in ("anees", "step_ms"):
            assert np.isfinite(r["value"]) and r["value"] >= 0, r
        if r["metric"] == "ess_mean":
            assert np.isnan(r["value"]) == ("CKF" in r["filter"]), r
        if r["metric"] == "ess_mean" and r["filter"] == "EM-MOGCPF":
            assert r["value"] > 0.99 * config.n_particles  # linear h: the cubature mixture is the exact posterior
    again = experiment.run_one(config, campaign.run_seeds(0, 1)[0])
    def strip(rs):  # bit patterns (NaN == NaN), timings left out
        return [(*(r[c] for c in ("case", "filter", "metric", "reading")), np.float64(r["value"]).tobytes())
                for r in rs if r["metric"] not in campaign.TIMING_METRICS]
    assert strip(rows) == strip(again)  # pure: the same seed gives the same numbers


def test_cpf_keeps_its_particles_alive_in_every_sea_state_at_the_default_reading():
    """Mean ESS above N/10 (the carried-P^i CPF once had ESS ~ 1 everywhere)."""
    cpf = next(f for f in experiment.MAIN_FILTERS if f.label == "CPF")
    config = experiment.RovConfig(scenario=RovScenario(duration=10.0), n_particles=100, readings=("plain",), filters=(cpf,))
    stats = experiment.summary(experiment.run_one(config, campaign.run_seeds(1, 1)[0]))
    for sea in SEA_STATES:
        assert stats[("plain", sea, "CPF")]["ess_mean"] > 100 / 10, sea


def test_reproduce_rov_json_csv_and_figures_on_the_campaign(tmp_path, capsys):
    args = argparse.Namespace(experiment="rov", runs=2, seed=1, particles=None, out=str(tmp_path), json=True,
                              workers=0, scheduler=None, resume=False)
    assert reproduce.run("rov", args, config=_short()) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["experiment"] == "rov" and report["runs"] == 2 and not report["failures"]
    assert {"plain|3|CPF", "density|0|CKF (matched model)", "plain|1-2|EM-MOGCPF"} <= set(report["summary"])
    assert set(report["summary"]["plain|3|CPF"]) == {"rmse", "rmse_sd", "rmse_ci95", "rmse_pooled", "anees", "anees_sd",
                                                     "ess_mean", "gated_updates", "gated_updates_range", "step_ms",
                                                     "runs", "refused_runs"}
    rows = campaign.read_csv(tmp_path / "rov.csv", campaign.TIDY_COLUMNS[:-1] + experiment.EXTRA_COLUMNS + ("value",))
    assert {r["run"] for r in rows} == {0, 1}
    made = reproduce._strict_json(experiment.summary(rows)[("plain", "3", "CPF")])  # NaN (no gate count) as null
    assert report["summary"]["plain|3|CPF"] == made  # made from the rows
    seas = len(SEA_STATES)
    assert len(list(tmp_path.glob("rov_rmse_sea_*.png"))) == seas and len(list(tmp_path.glob("rov_errors_sea_*.png"))) == seas
    assert len(list(tmp_path.glob("rov_velocity_errors_sea_*.png"))) == seas  # the paper's Figs. 6, 8, 10
    # the text tables: the paper's Table 3 beside ours, the sensitivity table and the rankings
    args.json = False
    args.resume = True  # nothing left to run: the tables come from the CSV alone
    assert reproduce.run("rov", args, config=_short()) == 0
    text = capsys.readouterr().out
    assert "CKF (matched model)" in text and "CKF (mismatched Q)" in text and "1.8577" in text
    assert "Wall time per filter step" in text  # the timings, apart from the tables
    assert "sample sd over runs (ddof = 1)" in text and "psi rad" in text  # the statistic and the unit, named
    assert "Sensitivity to the process-noise reading" in text and "paper: EM-MOGCPF < CPF" in text


def test_paper_table_is_complete_and_independent_of_our_runs():
    table = paper.table3_rmse()
    assert set(table) == {"0", "1-2", "3"}
    for sea, rows in table.items():
        assert set(rows) == {"PF", "CKF", "CPF", "EM-MOGCPF"}, sea  # Table 3 has no MOGCPF row
        for row in rows.values():
            assert set(row) == {"x", "y", "z", "psi"} and all(0 < v < 100 for v in row.values()), sea
    assert paper.table3_rmse() == table and paper.table3_rmse() is not table  # a fresh copy each time


def test_table3_prints_each_paper_number_in_its_own_cell():
    """Every quoted number sits in the row of its sea state and axis, under its filter's 'paper' column."""
    values = {**{m: 1.0 for m in experiment.METRICS}, "refused": 0.0}
    rows = [{"run": 0, "case": sea, "filter": label, "metric": m, "reading": "plain", "value": v}
            for sea in SEA_STATES for label in ("PF", "CKF (matched model)", "CPF", "EM-MOGCPF") for m, v in values.items()]
    lines = experiment.table3(rows).splitlines()
    for sea, filters in paper.table3_rmse().items():
        start = next(i for i, line in enumerate(lines) if line.startswith(f"{sea:<10}x "))
        for offset, axis in enumerate(paper.AXES):
            cells = lines[start + offset].split()[-8:]  # ours, paper for PF, CKF, CPF, EM-MOGCPF
            quoted = [float(c) for c in cells[1::2]]
            assert quoted == [filters[f][axis] for f in ("PF", "CKF", "CPF", "EM-MOGCPF")], (sea, axis)


def test_summary_is_the_mean_of_per_run_rmse_with_the_sample_sd_and_names_the_pooled_one_apart():
    mse = [0.04, 0.25, 0.09]  # per-run RMSE 0.2, 0.5, 0.3
    rows = [{"run": r, "case": "0", "filter": "PF", "metric": m, "reading": "plain", "value": v}
            for r, x in enumerate(mse) for m, v in {**{f"mse_{a}": x for a in paper.AXES}, "anees": 1.0 + r,
                                                    "ess_mean": 100.0, "step_ms": 1.0, "refused": 0.0}.items()]
    rows.append({"run": 3, "case": "0", "filter": "PF", "metric": "refused", "reading": "plain", "value": 1.0})
    rows += [{"run": 3, "case": "0", "filter": "PF", "metric": f"mse_{a}", "reading": "plain", "value": float("nan")}
             for a in paper.AXES]
    s = experiment.summary(rows)[("plain", "0", "PF")]
    assert s["rmse"]["x"] == pytest.approx(np.mean([0.2, 0.5, 0.3]))
    assert s["rmse_sd"]["x"] == pytest.approx(np.std([0.2, 0.5, 0.3], ddof=1))
    assert s["rmse_pooled"]["x"] == pytest.approx(np.sqrt(np.mean(mse))) and s["rmse_pooled"]["x"] > s["rmse"]["x"]
    from scipy import stats

    low, high = stats.t.interval(0.95, 2, loc=np.mean([0.2, 0.5, 0.3]), scale=stats.sem([0.2, 0.5, 0.3]))
    assert s["rmse_ci95"]["x"] == pytest.approx((high - low) / 2)
    assert s["runs"] == 3 and s["refused_runs"] == 1 and s["anees"] == pytest.approx(2.0)


def test_quick_keeps_every_case_and_main_filter_and_leaves_the_costly_sweep_out():
    default = experiment.RovConfig()
    quick = default.quick()
    assert quick.cases() == default.cases() and quick.scenario.duration == 20.0
    labels = {f.label for f in quick.filters}
    assert labels == {f.label for f in experiment.MAIN_FILTERS}
    assert not labels & {f.label for f in experiment.N_SWEEP}
