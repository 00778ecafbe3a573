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
    assert tr.Z.shape == (K, 1) and tr.U.shape == (K, 3) and tr.params.shape == (K, 2) and tr.truth.shape == (K, 2)
    np.testing.assert_array_equal(tr.leader, np.arange(K) % 2)
    true_leader = tr.leaders_true[tr.leader, np.arange(K)]
    gps_error = tr.params - true_leader
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


def test_run_one_rows_every_filter_finite():
    config = replace(experiment.CnConfig().quick(), n_particles=300, kld_n_max=200, cases=("gaussian", "multipath"))
    rows = experiment.run_one(config, run_seeds(7, 1)[0])
    assert {r["filter"] for r in rows} == set(experiment.filter_names(config))
    assert "MCUPF tuned" in {r["filter"] for r in rows}
    assert {r["case"] for r in rows} == {"gaussian", "multipath"}
    apes = {(r["case"], r["filter"]): r["value"] for r in rows if r["metric"] == "ape_m"}
    assert all(math.isfinite(v) for v in apes.values())
    particles = {(r["case"], r["filter"]): r["value"] for r in rows if r["metric"] == "mean_particles"}
    assert particles[("gaussian", "UPF")] == 300 and 50 <= particles[("gaussian", "MCUPF")] <= 300
    assert math.isnan(particles[("gaussian", "CKF")])
    doc = experiment.json_document(rows)
    assert set(doc["gaussian"]["MCUPF"]) >= {"ape_m", "step_ms", "mean_particles", "paper_ape_m"}
    assert "SIMULATED" in experiment.report(rows, config)
