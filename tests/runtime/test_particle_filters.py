"""Particle filters on generated C: convergence to the Kalman filter, stability, outliers, seeds."""
import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime.filters import mixture as mix, particle as pf
from abyssal.runtime.noise.mixtures import GaussianMixture
from abyssal.runtime.resampling import ResamplingPolicy
from abyssal.runtime.experiments.rov.scenario import SEA_STATES, RovScenario, make_filter, run_filter, simulate

DT = 0.5


@pytest.fixture(scope="module")
def linear():
    if "linear_cv" not in abyssal.generated.available():
        pytest.skip("linear_cv model not generated in this checkout")
    return abyssal.generated.load("linear_cv")


def _linear_problem(rng, steps=25):
    """Truth and measurements of the constant-velocity model, with its exact A, B, Q, R."""
    A = np.block([[np.eye(2), DT * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
    B = np.vstack([DT**2 / 2 * np.eye(2), DT * np.eye(2)])
    Q = np.diag([0.02, 0.02, 0.05, 0.05])
    R = np.diag([0.5, 0.8])
    x0, P0 = np.array([0.0, 0.0, 1.0, -0.5]), np.diag([1.0, 1.0, 0.2, 0.2])
    x = x0 + np.linalg.cholesky(P0) @ rng.standard_normal(4)
    us, zs = [], []
    for k in range(steps):
        u = np.array([0.2 * np.sin(0.3 * k), 0.1])
        x = A @ x + B @ u + np.linalg.cholesky(Q) @ rng.standard_normal(2 * 2)
        us.append(u)
        zs.append(x[:2] + np.linalg.cholesky(R) @ rng.standard_normal(2))
    return A, B, Q, R, x0, P0, np.array(us), np.array(zs)


def _kalman(A, B, Q, R, x0, P0, us, zs):
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    x, P = x0.copy(), P0.copy()
    for u, z in zip(us, zs):
        x, P = A @ x + B @ u, A @ P @ A.T + Q
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        x, P = x + K @ (z - H @ x), P - K @ S @ K.T
    return x, P


def _run(filt, us, zs):
    for u, z in zip(us, zs):
        filt.step(u, DT, z)
    return filt.x, filt.P


def test_pf_converges_to_kalman_filter_as_n_grows(linear):
    A, B, Q, R, x0, P0, us, zs = _linear_problem(np.random.default_rng(0))
    x_kf, P_kf = _kalman(A, B, Q, R, x0, P0, us, zs)
    noise_q, noise_r = GaussianMixture.gaussian(np.zeros(4), Q), GaussianMixture.gaussian(np.zeros(2), R)
    errors = {}
    for n in (100, 10_000):
        errs = []
        for seed in range(4):
            filt = pf.ParticleFilter(linear, x0, P0, noise_q, noise_r, n, np.random.default_rng(seed))
            x, _ = _run(filt, us, zs)
            errs.append(np.linalg.norm(np.linalg.solve(np.linalg.cholesky(P_kf), x - x_kf)))
        errors[n] = np.mean(errs)
    assert errors[10_000] < errors[100]
    assert errors[10_000] < 0.1  # within a tenth of the KF's standard deviation


def test_cubature_and_mixture_filters_match_kalman_filter_on_a_linear_model(linear):
    A, B, Q, R, x0, P0, us, zs = _linear_problem(np.random.default_rng(1))
    x_kf, P_kf = _kalman(A, B, Q, R, x0, P0, us, zs)
    noise_q, noise_r = GaussianMixture.gaussian(np.zeros(4), Q), GaussianMixture.gaussian(np.zeros(2), R)
    gs = _run(mix.GaussianSumCKF(linear, x0, P0, noise_q, noise_r, n_components=1), us, zs)
    assert np.allclose(gs[0], x_kf, atol=1e-9) and np.allclose(gs[1], P_kf, atol=1e-9)
    L = np.linalg.cholesky(P_kf)
    # CPF's carried proposal N(x^i_k|k, P^i_k|k) is much wider than p(x_k|x_k-1) here, so its weights
    # degenerate (ESS ~ 1 per step): it stays consistent but needs a looser bound at this N.
    cpf = _run(pf.CubatureParticleFilter(linear, x0, P0, noise_q, noise_r, 2000, np.random.default_rng(2)), us, zs)
    assert np.linalg.norm(np.linalg.solve(L, cpf[0] - x_kf)) < 2.0
    # the locally optimal proposal is exact for this linear model: the weights are the predictive likelihoods
    opt = _run(pf.CubatureParticleFilter(linear, x0, P0, noise_q, noise_r, 2000, np.random.default_rng(2),
                                         proposal="optimal"), us, zs)
    assert np.linalg.norm(np.linalg.solve(L, opt[0] - x_kf)) < 0.5
    for filt in (mix.EMMixtureCubatureParticleFilter(linear, x0, P0, noise_q, noise_r, 2000, np.random.default_rng(3),
                                                    n_components=1),
                 mix.MixtureCubatureParticleFilter(linear, x0, P0, noise_q, noise_r, 2000, np.random.default_rng(4),
                                                  n_components=1)):
        x, _ = _run(filt, us, zs)
        assert np.linalg.norm(np.linalg.solve(L, x - x_kf)) < 0.5, filt.name


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


def test_every_filter_stays_finite_over_ten_thousand_steps(rov):
    # a slow climb keeps the catenary shallow over 1000 s; sea state 3 is the hardest noise
    scenario = RovScenario(duration=1000.0, climb_speed=0.05)
    sea = SEA_STATES["3"]
    truth = simulate(rov, scenario, sea, np.random.default_rng(5))
    assert truth.states.shape[0] == 10_000
    raw = np.sqrt(np.mean((truth.measurements[:, :3] - truth.states[:, :3]) ** 2, axis=0))  # x y z of the sensor
    for i, name in enumerate(("PF", "CKF", "CPF", "CPF-optimal", "MOGCPF", "EM-MOGCPF", "GS-CKF")):
        filt = make_filter(name, rov, scenario, sea, 24, np.random.default_rng(i))
        result = run_filter(filt, truth, scenario.dt)
        assert np.all(np.isfinite(result.estimates)), name
        assert np.all(np.isfinite(result.covariances)), name
        rmse = np.sqrt(np.mean((result.estimates[:, :3] - truth.states[:, :3]) ** 2, axis=0))
        if name == "CPF":  # the carried-P^i proposal degenerates (ESS ~ 1, see below): finite, not accurate
            continue
        # filtering must beat the raw position fixes it is given (measured here: 0.2-0.7 of them at N = 24)
        assert np.all(rmse < 0.9 * raw), (name, rmse, raw)


@pytest.mark.parametrize("name", ["PF", "CPF", "CPF-optimal", "MOGCPF", "EM-MOGCPF", "GS-CKF", "CKF"])
def test_outlier_beyond_every_particle_recovers_without_nan(rov, name):
    scenario = RovScenario(duration=30.0)
    sea = SEA_STATES["0"]
    truth = simulate(rov, scenario, sea, np.random.default_rng(8))
    final_errors = []
    # the paper's CKF runs ungated and takes a 1e6 m fix as it comes; the recovery asked of it is its gate's (the
    # labelled gated variant, the runtime's default gate)
    options = {"gate_probability": 1e-10} if name == "CKF" else {}
    for outlier in (False, True):
        filt = make_filter(name, rov, scenario, sea, 100, np.random.default_rng(9), **options)
        for k in range(truth.states.shape[0]):
            z = truth.measurements[k]
            if outlier and k == 100:
                z = z + np.array([1e6, -1e6, 1e6, 0.0])  # every likelihood underflows to zero
            filt.step(truth.inputs[k], scenario.dt, z)
            assert np.all(np.isfinite(filt.x)) and np.all(np.isfinite(filt.P)), (name, k)
        final_errors.append(np.sqrt(np.mean((filt.x[:3] - truth.states[-1, :3]) ** 2)))
    # recovered: within half again (+ 0.1 m) of the untouched run 20 s later (measured: 0.39-1.21 m both ways)
    assert final_errors[1] < 1.5 * final_errors[0] + 0.1, (name, final_errors)


@pytest.mark.parametrize("name", ["PF", "CPF", "CPF-optimal", "MOGCPF", "EM-MOGCPF"])
def test_run_is_reproducible_from_its_seed(rov, name):
    scenario = RovScenario(duration=5.0)
    sea = SEA_STATES["1-2"]
    truth = simulate(rov, scenario, sea, np.random.default_rng(4))
    runs = [run_filter(make_filter(name, rov, scenario, sea, 60, np.random.default_rng(17)), truth, scenario.dt)
            for _ in range(2)]
    assert np.array_equal(runs[0].estimates, runs[1].estimates)
    other = run_filter(make_filter(name, rov, scenario, sea, 60, np.random.default_rng(18)), truth, scenario.dt)
    assert not np.array_equal(runs[0].estimates, other.estimates)


def test_resampling_every_step_keeps_uniform_weights(rov):
    scenario = RovScenario(duration=2.0)
    sea = SEA_STATES["0"]
    truth = simulate(rov, scenario, sea, np.random.default_rng(1))
    Q, R = scenario.process_covariance(rov), sea.measurement_noise()
    filt = pf.ParticleFilter(rov, np.zeros(12), scenario.P0, Q, R, 50, np.random.default_rng(2),
                             policy=ResamplingPolicy("residual", threshold=1.0))
    for k in range(truth.states.shape[0]):
        filt.step(truth.inputs[k], scenario.dt, truth.measurements[k])
        assert np.allclose(filt.log_weights, -np.log(50))


@pytest.mark.parametrize("sea_name", list(SEA_STATES))
def test_locally_optimal_cpf_keeps_its_particles_in_every_sea_state(rov, sea_name):
    # the carried-P^i CPF collapses (ESS ~ 1); the locally optimal proposal must keep ESS > N/10
    scenario = RovScenario(duration=20.0)  # the default (plain) reading: Q singular on the pose
    sea = SEA_STATES[sea_name]
    truth = simulate(rov, scenario, sea, np.random.default_rng(3))
    result = run_filter(make_filter("CPF-optimal", rov, scenario, sea, 100, np.random.default_rng(4)), truth, scenario.dt)
    assert np.mean(result.ess) > 100 / 10
    assert np.all(np.isfinite(result.estimates))


def test_singular_process_noise_moves_particles_only_on_its_subspace(linear):
    # Q zero on the positions: p(x_k | x_k-1) is degenerate there, and the position of every particle must be
    # exactly f(x_k-1) (no floor, no leak), for the bootstrap and both cubature proposals
    Q = np.diag([0.0, 0.0, 0.05, 0.05])
    noise_r = GaussianMixture.gaussian(np.zeros(2), np.diag([0.5, 0.8]))
    never = ResamplingPolicy(threshold=0.0)
    for make in (lambda: pf.ParticleFilter(linear, np.zeros(4), np.eye(4), Q, noise_r, 50, 1, policy=never),
                 lambda: pf.CubatureParticleFilter(linear, np.zeros(4), np.eye(4), Q, noise_r, 50, 1, policy=never),
                 lambda: pf.CubatureParticleFilter(linear, np.zeros(4), np.eye(4), Q, noise_r, 50, 1, policy=never,
                                                   proposal="optimal")):
        filt = make()
        before = filt.particles.copy()
        expected = linear.f_batch(before, np.array([0.1, 0.2]), None, DT)
        filt.step(np.array([0.1, 0.2]), DT, np.array([0.3, -0.2]))
        assert filt.resamples == 0
        np.testing.assert_allclose(filt.particles[:2], expected[:2], rtol=0, atol=1e-12)
        assert not np.allclose(filt.particles[2:], expected[2:])  # the velocities did get noise
        assert np.isfinite(filt.ess) and filt.ess > 1


def test_dt_beyond_the_stable_range_is_subdivided_or_refused(rov):
    # one RK4 step of 5 s from these particles overflows; step doubling finds the substeps, and 50 s is refused
    R = GaussianMixture.gaussian(np.zeros(4), np.diag([0.3, 0.2, 0.3, 0.05]))
    Q = np.diag([0, 0, 0, 0, 3, 4, 5, 0.02, 2, 2, 2, 0.5])
    for filt in (pf.ParticleFilter(rov, np.zeros(12), 0.3 * np.eye(12), Q, R, 100, 1),
                 pf.CubatureParticleFilter(rov, np.zeros(12), 0.3 * np.eye(12), Q, R, 100, 1, proposal="optimal")):
        filt.step(np.zeros(4), 5.0, np.zeros(4))
        assert filt.pieces(np.zeros(4), 5.0) > 1 and np.abs(filt.x).max() < 100
        x = filt.x
        with pytest.raises(ValueError, match="dt = 50.0 s is beyond"):
            filt.step(np.zeros(4), 50.0, np.zeros(4))
        np.testing.assert_array_equal(filt.x, x)
    carried = pf.CubatureParticleFilter(rov, np.zeros(12), 0.3 * np.eye(12), Q, R, 100, 1)
    with pytest.raises(ValueError, match="cannot be subdivided"):
        carried.step(np.zeros(4), 5.0, np.zeros(4))


@pytest.mark.parametrize("refused", ["dt beyond the stable range", "overflowing input", "NaN input"])
def test_refused_cpf_predict_leaves_the_next_step_bit_identical(rov, refused):
    """The carried-P^i CPF: a predict refused after its generated cubature step ran (an overflow, whose failed
    guard repairs the carried covariances in place) or before it leaves particles, weights, carried
    covariances and the generator as an untouched twin's, and the following steps bit-identical."""
    R = GaussianMixture.gaussian(np.zeros(4), np.diag([0.3, 0.2, 0.3, 0.05]))
    Q = np.diag([1e-3] * 8 + [1e-2] * 4)
    u, z = np.array([20.0, 5.0, 10.0, 0.5]), np.array([0.1, -0.1, 0.2, 0.05])
    bad_u, bad_dt = {"dt beyond the stable range": (u, 5.0), "overflowing input": (np.full(4, 1e308), 0.1),
                     "NaN input": (np.array([np.nan, 0, 0, 0]), 0.1)}[refused]
    filt, twin = (pf.CubatureParticleFilter(rov, np.zeros(12), 0.3 * np.eye(12), Q, R, 50, 3) for _ in range(2))
    for f in (filt, twin):
        f.step(u, 0.1, z)
    with pytest.raises(ValueError):
        filt.predict(bad_u, bad_dt)
    for f in (filt, twin):
        f.step(u, 0.1, z)
        f.predict(u, 0.1)
        f.step(u, 0.1, z)
    for a, b in zip(filt.checkpoint().values(), twin.checkpoint().values()):
        assert repr(a) == repr(b) if isinstance(a, dict) else np.array_equal(np.asarray(a), np.asarray(b))


def test_the_papers_underflow_and_estimate_rules_are_options_beside_the_engines(linear):
    """underflow="normalise" normalises an update whose likelihood underflows at every particle (the weight goes to
    the particles nearest the measurement, ESS ~ 1) where the default keeps the weights (ESS stays N); estimate="after"
    reports the moments of the resampled particles, the default the weighted moments before resampling."""
    Q = np.diag([0.02, 0.02, 0.05, 0.05])
    R = GaussianMixture.gaussian(np.zeros(2), np.diag([0.5, 0.8]))
    x0, P0 = np.zeros(4), np.eye(4)

    def make(**rules):
        return pf.ParticleFilter(linear, x0, P0, Q, R, 400, 3, policy=ResamplingPolicy("multinomial", 1.0),
                                 gate_probability=0.0, **rules)

    far = np.array([1e3, -1e3])  # ~1400 sigma of R from every particle: every likelihood underflows
    kept, normalised = make(), make(underflow="normalise")
    for filt in (kept, normalised):
        filt.step(np.zeros(2), DT, far)
        assert filt.uninformative == 1
    assert kept.ess == pytest.approx(400.0)
    assert normalised.ess < 2.0
    # the normalised estimate jumps to the particle nearest the measurement; the kept one stays near the prior
    assert np.linalg.norm(normalised.x[:2]) > np.linalg.norm(kept.x[:2]) + 1.0

    before, after = make(), make(estimate="after")
    z = np.array([0.8, -0.4])
    for filt in (before, after):
        filt.step(np.zeros(2), DT, z)
    np.testing.assert_allclose(after.x, after.particles.mean(axis=1), rtol=0, atol=1e-12)  # the resampled cloud
    assert not np.allclose(before.x, before.particles.mean(axis=1), rtol=0, atol=1e-6)  # the weighted cloud
    with pytest.raises(ValueError, match="underflow must be one of"):
        make(underflow="ignore")
