"""The carried proposals in C (filters/particle/carried.py: CPF carried, UPF, HRUPF, MCUPF) against the SIR engine's
NumPy path around the runtime's batched steps, the reference they replace: both draw from the same numpy Generator
in the same order, so the two filters must agree step after step to rounding -- particles, weights, estimates,
carried covariances -- and exactly in what they count (gated entries, re-acquisitions, resamplings, the particle
number under KLD-resampling) and in the Generator's state. Steps, predicts, updates alone, missing entries, a gated
outlier, a jump that is admitted after the gate's patience, a singular and a dense process noise."""
from __future__ import annotations

import math

import numpy as np
import pytest

from abyssal.runtime.experiments.cn import scenario
from abyssal.runtime.filters.particle import CubatureParticleFilter, UnscentedParticleFilter
from abyssal.runtime.filters.particle.carried import CompiledCarried
from abyssal.runtime.noise.mixtures import GaussianMixture
from abyssal.runtime.resampling import KLDResampling, ResamplingPolicy


def pair(make, monkeypatch):
    """(the filter on the C proposal, its twin on the NumPy path)."""
    compiled = make()
    assert isinstance(compiled._compiled, CompiledCarried)
    with monkeypatch.context() as m:
        m.setattr(CompiledCarried, "fits", staticmethod(lambda engine: False))
        twin = make()
    assert twin._compiled is None
    return compiled, twin


def assert_same(a, b, label):
    assert a.N == b.N and a.n_particles == b.n_particles, label
    for name in ("gated", "inflations", "resamples", "uninformative"):
        assert getattr(a, name) == getattr(b, name), (label, name)
    assert a.proposal.failed_slices == b.proposal.failed_slices, label
    scale = max(1.0, float(np.abs(b.particles).max()))
    np.testing.assert_allclose(a.particles, b.particles, rtol=0, atol=1e-9 * scale, err_msg=label)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9 * scale, err_msg=label)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-7, atol=1e-9 * scale**2, err_msg=label)
    np.testing.assert_allclose(a.weights, b.weights, rtol=1e-7, atol=1e-12, err_msg=label)
    np.testing.assert_allclose(a.proposal.carried, b.proposal.carried, rtol=1e-8, atol=1e-10 * scale**2, err_msg=label)
    assert math.isclose(a.ess, b.ess, rel_tol=1e-7), label
    assert a.rng.bit_generator.state == b.rng.bit_generator.state, label


def drive(a, b, calls):
    for k, (label, call) in enumerate(calls):
        assert call(a) == call(b), (k, label)
        assert_same(a, b, f"call {k}: {label}")


def rov_calls(rov, steps=16, jump_at=10):
    """rov4dof along a thrust profile: nominal steps, a missing entry, a predict and an update alone, one outlier on
    the depth (gated), then a jump of the position the cloud cannot follow (gated, then admitted)."""
    rng = np.random.default_rng(7)
    x, calls = np.zeros(rov.n_x), []
    for k in range(steps):
        u = np.array([20.0, 5.0, 10.0, 0.5 * math.sin(0.2 * k)]) + 0.5 * rng.standard_normal(4)
        x = rov.f(x, u, None, 0.1)
        z = rov.h(x) + rng.normal(0.0, [0.2, 0.2, 0.1, 0.05])
        if k == 3:
            z[1] = np.nan
        if k == 5:
            z[2] += 50.0
        if k >= jump_at:
            z[0] += 30.0
        if k == 6:
            calls.append(("predict", lambda f, u=u: f.predict(u, 0.1)))
            calls.append(("update alone", lambda f, z=z.copy(): f.update(z)))
            continue
        calls.append((f"step {k}", lambda f, u=u, z=z.copy(): f.step(u, 0.1, z)))
    return calls


@pytest.mark.parametrize("kind", ["CPF", "CPF gate off", "CPF singular Q", "CPF dense Q", "UPF", "HRUPF", "MCUPF"])
def test_c_proposal_on_rov4dof_equals_the_numpy_path(rov, monkeypatch, kind):
    Q = np.diag([1e-3] * 8 + [1e-2] * 4)
    if kind == "CPF singular Q":
        Q = np.diag([0.0] * 4 + [1e-2] * 4 + [0.0] * 4)  # no noise on the pose: the draws live on a subspace
    if kind == "CPF dense Q":
        A = np.random.default_rng(1).normal(size=(12, 12))
        Q = 1e-3 * (A @ A.T / 12 + np.eye(12))  # not diagonal: a dense basis of the subspace
    R = np.diag([0.2, 0.2, 0.1, 0.05]) ** 2
    mixture = GaussianMixture(np.array([0.8, 0.2]), np.array([[0.0] * 4, [0.1, -0.1, 0.05, 0.0]]), np.stack([R, 9 * R]))
    P0 = 0.05 * np.eye(12)

    def make():
        if kind.startswith("CPF"):
            return CubatureParticleFilter(rov, np.zeros(12), P0, Q, mixture, 60, 3, gate_patience=2,
                                          gate_probability=0.0 if kind == "CPF gate off" else 1e-10)
        update = {"UPF": "ukf", "HRUPF": "huber", "MCUPF": "mcc"}[kind]
        resampling = KLDResampling(bin_size=(0.05, 0.05), n_min=20, n_max=80) if kind == "MCUPF" else None
        return UnscentedParticleFilter(rov, np.zeros(12), P0, Q, R, 60, 3, update=update, resampling=resampling,
                                       gate_patience=2, sigma=2.0)

    a, b = pair(make, monkeypatch)
    drive(a, b, rov_calls(rov))
    if kind != "CPF gate off":
        assert a.gated >= 2 and a.inflations >= 1  # the outlier, and the jump: gated, then admitted


@pytest.mark.parametrize("update, resampling", [("ukf", None), ("huber", None), ("mcc", "kld"),
                                                ("ukf", "systematic")])
def test_c_proposal_on_cn2d_ranges_equals_the_numpy_path(cn, monkeypatch, update, resampling):
    trial = scenario.simulate(scenario.CnScenario(), "gaussian", np.random.default_rng(11))
    Q, R = np.diag([100.0, 100.0]), np.eye(cn.n_y) * 0.1  # each leader sensor's range
    policy = {None: None, "kld": KLDResampling(n_max=2000), "systematic": ResamplingPolicy("systematic", 0.5)}[resampling]

    def make():
        return UnscentedParticleFilter(cn, trial.x0, trial.P0, Q, R, 3000 if resampling == "kld" else 500, 2,
                                       update=update, resampling=policy)

    a, b = pair(make, monkeypatch)
    calls = [(f"step {k}", lambda f, k=k: f.step(trial.U[k], trial.dt, trial.Z[k], trial.params[k])) for k in range(20)]
    calls.insert(9, ("update alone", lambda f: f.update(trial.Z[9], trial.params[9])))
    drive(a, b, calls)
    if resampling == "kld":
        assert a.N < 3000  # the particle number adapted


def test_the_numpy_path_is_kept_where_the_c_proposal_does_not_fit(rov):
    """A process-noise mixture (or a mean) keeps the NumPy path."""
    Q = GaussianMixture(np.array([0.5, 0.5]), np.zeros((2, 12)), np.stack([1e-3 * np.eye(12), 4e-3 * np.eye(12)]))
    R = GaussianMixture.gaussian(np.zeros(4), 0.01 * np.eye(4))
    f = CubatureParticleFilter(rov, np.zeros(12), 0.05 * np.eye(12), Q, R, 20, 0)
    assert f._compiled is None
    assert f.step(np.zeros(4), 0.1, np.zeros(4)) in (True, False) and np.all(np.isfinite(f.x))
