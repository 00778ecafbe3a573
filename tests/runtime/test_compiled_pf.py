"""The SIR engine's compiled bootstrap step (filters/particle/compiled.py) against the engine's NumPy step given the
same draws: the same estimates, covariances, particles, weights, ESS, gate counts, widenings and resamplings, step
after step (predicts, updates alone, missing entries, a gated outlier, a jump that is re-acquired by widening,
an underflowing likelihood, angle outputs, mixture measurement noise, a singular Q)."""
from __future__ import annotations

import math

import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime.compiled import sir
from abyssal.runtime.filters.particle import ParticleFilter
from abyssal.runtime.filters.particle.compiled import CompiledBootstrap
from abyssal.runtime.noise.mixtures import GaussianMixture
from abyssal.runtime.resampling import KLDResampling, ResamplingPolicy

DT = 0.5


class PhiloxDraws:
    """The compiled step's draws of step `counter` (its process-noise normals and resampling uniforms), handed to
    the NumPy engine in place of its Generator's."""

    def __init__(self, key: int):
        self.key, self.counter = key, 0

    def noise(self, transition, count: int) -> np.ndarray:
        y = sir.normals(self.key, self.counter, transition.rank, count) * np.sqrt(transition.variances)[:, None]
        return transition.embed(y) + transition.mean[:, None]

    def uniforms(self, n: int) -> np.ndarray:
        return sir.uniforms(self.key, self.counter, sir.TAG_RESAMPLING, n)


class PhiloxPolicy:
    """A ResamplingPolicy whose systematic / stratified uniforms are the compiled step's."""

    def __init__(self, policy: ResamplingPolicy, draws: PhiloxDraws):
        self.policy, self.draws = policy, draws

    def due(self, ess, n):
        return self.policy.due(ess, n)

    def ancestors(self, weights, rng, states=None):
        n = weights.shape[0]
        u = self.draws.uniforms(1 if self.policy.scheme == "systematic" else n)
        cdf = np.cumsum(weights)
        return np.minimum(np.searchsorted(cdf / cdf[-1], (np.arange(n) + u) / n, side="right"), n - 1)


def pair(make, monkeypatch):
    """(the compiled filter, the NumPy engine's twin on the compiled filter's draws, the draws)."""
    compiled = make()
    assert compiled._compiled is not None
    with monkeypatch.context() as m:
        m.setattr(CompiledBootstrap, "fits", staticmethod(lambda engine: False))
        twin = make()
    assert twin._compiled is None and twin.streams is None
    draws = PhiloxDraws(int(compiled.streams[0]))
    twin.transition.sample = lambda rng, count: draws.noise(twin.transition, count)
    twin.policy = PhiloxPolicy(twin.policy, draws)
    return compiled, twin, draws


def assert_equal_filters(a, b, label):
    assert a.N == b.N and a.n_particles == b.n_particles, label
    for name in ("gated", "inflations", "resamples", "uninformative"):
        assert getattr(a, name) == getattr(b, name), (label, name)
    np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-9, err_msg=label)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-7, atol=1e-9, err_msg=label)
    np.testing.assert_allclose(a.particles, b.particles, rtol=1e-9, atol=1e-9, err_msg=label)
    np.testing.assert_allclose(a.weights, b.weights, rtol=1e-7, atol=1e-12, err_msg=label)
    np.testing.assert_allclose(a.log_weights, b.log_weights, rtol=1e-9, atol=1e-9, err_msg=label)
    assert math.isclose(a.ess, b.ess, rel_tol=1e-8), label


def drive(compiled, twin, draws, calls):
    """Run the same calls on both (each on the draws of the compiled filter's step counter), compare after each."""
    for k, (label, call) in enumerate(calls):
        draws.counter = int(compiled.streams[1])
        ra, rb = call(compiled), call(twin)
        assert ra == rb, (k, label)
        assert_equal_filters(compiled, twin, f"call {k}: {label}")


def linear_calls(jump_at=14):
    """Steps of linear_cv with its position measured: nominal, missing entries, a predict, an update alone, one
    outlier entry (gated), then a jump the cloud cannot follow (gated, then widened after the patience)."""
    calls = []
    x = np.array([0.0, 0.0, 1.0, -0.5])
    for k in range(24):
        u = np.array([0.2 * math.sin(0.3 * k), 0.1])
        x = x + DT * np.array([x[2], x[3], u[0], u[1]])
        z = x[:2] + (np.array([0.5, -0.3]) if k % 2 else np.array([-0.2, 0.4]))
        if k >= jump_at:
            z = z + np.array([40.0, -25.0])
        if k == 3:
            z[1] = np.nan
        if k == 6:
            z[0] += 1e4
        if k == 8:
            calls.append(("predict", lambda f, u=u: f.predict(u, DT)))
            calls.append(("update alone", lambda f, z=z.copy(): f.update(z)))
            continue
        calls.append((f"step {k}", lambda f, u=u, z=z.copy(): f.step(u, DT, z)))
    return calls


@pytest.mark.parametrize("scheme, threshold", [("systematic", 0.5), ("stratified", 0.5), ("systematic", 1.0),
                                               ("systematic", 0.0)])
def test_compiled_pf_equals_the_numpy_engine_given_the_same_draws(monkeypatch, scheme, threshold):
    model = abyssal.generated.load("linear_cv")
    Q = np.diag([0.02, 0.02, 0.05, 0.05])
    R = GaussianMixture.gaussian(np.zeros(2), np.diag([0.5, 0.8]))

    def make():
        return ParticleFilter(model, np.array([0.0, 0.0, 1.0, -0.5]), np.diag([1.0, 1.0, 0.2, 0.2]), Q, R, 700, 5,
                              policy=ResamplingPolicy(scheme, threshold), gate_patience=2)

    compiled, twin, draws = pair(make, monkeypatch)
    drive(compiled, twin, draws, linear_calls())
    assert compiled.gated >= 3 and compiled.inflations >= 1  # the outlier, and the jump: gated, then widened
    if threshold == 0.5:
        assert 0 < compiled.resamples < 25


def test_compiled_pf_equals_the_numpy_engine_on_rov4dof(monkeypatch):
    """Angle output (the heading's residual wrapped), a two-component measurement mixture, no process noise on the
    pose (a singular Q: the pose moves by f alone), and an underflowing likelihood with the gate off."""
    model = abyssal.generated.load("rov4dof")
    R = np.diag([0.05, 0.05, 0.02, 0.01])
    mixture = GaussianMixture(np.array([0.8, 0.2]), np.array([[0.0] * 4, [0.1, -0.1, 0.05, 0.0]]), np.stack([R, 9 * R]))
    Q = np.diag([0.0] * 4 + [1e-3] * 4 + [0.0] * 4)[:model.n_x, :model.n_x]
    x0 = np.zeros(model.n_x)
    x0[3] = 3.0  # heading near pi: residuals wrap
    rng = np.random.default_rng(3)
    calls = []
    for k in range(12):
        u = 0.3 * rng.standard_normal(model.n_u)
        z = rng.normal(0.0, 0.2, model.n_y)
        z[3] = -3.1 + 0.05 * k
        if k == 5:
            z[0] = 1e3  # every likelihood underflows (gate off): the weights stay
        calls.append((f"step {k}", lambda f, u=u, z=z: f.step(u, DT, z)))

    def make(gate_probability):
        return lambda: ParticleFilter(model, x0, 0.05 * np.eye(model.n_x), Q, mixture, 600, 9,
                                      gate_probability=gate_probability)

    for gate_probability in (1e-10, 0.0):
        compiled, twin, draws = pair(make(gate_probability), monkeypatch)
        drive(compiled, twin, draws, calls)
        assert compiled.uninformative == (1 if gate_probability == 0.0 else 0)
        assert compiled.gated == (0 if gate_probability == 0.0 else 1)


def test_philox_ancestors_are_the_c_steps(monkeypatch):
    """The resampling a step that may widen leaves to Python draws the ancestors the C step would have drawn."""
    model = abyssal.generated.load("linear_cv")
    Q = np.diag([0.02, 0.02, 0.05, 0.05])
    R = GaussianMixture.gaussian(np.zeros(2), np.diag([0.5, 0.8]))
    for scheme in ("systematic", "stratified"):
        a, b = (ParticleFilter(model, np.zeros(4), 4.0 * np.eye(4), Q, R, 1500, 2, policy=ResamplingPolicy(scheme, 1.0))
                for _ in range(2))
        monkeypatch.setattr(b._compiled, "scheme", sir.CALLER)  # b resamples in Python from the same uniforms
        for k in range(4):
            a.step(np.zeros(2), DT, np.array([0.3 * k, -0.1 * k]))
            b.step(np.zeros(2), DT, np.array([0.3 * k, -0.1 * k]))
            assert a.particles.tobytes() == b.particles.tobytes(), (scheme, k)
        assert a.resamples == b.resamples == 4


def test_kld_policy_runs_the_compiled_step_with_a_variable_particle_number():
    """KLD-resampling draws the ancestors in Python (the filter's rng) around the compiled step: N follows the
    occupied bins inside the capacity, and the filter finds a vehicle near rest from a wide start."""
    model = abyssal.generated.load("linear_cv")
    Q = np.diag([0.02, 0.02, 0.01, 0.01])
    R = GaussianMixture.gaussian(np.zeros(2), np.diag([0.5, 0.5]))
    filt = ParticleFilter(model, np.zeros(4), np.diag([25.0, 25.0, 0.01, 0.01]), Q, R, 300, 1,
                          policy=KLDResampling(bin_size=(0.5, 0.5), n_min=20, n_max=900))
    assert filt._compiled is not None and filt.capacity == 900
    noise = np.random.default_rng(4).normal(0.0, math.sqrt(0.5), (15, 2))
    counts = []
    for k in range(15):
        filt.step(np.zeros(2), DT, np.array([2.0, -1.0]) + noise[k])
        counts.append(filt.N)
        assert filt.particles.shape == (4, filt.N) and filt.log_weights.shape == (filt.N,)
        assert np.all(np.isfinite(filt.particles)) and abs(filt.weights.sum() - 1.0) < 1e-12
    assert len(set(counts)) > 3 and all(20 <= n <= 900 for n in counts), counts  # N follows the occupied bins
    assert np.linalg.norm(filt.x[:2] - np.array([2.0, -1.0])) < 2.0
