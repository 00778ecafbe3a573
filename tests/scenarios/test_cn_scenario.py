"""Seed 002's simulated lake trial (runtime/experiments/cn/scenario.py) and its campaign run."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from abyssal.runtime.experiments.campaign import run_seeds
from abyssal.runtime.experiments.cn import experiment, scenario

SC = scenario.CnScenario()


def test_trial_shapes_leaders_alternate_and_p_is_the_broadcast_leader():
    tr = scenario.simulate(SC, "gaussian", np.random.default_rng(0))
    K = int(SC.duration // SC.ping_period)
    assert tr.Z.shape == (K, 2) and tr.U.shape == (K, 3) and tr.params.shape == (K, 4) and tr.truth.shape == (K, 2)
    np.testing.assert_array_equal(tr.leader, np.arange(K) % 2)
    # one range sensor per leader: the ping's range in its leader's column, NaN in the other's; the pinging
    # leader's broadcast in its own parameter slots
    rows = np.arange(K)
    np.testing.assert_array_equal(tr.Z[rows, tr.leader], tr.ranges)
    assert np.isnan(tr.Z[rows, 1 - tr.leader]).all()
    np.testing.assert_array_equal(tr.params.reshape(K, 2, 2)[rows, tr.leader], tr.gps)
    assert [scenario.ping(tr, k)[0] for k in range(3)] == ["leader0", "leader1", "leader0"]
    true_leader = tr.leaders_true[tr.leader, np.arange(K)]
    gps_error = tr.gps - true_leader
    assert 1.0 < gps_error.std() < 2.2  # 1.8 m CEP
    # the AUV is between the leaders (Fig. 6)
    assert np.all((tr.truth[:, 1] < tr.leaders_true[0, :, 1]) & (tr.truth[:, 1] > tr.leaders_true[1, :, 1]))


def test_filter_input_reproduces_dead_reckoning_through_cn2d(cn):
    tr = scenario.simulate(SC, "gaussian", np.random.default_rng(1))
    x = tr.x0.copy()
    for k in range(len(tr.t)):
        x = cn.f(x, tr.U[k], tr.params[k], tr.dt)
        np.testing.assert_allclose(x, tr.dr[k], atol=1e-8)


def test_dead_reckoning_drifts_tens_of_metres_on_average():
    apes = [scenario.ape(t.dr, t.truth) for t in (scenario.simulate(SC, "gaussian", np.random.default_rng(s)) for s in range(12))]
    assert 10.0 < np.mean(apes) < 100.0


@pytest.mark.parametrize("case,eps", [("eps0.1", 0.1), ("eps0.3", 0.3)])
def test_contamination_matches_eq_1(case, eps):
    errors = np.concatenate([scenario.simulate(SC, case, np.random.default_rng(s)).range_error for s in range(30)])
    # variance of (1 - eps) N(0, R) + eps N(0, 10 R) is (1 + 9 eps) R
    assert abs(errors.var() / ((1 + 9 * eps) * SC.range_variance) - 1) < 0.15


def test_multipath_are_late_arrivals():
    errors = np.concatenate([scenario.simulate(SC, "multipath", np.random.default_rng(s)).range_error for s in range(30)])
    late = errors > 8.0
    assert 0.03 < late.mean() < 0.07 and errors.min() > -6.0


def test_same_seed_same_trial_and_unknown_case_refused():
    a = scenario.simulate(SC, "eps0.3", np.random.default_rng(5))
    b = scenario.simulate(SC, "eps0.3", np.random.default_rng(5))
    np.testing.assert_array_equal(a.Z, b.Z)
    with pytest.raises(ValueError, match="noise case"):
        scenario.simulate(SC, "laplace", np.random.default_rng(0))


def _trial(geometry: str, case: str = "gaussian", seed: int = 3, **changes):
    return scenario.simulate(replace(SC, leaders=scenario.GEOMETRIES[geometry], **changes), case,
                             np.random.default_rng(seed))


def test_the_geometry_draws_no_random_numbers_so_trials_are_paired():
    a, b = _trial("collinear", "eps0.3"), _trial("crossing90", "eps0.3")
    for name in ("truth", "dr", "U", "x0", "range_error"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.allclose(a.Z, b.Z)  # the ranges are to other leaders
    with pytest.raises(ValueError, match="leaders"):
        scenario.simulate(replace(SC, leaders=((0.0, 400.0),)), "gaussian", np.random.default_rng(0))


def test_crossing_angle_and_gdop_against_the_two_range_geometry():
    """GDOP from (H^T H)^-1 of the two unit lines of sight, computed here apart; the angle between the range lines
    from the leaders' bearings."""
    trial = _trial("crossing60")
    for k in (0, 57, 200):
        los = trial.leaders_true[:, k] - trial.truth[k]
        H = los / np.linalg.norm(los, axis=1, keepdims=True)
        assert scenario.gdop(trial)[k] == pytest.approx(math.sqrt(np.trace(np.linalg.inv(H.T @ H))), rel=1e-9)
        bearings = np.arctan2(los[:, 1], los[:, 0])
        between = abs(math.degrees(bearings[0] - bearings[1])) % 180.0
        assert scenario.crossing_angles(trial)[k] == pytest.approx(min(between, 180.0 - between), abs=1e-9)


@pytest.mark.parametrize("geometry,low,high", [("collinear", 5, 15), ("crossing60", 58, 66), ("crossing90", 84, 90)])
def test_each_geometry_crosses_as_named(geometry, low, high):
    """The names say what the layouts do over a whole trial (medians), and the collinear one never crosses well."""
    angles = np.concatenate([scenario.crossing_angles(_trial(geometry, seed=s)) for s in range(3)])
    assert low < np.median(angles) < high
    if geometry == "collinear":
        assert angles.max() < 20.0 and np.median(np.concatenate([scenario.gdop(_trial(geometry, seed=s)) for s in range(3)])) > 5


def test_printed_tuning_beats_a_quarter_of_dead_reckoning_when_the_lines_cross_well_and_not_when_collinear(cn):
    """The Kalman filters of Table 7 with the paper's Q = (10 m)^2, R = 0.1 on one full trial: geometry, not the
    tuning, separates 'near dead reckoning' from 'a few metres'."""
    config = experiment.CnConfig()
    for geometry, better in (("crossing60", True), ("collinear", False)):
        trial = _trial(geometry)
        dr = scenario.ape(trial.dr, trial.truth)
        for name in ("CKF", "MCUKF"):
            filt = experiment.make_filter(name, cn, trial, config, np.random.default_rng(0))
            result = experiment.run_kalman_by_sensor(filt, trial)
            assert (scenario.ape(result.x, trial.truth) < dr / 4) == better, (geometry, name)


@pytest.mark.parametrize("name", ["CKF", "MCUKF"])
def test_each_leader_as_its_own_sensor_update_equals_the_stacked_run(cn, name):
    """update(leader_k, z, t, p=gps) per ping gives the estimates of run() on the stacked form (the silent leader's
    entry NaN) to rounding, and the NEES the filter reports."""
    config, trial = experiment.CnConfig(), _trial("crossing60", "multipath")
    by_sensor = experiment.run_kalman_by_sensor(experiment.make_filter(name, cn, trial, config, None), trial)
    stacked = experiment.make_filter(name, cn, trial, config, None).run(trial.U, trial.Z, trial.dt,
                                                                       params=trial.params, truth=trial.truth)
    np.testing.assert_allclose(by_sensor.x, stacked.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(by_sensor.nees, stacked.nees, rtol=1e-7)


def _short_config(**changes):
    quick = experiment.CnConfig().quick()
    return replace(quick, scenario=replace(quick.scenario, duration=300.0), n_particles=150, kld_n_max=100,
                   cases=("gaussian", "multipath"), geometries=("collinear", "crossing90"),
                   filters=("DR", "CKF", "UPF", "MCUPF"), tuned=("CKF",), **changes)


def test_run_one_rows_every_geometry_case_filter_and_stream():
    config = _short_config()
    rows = experiment.run_one(config, run_seeds(7, 1)[0])
    assert {r["filter"] for r in rows} == set(experiment.filter_names(config)) | {experiment.TRIAL}
    assert {r["case"] for r in rows} == {"gaussian", "multipath"} and {r["geometry"] for r in rows} == {"collinear", "crossing90"}
    streams = {(r["filter"], r["stream"]) for r in rows if r["metric"] == "ape_m" and r["geometry"] == "collinear"
               and r["case"] == "gaussian"}
    assert {s for f, s in streams if f == "MCUPF"} == set(range(config.streams))
    assert {s for f, s in streams if f in ("CKF", "DR", "CKF tuned")} == {0}
    value = {(r["geometry"], r["case"], r["filter"], r["stream"], r["metric"]): r["value"] for r in rows}
    assert all(math.isfinite(v) for k, v in value.items() if k[-1] == "ape_m")
    assert all(v == 0.0 for k, v in value.items() if k[-1] == "refused")
    # the streams differ (independent random numbers), the trial does not depend on the filter
    assert value[("collinear", "gaussian", "UPF", 0, "ape_m")] != value[("collinear", "gaussian", "UPF", 1, "ape_m")]
    # KLD: step 0 runs N_start = 150, the steady count afterwards is what KLD-resampling chose (<= N_max = 100)
    for s in range(config.streams):
        steady = value[("crossing90", "gaussian", "MCUPF", s, "steady_particles")]
        mean = value[("crossing90", "gaussian", "MCUPF", s, "mean_particles")]
        K = config.scenario.duration // config.scenario.ping_period
        assert config.kld_n_min <= steady <= config.kld_n_max
        assert mean == pytest.approx((150 + (K - 1) * steady) / K)
    assert value[("crossing90", "gaussian", "UPF", 0, "steady_particles")] == 150
    assert math.isnan(value[("crossing90", "gaussian", "CKF", 0, "mean_particles")])
    assert math.isnan(value[("crossing90", "gaussian", "DR", 0, "anees")])
    assert 0 <= value[("crossing90", "gaussian", "CKF", 0, "coverage95")] <= 1
    assert value[("collinear", "gaussian", experiment.TRIAL, 0, "crossing_median_deg")] < 20
    assert value[("crossing90", "gaussian", experiment.TRIAL, 0, "gdop_median")] < 1.5
    # a geometry's numbers do not depend on which other geometries run (the same seeds)
    again = experiment.run_one(replace(config, geometries=("crossing90",)), run_seeds(7, 1)[0])
    def strip(rs):
        return [(r["case"], r["filter"], r["stream"], r["metric"], r["value"]) for r in rs
                if r["geometry"] == "crossing90" and r["metric"] != "step_ms"]
    assert strip(again) == strip(rows)
    doc = experiment.json_document(rows)
    assert set(doc["crossing90"]["gaussian"]["MCUPF"]) >= {"ape_m", "ape_m_sd", "steady_particles", "stream_sd_m",
                                                          "paper_ape_m", "coverage95"}
    text = experiment.report(rows, config)
    assert "SIMULATED" in text and "geometry collinear" in text and "ddof = 1" in text


def test_tables_are_the_statistics_they_name():
    """Hand-made rows: 3 runs, a particle filter on 2 streams; the table's numbers recomputed here from the values."""
    rows = []
    ape = {"DR": [[20.0], [40.0], [30.0]], "UPF": [[4.0, 6.0], [12.0, 8.0], [6.0, 7.0]]}
    for f, runs in ape.items():
        for run, streams in enumerate(runs):
            for stream, v in enumerate(streams):
                rows.append({"run": run, "case": "gaussian", "filter": f, "metric": "ape_m", "geometry": "crossing60",
                             "stream": stream, "value": v})
    e = experiment.summary(rows)[("crossing60", "gaussian", "UPF")]
    per_run = [5.0, 10.0, 6.5]
    assert e["ape_m"].mean == pytest.approx(np.mean(per_run)) and e["ape_m"].sd == pytest.approx(np.std(per_run, ddof=1))
    assert e["stream_sd_m"] == pytest.approx(np.median([np.std(v, ddof=1) for v in ape["UPF"]]))
    assert e["below_dr4"] == (1, 3) and e["below_dr"] == (3, 3)  # 5 < 20/4 fails, 10 < 40/4 fails, 6.5 < 7.5


def test_config_refuses_unknown_geometries_and_no_streams():
    with pytest.raises(ValueError, match="geometries"):
        experiment.CnConfig(geometries=("triangle",))
    with pytest.raises(ValueError, match="streams"):
        experiment.CnConfig(streams=0)


def test_count_sweep_runs_the_cn_trials_with_each_floor_and_rule_set():
    """cn-count: the same trials as the cn experiment (the UPF under our rules is the cn experiment's UPF there, with
    its own streams), the KLD floor sets the steady count, both rule sets run, and the implied count interpolates."""
    from abyssal.runtime.experiments.cn import count_sweep

    base = replace(_short_config(), n_particles=120, kld_n_max=60)
    config = count_sweep.CountConfig(base=base, geometries=("crossing90",), cases=("multipath",), floors=(10, 120),
                                     streams=1)
    rows = count_sweep.run_one(config, run_seeds(3, 1)[0])
    value = {(r["filter"], r["metric"]): r["value"] for r in rows}
    assert {r["filter"] for r in rows} == set(config.labels())
    for rules in ("paper", "ours"):
        assert value[(count_sweep.mcupf_label(120, rules), "steady_particles")] == 120  # the floor above N_max
        assert 10 <= value[(count_sweep.mcupf_label(10, rules), "steady_particles")] <= 60
        assert value[(count_sweep.upf_label(rules), "steady_particles")] == 120
        assert all(math.isfinite(value[(label, "ape_m")]) for label in config.labels())
    # the rule sets differ in their estimates on the same trial and streams
    assert value[(count_sweep.upf_label("paper"), "ape_m")] != value[(count_sweep.upf_label("ours"), "ape_m")]
    ratios = [(10, 10.0, 0.5), (100, 100.0, 1.0), (1000, 1000.0, 2.0)]
    assert count_sweep.implied_count(ratios, 1.0) == pytest.approx(100.0)
    assert count_sweep.implied_count(ratios, 1.5) == pytest.approx(math.sqrt(100 * 1000))  # log-linear
    assert count_sweep.implied_count(ratios, 3.0) is None  # beyond the sweep
    assert "paper's rules" in count_sweep.report(rows, config)
