"""Reliability of every SIR filter of the one engine (PF, CPF carried and locally optimal, UPF, HRUPF, MCUPF):
a refusal leaves the filter bit-identical and its next steps equal to an untouched twin's; the innovation gate;
re-acquiring a permanent jump; finite in, finite out; KLD-resampling far from the origin; a variable particle
number; and the merged UPF against an independent NumPy UPF given the same draws."""
from __future__ import annotations

import math

import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime.experiments.cn import scenario
from abyssal.runtime.filters.particle import CubatureParticleFilter, ParticleFilter, UnscentedParticleFilter
from abyssal.runtime.noise.mixtures import GaussianMixture
from abyssal.runtime.resampling import KLDResampling, ResamplingPolicy, kld_resample

DT = 0.5
SIR_FILTERS = ("PF", "CPF", "CPF-optimal", "UPF", "HRUPF", "MCUPF")


@pytest.fixture(scope="module")
def linear():
    return abyssal.generated.load("linear_cv")


def make(name, model, *, n=40, rng=3, x0=None, P0=None, Q=None, R=None, **options):
    """The SIR filter `name` on `model` (Q, R: covariance matrices)."""
    nx, ny = model.n_x, model.n_y
    x0 = np.zeros(nx) if x0 is None else x0
    P0 = np.eye(nx) if P0 is None else P0
    Q = 0.05 * np.eye(nx) if Q is None else Q
    R = 0.5 * np.eye(ny) if R is None else R
    noise = GaussianMixture.gaussian(np.zeros(ny), R)
    if name == "PF":
        return ParticleFilter(model, x0, P0, Q, noise, n, rng, **options)
    if name in ("CPF", "CPF-optimal"):
        return CubatureParticleFilter(model, x0, P0, Q, noise, n, rng, proposal="optimal" if name == "CPF-optimal" else "carried",
                                      **options)
    update = {"UPF": "ukf", "HRUPF": "huber", "MCUPF": "mcc"}[name]
    if name == "MCUPF":
        options.setdefault("resampling", KLDResampling(bin_size=(0.5, 0.5), n_min=10, n_max=3 * n))
    return UnscentedParticleFilter(model, x0, P0, Q, R, n, rng, update=update, **options)


def nominal(model, k):
    u = np.array([0.3 * math.sin(0.3 * k), 0.1, 0.4])[: model.n_u]
    z = np.array([0.1 * k, -0.05 * k])[: model.n_y]
    return u, z


def assert_same(a, b, path="state"):
    """Two checkpoints (nested dicts of arrays, numbers, generator states, tuples) are bit-identical."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            assert_same(a[key], b[key], f"{path}.{key}")
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        assert np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True), path
    else:
        assert a == b or (a != a and b != b), path


def run_nominal(filt, model, ks):
    for k in ks:
        u, z = nominal(model, k)
        filt.step(u, DT, z)
        if k % 3 == 0:
            filt.predict(u, DT)


def refusals(model):
    """(name, call) of calls every SIR filter must refuse; the last ones ran before the fix with P = inf
    accepted, or left the filter refusing every later step."""
    u, z = nominal(model, 2)
    n_u, n_p = model.n_u, model.n_p
    return {
        "inf z": lambda f: f.step(u, DT, np.full_like(z, np.inf)),
        "NaN u": lambda f: f.step(np.full(n_u, np.nan), DT, z),
        "NaN p": lambda f: f.step(u, DT, z, np.full(n_p, np.nan)),
        "overflowing u, predict": lambda f: f.predict(np.full(n_u, 1e308), DT),
        "overflowing u, step": lambda f: f.step(np.full(n_u, 1e308), DT, z),
        "absurd finite u (P = inf)": lambda f: f.step(np.full(n_u, 1e200), DT, z),
        "absurd dt": lambda f: f.step(u, 1e300, z),
    }


# ---------------------------------------------------------------------------------------------
# a refusal leaves the filter bit-identical, its next steps equal to an untouched twin's


@pytest.mark.parametrize("model_name", ["linear_cv", "cn2d"])
@pytest.mark.parametrize("name", SIR_FILTERS)
def test_every_refusal_leaves_the_filter_bit_identical_and_the_next_steps_equal_a_twins(model_name, name):
    model = abyssal.generated.load(model_name)
    for label, call in refusals(model).items():
        filt, twin = make(name, model), make(name, model)
        run_nominal(filt, model, range(2))
        run_nominal(twin, model, range(2))
        before = filt.checkpoint()
        reported = (filt.x, filt.P, filt.ess, filt.n_particles)
        with pytest.raises(ValueError):
            call(filt)
        assert_same(before, filt.checkpoint(), f"{name} {label}")
        assert_same(reported, (filt.x, filt.P, filt.ess, filt.n_particles), f"{name} {label} reports")
        run_nominal(filt, model, range(2, 6))
        run_nominal(twin, model, range(2, 6))
        assert_same(filt.checkpoint(), twin.checkpoint(), f"{name} after {label}")


@pytest.mark.parametrize("name", SIR_FILTERS)
def test_finite_in_finite_out_and_never_stuck(name, cn):
    """Absurd but finite inputs are refused, or accepted with a finite estimate, covariance, particles and weights;
    either way the next nominal steps are accepted; numerical errors never escape as FloatingPointError or
    OverflowError (numpy set to raise on every floating-point error)."""
    n_u, n_y, n_p = cn.n_u, cn.n_y, cn.n_p
    calls = {"u = 1e200": lambda f: f.step(np.full(n_u, 1e200), DT, np.zeros(n_y)),
             "predict u = 1e308": lambda f: f.predict(np.full(n_u, 1e308), DT),
             "p = 1e300": lambda f: f.step(np.zeros(n_u), DT, np.zeros(n_y), np.full(n_p, 1e300)),
             "z = 1e300": lambda f: f.step(np.zeros(n_u), DT, np.full(n_y, 1e300)),
             "heading 1e300": lambda f: f.step(np.array([1.0, 0.0, 1e300]), DT, np.zeros(n_y)),
             "z = 1e6": lambda f: f.step(np.zeros(n_u), DT, np.full(n_y, 1e6))}
    for raising in (False, True):
        for label, call in calls.items():
            filt = make(name, cn)
            run_nominal(filt, cn, range(2))
            with np.errstate(all="raise" if raising else "warn"):
                try:
                    call(filt)
                except ValueError:
                    pass
                for value in (filt.x, filt.P, filt.particles, np.exp(filt.log_weights)):
                    assert np.all(np.isfinite(value)), (name, label)
                run_nominal(filt, cn, range(2, 7))  # accepted: not stuck
    with pytest.raises(ValueError, match="x0"):
        make(name, cn, x0=np.full(2, 1e300))


# ---------------------------------------------------------------------------------------------
# the innovation gate


@pytest.mark.parametrize("name", SIR_FILTERS)
def test_an_outlier_entry_is_gated_and_the_step_equals_one_without_it(name, linear):
    """One entry far outside the cloud is left out of proposal and weights: the filter ends bit-identical to a twin
    that got that entry as missing (NaN), apart from the gate's count. Before the gate, a +1e6 m range moved the plain
    UPF by 6.2e5 m. The MCUPF's correntropy update discounts the entry itself (its S holds R~ = R / C, so the gate
    passes it) and the likelihood underflows: its estimate stays with the twin's within 10 cm (its draws differ)."""
    for outlier in (1e6, 1e300):
        filt, twin = make(name, linear), make(name, linear)
        run_nominal(filt, linear, range(3))
        run_nominal(twin, linear, range(3))
        u, z = nominal(linear, 3)
        bad, missing = z.copy(), z.copy()
        bad[0] += outlier
        missing[0] = np.nan
        filt.step(u, DT, bad)
        twin.step(u, DT, missing)
        if name == "MCUPF" and outlier == 1e6:
            assert np.linalg.norm(filt.x - twin.x) < 0.1
            continue
        assert filt.gated == 1
        a, b = filt.checkpoint(), twin.checkpoint()
        a.pop("gate"), b.pop("gate")
        assert_same(a, b, f"{name} outlier {outlier:g}")


def test_gate_off_uses_every_entry(linear):
    filt = make("UPF", linear, gate_probability=0.0)
    run_nominal(filt, linear, range(3))
    u, z = nominal(linear, 3)
    x = filt.x
    filt.step(u, DT, z + np.array([1e3, 0.0]))
    assert filt.gated == 0 and np.linalg.norm(filt.x - x) > 100  # the UKF update followed it
    with pytest.raises(ValueError, match="gate_probability"):
        make("PF", linear, gate_probability=1.5)


def _jump_truth(model, rng, steps=120, at=40, jump=(40.0, -25.0)):
    """linear_cv truth whose position jumps by `jump` (47 m, 56 standard deviations of R) at step `at` and stays."""
    Q, R = np.diag([0.02, 0.02, 0.05, 0.05]), np.diag([0.5, 0.8])
    x = np.array([0.0, 0.0, 1.0, -0.5])
    xs, us, zs = [], [], []
    for k in range(steps):
        u = np.array([0.2 * math.sin(0.3 * k), 0.1])
        x = model.f(x, u, None, DT) + np.linalg.cholesky(Q) @ rng.standard_normal(4)
        if k == at:
            x[:2] += jump
        xs.append(x.copy())
        us.append(u)
        zs.append(x[:2] + np.linalg.cholesky(R) @ rng.standard_normal(2))
    return np.array(xs), np.array(us), np.array(zs), Q, R


def _steps_to_return(name, model, seed, n, **options):
    """Steps after the jump until the position error is back within 3x its pre-jump mean + 0.5 m (None: never)."""
    xs, us, zs, Q, R = _jump_truth(model, np.random.default_rng(seed))
    filt = make(name, model, n=n, rng=1, x0=np.array([0.0, 0.0, 1.0, -0.5]), P0=np.diag([1.0, 1.0, 0.2, 0.2]), Q=Q, R=R,
                **options)
    errors = []
    for u, z, x in zip(us, zs, xs):
        filt.step(u, DT, z)
        errors.append(np.linalg.norm(filt.x[:2] - x[:2]))
    errors = np.array(errors)
    back = np.flatnonzero(errors[41:] < 3 * errors[20:40].mean() + 0.5)
    return int(back[0]) + 1 if back.size else None


def test_a_permanent_jump_is_reacquired(linear):
    """A jump the cloud cannot follow is gated, and after gate_patience gatings re-acquired: the PF by widening its
    cloud along the gated entries, the proposals that use z by admitting them (module docstring of engine.py).
    Without the widening (gate_inflation = 1) the PF stays gated, and using the entry (gate off) does not bring it
    back either: its likelihood underflows at every particle, so the weights stay as they were."""
    seeds = range(6)
    # the PF over 30 seeds (its compiled step draws its own stream: rates, not the outcome of given seeds; the
    # NumPy engine and the compiled step both came back in 29 of 30 runs, 12 of 30 without the widening, 17 of 30
    # with the gate off)
    back = {label: [_steps_to_return("PF", linear, s, 500, **options) for s in range(30)]
            for label, options in (("default", {}), ("no widening", {"gate_inflation": 1.0}),
                                   ("gate off", {"gate_probability": 0.0}))}
    assert sum(b is not None and b <= 80 for b in back["default"]) >= 27, back
    assert sum(b is not None for b in back["no widening"]) <= 15, back
    assert sum(b is not None for b in back["gate off"]) <= 20, back
    for name, limit in (("CPF", 10), ("UPF", 10), ("HRUPF", 40), ("CPF-optimal", 75)):
        steps = [_steps_to_return(name, linear, s, 200) for s in seeds[:3]]
        assert all(b is not None and b <= limit for b in steps), (name, steps)


# ---------------------------------------------------------------------------------------------
# KLD-resampling and a variable particle number


def test_kld_bins_are_relative_to_the_cloud():
    """The same cloud shifted by 1e7 m (a multiple of the bin width) gets the same ancestors from the same draws;
    before, its bin index was counted from the origin and every step was refused."""
    rng = np.random.default_rng(5)
    X = rng.normal(0.0, 0.3, (2, 400))
    w = rng.random(400)
    w /= w.sum()
    params = KLDResampling(bin_size=(0.01, 0.01), n_min=10, n_max=800)
    near = kld_resample(w, X, np.random.default_rng(1), params)
    far = kld_resample(w, X + 1e7, np.random.default_rng(1), params)
    np.testing.assert_array_equal(near, far)
    wide = kld_resample(w, X * 1e12, np.random.default_rng(1), params)  # spans more than 2^21 bins
    assert 10 <= wide.size <= 800


def test_mcupf_far_from_the_origin_is_never_refused(cn):
    trial = scenario.simulate(scenario.CnScenario(), "gaussian", np.random.default_rng(11))
    shift = np.array([1e7, -1e7])
    params = trial.params[:30] + np.tile(shift, 2)  # both leader sensors' positions
    filt = UnscentedParticleFilter(cn, trial.x0 + shift, trial.P0, np.diag([100.0, 100.0]), np.eye(2) * 0.1, 500, 2,
                                   update="mcc", resampling=KLDResampling(bin_size=(0.01, 0.01), n_min=20, n_max=500))
    result = filt.run(trial.U[:30], trial.Z[:30], trial.dt, params=params)  # all-or-nothing: no step refused
    assert np.all((result.particles[1:] >= 20) & (result.particles[1:] <= 500))
    assert np.mean(np.linalg.norm(result.x - shift - trial.truth[:30], axis=1)) < 100


def test_variable_particle_number_keeps_the_transaction(linear):
    """A bootstrap PF with KLD-resampling: N changes every step inside a fixed capacity; a checkpoint taken at one N
    restores at another; a refusal after N changed leaves it bit-identical."""
    filt = make("PF", linear, n=300, policy=KLDResampling(bin_size=(1.0, 1.0), n_min=20, n_max=400))
    assert filt.capacity == 400
    counts = set()
    saved = filt.checkpoint()
    for k in range(8):
        u, z = nominal(linear, k)
        filt.step(u, DT, z)
        counts.add(filt.N)
        assert filt.particles.shape == (4, filt.N) and filt.weights.shape[0] == filt.n_particles
    assert len(counts) > 1 and max(counts) <= 400
    later = filt.checkpoint()
    with pytest.raises(ValueError):
        filt.step(np.full(2, 1e200), DT, z)
    assert_same(later, filt.checkpoint())
    filt.restore(saved)
    assert filt.N == 300
    assert_same(saved, filt.checkpoint())


def test_singular_process_noise_for_the_unscented_family(cn):
    """Q with no noise on x: every particle's x is exactly f(x_prev) (no floor, no leak), for the UPF family too
    (the old UPF refused a singular Q)."""
    never = ResamplingPolicy(threshold=0.0)
    trial = scenario.simulate(scenario.CnScenario(), "gaussian", np.random.default_rng(11))
    for update in ("ukf", "huber", "mcc"):
        filt = UnscentedParticleFilter(cn, trial.x0, trial.P0, np.diag([0.0, 100.0]), np.eye(2) * 0.1, 100, 1,
                                       update=update, resampling=never)
        before = filt.particles.copy()
        expected = cn.f_batch(before, trial.U[0], trial.params[0], trial.dt)
        filt.step(trial.U[0], trial.dt, trial.Z[0], trial.params[0])
        np.testing.assert_allclose(filt.particles[0], expected[0], rtol=0, atol=1e-9)
        assert not np.allclose(filt.particles[1], expected[1])
        assert np.isfinite(filt.ess) and filt.ess > 1


# ---------------------------------------------------------------------------------------------
# the merged UPF against an independent NumPy UPF


def _cholesky2(P):
    """Lower Cholesky factors of (N, 2, 2) covariances."""
    return np.linalg.cholesky(P)


def _sigma_points(x, P):
    """The scaled unscented points of lambda = 3 - n = 1 (n = 2): x, x +- sqrt(3) L_i; weights 1/3, 1/6 x 4."""
    L = _cholesky2(P) * math.sqrt(3.0)
    X = np.stack([x, x + L[:, :, 0], x + L[:, :, 1], x - L[:, :, 0], x - L[:, :, 1]], axis=1)  # (N, 5, 2)
    return X, np.array([1 / 3, 1 / 6, 1 / 6, 1 / 6, 1 / 6])


def _numpy_upf(x0, P0, Q, R, U, Z, params, dt, N, rng, sigma=None):
    """Van der Merwe's UPF on cn2d written out in NumPy, with the draws taken from rng in the engine's order
    (initial cloud; per step the proposal's standard normals, then the multinomial uniforms). sigma: the MCC update
    (R~ = R / C, C = exp(-min(nu^2 / (2 R sigma^2), 50))) instead of the UKF's."""
    values, vectors = np.linalg.eigh(P0)
    x = (x0[:, None] + (vectors * np.sqrt(values)) @ rng.standard_normal((2, N))).T  # (N, 2)
    P = np.repeat(P0[None], N, axis=0)
    log_w = np.full(N, -math.log(N))
    q_std, R = np.sqrt(np.diag(Q)), float(R[0, 0])
    estimates = []
    for u, z, p in zip(U, Z, params):
        c, s, theta = u
        velocity = np.array([c * math.cos(theta) + s * math.sin(theta), c * math.sin(theta) - s * math.cos(theta)])
        f = x + dt * velocity
        X, wts = _sigma_points(x, P)
        Xf = X + dt * velocity
        m = np.einsum("k,nki->ni", wts, Xf)
        D = Xf - m[:, None]
        P_pred = np.einsum("k,nki,nkj->nij", wts, D, D) + Q
        if np.isnan(z[0]):
            new = f + (q_std[:, None] * rng.standard_normal((2, N))).T
            P = P_pred
        else:
            X, wts = _sigma_points(m, P_pred)
            ranges = np.linalg.norm(X - p, axis=2)  # (N, 5)
            zp = ranges @ wts
            dz = ranges - zp[:, None]
            Pzz = np.einsum("k,nk,nk->n", wts, dz, dz)
            Pxz = np.einsum("k,nki,nk->ni", wts, X - m[:, None], dz)
            nu = z[0] - zp
            R_used = np.full(N, R) if sigma is None else R / np.exp(-np.minimum(nu**2 / (2 * R * sigma**2), 50.0))
            S = Pzz + R_used
            K = Pxz / S[:, None]
            mean = m + K * nu[:, None]
            P_post = P_pred - np.einsum("ni,nj->nij", K, K) * S[:, None, None]
            L = _cholesky2(P_post)
            xi = rng.standard_normal((2, N))
            new = mean + np.einsum("nij,jn->ni", L, xi)
            log_prior = -0.5 * np.sum(((new - f) / q_std) ** 2, axis=1) - np.log(q_std).sum() - math.log(2 * math.pi)
            r = z[0] - np.linalg.norm(new - p, axis=1)
            log_lik = -0.5 * r**2 / R - 0.5 * math.log(2 * math.pi * R)
            log_q = (-0.5 * np.sum(xi**2, axis=0) - np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
                     - math.log(2 * math.pi))
            log_w = log_w + log_prior + log_lik - log_q
            P = P_post
        w = np.exp(log_w - log_w.max())
        w /= w.sum()
        estimates.append(w @ new)
        cdf = np.cumsum(w)
        ancestors = np.searchsorted(cdf / cdf[-1], np.sort(rng.random(N)), side="right")
        x, P, log_w = new[ancestors], P[ancestors], np.full(N, -math.log(N))
    return np.array(estimates)


@pytest.mark.parametrize("update,sigma", [("ukf", None), ("mcc", 15.0)])
def test_merged_upf_equals_an_independent_numpy_upf_given_the_same_draws(cn, update, sigma):
    trial = scenario.simulate(scenario.CnScenario(), "eps0.1", np.random.default_rng(11))
    T, N = 25, 200
    Z = trial.Z[:T].copy()
    Z[[4, 11]] = np.nan  # steps without a range: the transition and P^j's prediction
    ranges = trial.ranges[:T, None].copy()  # the reference: the ping's one range to the pinging leader's broadcast
    ranges[[4, 11]] = np.nan
    Q, R = np.diag([100.0, 100.0]), np.eye(2) * 0.1  # each leader sensor's R
    filt = UnscentedParticleFilter(cn, trial.x0, trial.P0, Q, R, N, np.random.default_rng(8), update=update,
                                   **({} if sigma is None else {"sigma": sigma}))
    got = filt.run(trial.U[:T], Z, trial.dt, params=trial.params[:T]).x
    want = _numpy_upf(trial.x0, trial.P0, Q, R[:1, :1], trial.U[:T], ranges, trial.gps[:T], trial.dt, N,
                      np.random.default_rng(8), sigma)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-7)
