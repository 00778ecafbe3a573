"""The seed-000 ROV scenario: noise models as data, the catenary path, the truth simulator, the
experiment runner and `abyssal reproduce rov` output."""
import argparse
import json

import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime.experiments import reproduce
from abyssal.runtime.experiments.rov.scenario import SEA_STATES, RovScenario, mass_diagonal, run_experiment, simulate


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


def test_sea_states_are_data_with_renormalised_weights():
    assert SEA_STATES["0"].measurement_noise().n_components == 1
    sea12 = SEA_STATES["1-2"]
    assert sea12.printed_weights == (1.875, 0.04)  # as printed: they sum to 1.915
    assert np.allclose(sea12.weights, [1.875 / 1.915, 0.04 / 1.915])
    noise = sea12.measurement_noise()
    assert np.allclose(noise.covariances[1], 0.357 * np.diag([0.4, 0.3, 0.3, 0.4]))
    sea3 = SEA_STATES["3"].measurement_noise()
    assert np.allclose(sea3.weights, [0.1, 0.9])
    assert np.allclose(np.diag(sea3.covariances[1]), 150 * np.array([0.2, 0.2, 0.1, 0.003]))
    for sea in SEA_STATES.values():
        assert np.isclose(sea.weights.sum(), 1.0)


def test_process_noise_is_printed_q_through_inverse_mass_per_second(rov):
    scenario = RovScenario()
    Q = scenario.process_covariance(rov)
    mass = mass_diagonal(rov)
    assert np.allclose(mass, [26 + 24.56, 26 + 34.27, 26 + 39.19, 1.04 + 2.01])
    assert np.isclose(Q[4, 4], 0.1 * 3 / mass[0] ** 2)
    assert np.isclose(Q[8, 8], 0.1 * 2)
    assert np.isclose(Q[0, 0], 0.1 * 1e-3)  # the pose floor
    assert np.all(np.linalg.eigvalsh(Q) > 0)


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
    scenario = RovScenario()
    a = simulate(rov, scenario, SEA_STATES["0"], np.random.default_rng(3))
    b = simulate(rov, scenario, SEA_STATES["0"], np.random.default_rng(3))
    assert np.array_equal(a.states, b.states) and np.array_equal(a.measurements, b.measurements)
    assert a.states.shape == (2000, 12) and a.inputs.shape == (2000, 4)
    end, _ = scenario.reference(a.times[-1])
    assert np.linalg.norm(a.states[-1, :3] - end[:3]) < 3.0
    residual = a.measurements - a.states[:, :4]
    assert np.allclose(residual.var(axis=0), [0.3, 0.2, 0.3, 0.05], rtol=0.15)


def test_experiment_metrics_and_reproduce_json(tmp_path, capsys):
    short = RovScenario(duration=3.0)
    results = run_experiment(1, 0, 20, sea_states=("0", "3"), scenario=short)
    metrics = results["3"]["metrics"]
    assert set(metrics) == {"PF", "CKF", "CPF", "MOGCPF", "EM-MOGCPF", "GS-CKF"}
    for m in metrics.values():
        assert set(m["rmse"]) == {"x", "y", "z", "psi"}
        assert all(np.isfinite(v) and v >= 0 for v in m["rmse"].values())
        assert m["step_ms"] > 0 and np.isfinite(m["anees"])

    args = argparse.Namespace(experiment="rov", runs=1, seed=1, particles=20, out=str(tmp_path), json=True)
    assert reproduce.run_rov(args, scenario=short) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["experiment"] == "rov" and report["runs"] == 1
    assert set(report["sea_states"]) == {"0", "1-2", "3"}
    assert set(report["sea_states"]["1-2"]["EM-MOGCPF"]) == {"rmse", "step_ms", "anees"}
    assert len(list(tmp_path.glob("*.png"))) == 9


@pytest.mark.parametrize("experiment", ["cn", "tan", "remus"])
def test_reproduce_of_missing_experiments_says_so(experiment, capsys):
    args = argparse.Namespace(experiment=experiment, runs=None, seed=0, particles=None, out=None, json=False)
    assert reproduce.main(args) == 2
    assert "not implemented yet" in capsys.readouterr().err


def test_paper_table_is_quoted_not_computed():
    paper = reproduce.paper_rov_rmse()
    assert paper["3"]["EM-MOGCPF"]["psi"] == 2.1357 and paper["0"]["PF"]["x"] == 1.8577
