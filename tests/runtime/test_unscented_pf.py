"""UPF / HRUPF / MCUPF (runtime/filters/particle/unscented.py) and IVBCKF on cn2d."""
from __future__ import annotations

import numpy as np
import pytest

from abyssal.runtime.compiled.kalman import BatchStep
from abyssal.runtime.experiments.cn import scenario
from abyssal.runtime.filters.kalman.ivbckf import IVBCKF
from abyssal.runtime.filters.particle.unscented import UnscentedParticleFilter
from abyssal.runtime.resampling import KLDResampling

Q, R = np.diag([100.0, 100.0]), np.eye(2) * 0.1  # cn2d's two leader sensors, each R = 0.1


@pytest.fixture(scope="module")
def trial():
    return scenario.simulate(scenario.CnScenario(), "gaussian", np.random.default_rng(11))


def test_batched_update_equals_single_calls(cn, trial):
    f = UnscentedParticleFilter(cn, trial.x0, trial.P0, Q, R, 100, 0, update="mcc")
    f.step(trial.U[0], trial.dt, trial.Z[0], trial.params[0])
    proposal = f.proposal
    pb, ub = proposal._pb, proposal._ub
    mean, cov = f.particles.copy(), f.carried.copy()
    pb.mean[:, :f.N], pb.u[:], pb.dt[0], f.p[:] = mean, trial.U[1], trial.dt, trial.params[1]
    present = ~np.isnan(trial.Z[1])  # the leader that did not ping: a missing entry
    z1 = np.where(present, trial.Z[1], 0.0)
    ub.present[:] = present
    ub.set_measurement(z1)
    pb(f.N)
    ub(f.N)
    for j in (0, 17, 99):
        xp, Pp, _ = BatchStep(cn, "ukf_predict")(mean[:, j], cov[:, :, j], trial.U[1], trial.params[1], trial.dt, Q,
                                               proposal.abk)
        np.testing.assert_allclose(np.ravel(xp), pb.mean_pred[:, j], rtol=1e-13, atol=1e-9)
        xu, Pu, *_ = BatchStep(cn, "mcukf_update")(xp, Pp, z1, trial.params[1], R, present.astype(float), proposal.abk,
                                                 np.array([15.0]))
        np.testing.assert_allclose(np.ravel(xu), ub.mean_post[:, j], rtol=1e-13, atol=1e-9)
        np.testing.assert_allclose(np.asarray(Pu), ub.cov_post[:, :, j], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("update,kw", [("mcc", {"sigma": np.inf}), ("huber", {"gamma": 1e12})])
def test_robust_limits_are_the_upf(cn, trial, update, kw):
    a = UnscentedParticleFilter(cn, trial.x0, trial.P0, Q, R, 200, 3)
    b = UnscentedParticleFilter(cn, trial.x0, trial.P0, Q, R, 200, 3, update=update, **kw)
    ra = a.run(trial.U[:20], trial.Z[:20], trial.dt, params=trial.params[:20])
    rb = b.run(trial.U[:20], trial.Z[:20], trial.dt, params=trial.params[:20])
    np.testing.assert_allclose(ra.x, rb.x, rtol=0, atol=1e-8)


def test_tuned_filters_beat_dead_reckoning_on_a_gaussian_trial(cn, trial):
    """With Q, R matched to the simulation (the printed Q = 100 m^2 per step leaves them near DR)."""
    dr = scenario.ape(trial.dr, trial.truth)
    Qt, Rt = np.eye(2), np.eye(2)
    for f in (UnscentedParticleFilter(cn, trial.x0, trial.P0, Qt, Rt, 500, 1),
              UnscentedParticleFilter(cn, trial.x0, trial.P0, Qt, Rt, 2000, 1, update="mcc", resampling=KLDResampling()),
              IVBCKF(cn, trial.x0, trial.P0, Qt, Rt)):
        res = f.run(trial.U, trial.Z, trial.dt, params=trial.params)
        assert np.all(np.isfinite(res.x))
        assert scenario.ape(res.x, trial.truth) < 0.5 * dr, type(f).__name__


def test_kld_particle_number_bounded_and_adapts(cn, trial):
    f = UnscentedParticleFilter(cn, trial.x0, trial.P0, Q, R, 5000, 2, update="mcc",
                                resampling=KLDResampling(n_min=20, n_max=2000))
    res = f.run(trial.U[:30], trial.Z[:30], trial.dt, params=trial.params[:30])
    assert res.particles[0] == 5000  # N_start
    assert np.all(res.particles[1:] <= 2000) and np.all(res.particles[1:] >= 20)
    assert f.N <= 2000


def test_refused_step_leaves_filter_bit_identical(cn, trial):
    f = UnscentedParticleFilter(cn, trial.x0, trial.P0, Q, R, 300, 4, update="huber")
    f.step(trial.U[0], trial.dt, trial.Z[0], trial.params[0])
    before = f.checkpoint()
    for bad in ({"z": np.array([np.inf])}, {"dt": -1.0}, {"p": np.array([np.nan, 0.0])}):
        args = dict(u=trial.U[1], dt=trial.dt, z=trial.Z[1], p=trial.params[1]) | bad
        with pytest.raises(ValueError):
            f.step(**args)
        after = f.checkpoint()
        np.testing.assert_array_equal(before["particles"], after["particles"])
        np.testing.assert_array_equal(before["proposal"]["carried"], after["proposal"]["carried"])
        assert before["rng"] == after["rng"]  # random generator state


def test_ivbckf_reduces_to_ckf_without_outliers_on_average(cn, trial):
    """Well-tuned Q, R and Gaussian data: the VB scales stay near 1 and the estimate near the CKF's.
    (With the printed Q = 100 m^2 the IVBCKF shrinks the over-large prior and beats the CKF: seen, not asserted.)"""
    from abyssal.runtime import CKF
    Qt, Rt = np.eye(2), np.eye(2)
    a = CKF(cn, trial.x0, trial.P0, Qt, Rt, gate_probability=0.0).run(trial.U, trial.Z, trial.dt, params=trial.params)
    b = IVBCKF(cn, trial.x0, trial.P0, Qt, Rt).run(trial.U, trial.Z, trial.dt, params=trial.params)
    assert abs(scenario.ape(a.x, trial.truth) - scenario.ape(b.x, trial.truth)) < 0.5 * scenario.ape(a.x, trial.truth)


def test_update_alone_reweights_and_resamples(cn, trial):
    f = UnscentedParticleFilter(cn, trial.x0, trial.P0, Q, np.eye(2), 400, 5)
    before = f.x
    assert f.update(None) is False and f.update(np.array([np.nan, np.nan])) is False
    np.testing.assert_array_equal(f.x, before)
    assert f.update(trial.Z[0], trial.params[0]) is True
    # the particles have not moved, so the estimate stays inside the initial cloud
    assert np.linalg.norm(f.x - trial.x0) < 4 * np.sqrt(trial.P0[0, 0])
