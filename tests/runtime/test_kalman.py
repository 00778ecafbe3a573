"""The Kalman-family runtime: oracles, missing data, rejected calls, repair, robust updates."""
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime import CKF, EKF, MCUKF, UKF, HuberUKF, repair_covariance
from abyssal.verify import filters as verify_filters

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


@pytest.fixture(scope="module")
def linear():
    return abyssal.generated.load("linear_cv")


def rov_filter(rov, cls=CKF, **options):
    n = rov.n_x
    return cls(rov, np.full(n, 0.5), 0.2 * np.eye(n), 1e-3 * np.eye(n), np.diag([0.1, 0.1, 0.05, 0.01]), **options)


TAU = np.array([5.0, 1.0, 2.0, 0.1])


@pytest.mark.parametrize("name", ["rov4dof", "cn2d", "linear_cv"])
def test_filters_equal_their_oracles(name):
    pytest.importorskip("filterpy")
    checks = verify_filters.checks(abyssal.generated.load(name))
    names = {c.name for c in checks}
    assert {"ckf step", "ekf step (Joseph)", "mcukf, sigma = inf", "huber ukf, gamma = inf", "ckf step()",
            "ekf step()"} <= names
    if name == "linear_cv":
        assert "ckf on a linear model" in names
    failed = [(c.name, c.error) for c in checks if not c.ok]
    assert not failed


def test_all_three_equal_the_kalman_filter_on_a_linear_model(linear):
    sc = verify_filters.scenario(linear, steps=30, seed=11)
    exact = verify_filters.exact_kalman_run(linear, sc)
    for cls in (EKF, UKF, CKF):
        ours = verify_filters.run_ours(cls(linear, sc.x0, sc.P0, sc.Q, sc.R), sc)
        assert verify_filters.compare("linear_cv", cls.__name__, "kf", ours, exact).error < 1e-12


def test_nan_entries_are_left_out_and_all_nan_skips(rov):
    full, masked, reduced = rov_filter(rov), rov_filter(rov), rov_filter(rov)
    for f in (full, masked, reduced):
        f.predict(TAU, 0.1)
    z = np.array([0.6, 0.4, 0.55, 0.5])
    # the reduced filter sees entry 1 with an enormous variance: the limit of leaving it out
    reduced.R = np.diag([0.1, 1e30, 0.05, 0.01])
    z_nan = z.copy()
    z_nan[1] = np.nan
    assert masked.update(z_nan)
    reduced.update(z)
    full.update(z)
    np.testing.assert_allclose(masked.x, reduced.x, rtol=1e-9, atol=1e-12)
    assert not np.allclose(masked.x, full.x)
    assert masked.innovation[1] == 0.0 and masked.S[1, 1] == 1.0
    x, P = masked.x, masked.P
    assert masked.update(np.full(4, np.nan)) is False
    assert masked.update(None) is False
    np.testing.assert_array_equal(masked.x, x)
    np.testing.assert_array_equal(masked.P, P)


@pytest.mark.parametrize("cls", [EKF, CKF])
def test_step_with_missing_entries_equals_predict_then_update(rov, cls):
    fused, separate = rov_filter(rov, cls), rov_filter(rov, cls)
    for z in (np.array([0.6, np.nan, 0.55, 0.5]), np.array([0.6, 0.4, 0.55, 0.5]), None, np.full(4, np.nan)):
        fused.step(TAU, 0.1, z)
        separate.predict(TAU, 0.1)
        separate.update(z)
        np.testing.assert_allclose(fused.x, separate.x, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(fused.P, separate.P, rtol=1e-12, atol=1e-14)


def test_measurements_slower_than_predictions(linear):
    sc = verify_filters.scenario(linear, steps=20, seed=3)
    Z = np.full_like(sc.Z, np.nan)
    Z[4::5] = sc.Z[4::5]  # one measurement every fifth prediction
    flt = CKF(linear, sc.x0, sc.P0, sc.Q, sc.R)
    result = flt.run(sc.U, Z, sc.dt, params=sc.p)
    assert np.all(np.isnan(result.nis[np.isnan(Z[:, 0])]))
    assert np.all(np.isfinite(result.nis[4::5])) and np.all(result.nis_dof[4::5] == 2)
    # between measurements the covariance only grows
    assert np.trace(result.P[3]) > np.trace(result.P[2]) > np.trace(result.P[1])
    assert np.trace(result.P[4]) < np.trace(result.P[3])
    # and a predict-only filter agrees up to the first measurement
    pred = CKF(linear, sc.x0, sc.P0, sc.Q, sc.R)
    for k in range(4):
        pred.predict(sc.U[k], sc.dt, sc.p)
    np.testing.assert_array_equal(pred.x, result.x[3])


def test_nis_and_nees_are_consistent_on_a_linear_gaussian_model(linear):
    rng = np.random.default_rng(5)
    T, n = 400, linear.n_x
    Q, R = 1e-2 * np.eye(n), 0.5 * np.eye(2)
    x = np.zeros(n)
    X, Z, U = np.empty((T, n)), np.empty((T, 2)), rng.normal(size=(T, 2)) * 0.1
    for k in range(T):
        x = linear.f(x, U[k], None, 0.1) + rng.multivariate_normal(np.zeros(n), Q)
        X[k], Z[k] = x, linear.h(x) + rng.multivariate_normal(np.zeros(2), R)
    result = EKF(linear, np.zeros(n), 1e-6 * np.eye(n), Q, R).run(U, Z, 0.1, truth=X)
    # chi-square means: NIS ~ 2 degrees of freedom, NEES ~ 4 (loose bounds for 400 correlated samples)
    assert 1.6 < np.mean(result.nis) < 2.4
    assert 3.0 < np.mean(result.nees) < 5.0


def test_angle_innovations_are_wrapped(rov):
    flt = rov_filter(rov)
    flt.predict(TAU, 0.1)
    z = rov.h(flt.x)
    z[3] += 2 * math.pi - 0.05  # the compass reads the same heading one turn later, minus 0.05 rad
    flt.update(z)
    assert flt.innovation[3] == pytest.approx(-0.05, abs=1e-9)


@pytest.mark.parametrize("cls", [EKF, UKF, CKF, MCUKF, HuberUKF])
def test_rejected_calls_leave_the_state_unchanged(rov, cls):
    flt = rov_filter(rov, cls)
    flt.step(TAU, 0.1, np.array([0.5, 0.5, 0.5, 0.5]))
    x, P = flt.x, flt.P
    bad_calls = [
        lambda: flt.predict(np.array([1.0, np.nan, 0.0, 0.0]), 0.1),
        lambda: flt.predict(np.array([1.0, np.inf, 0.0, 0.0]), 0.1),
        lambda: flt.predict(np.zeros(3), 0.1),
        lambda: flt.predict(TAU, -0.1),
        lambda: flt.predict(TAU, float("nan")),
        lambda: flt.predict(TAU, 0.1, p=np.full(rov.n_p, np.nan)),
        lambda: flt.update(np.array([0.5, np.inf, 0.5, 0.5])),
        lambda: flt.update(np.zeros(5)),
        lambda: flt.update(np.zeros(4), p=np.zeros(2)),
        lambda: flt.step(np.array([1.0, np.nan, 0.0, 0.0]), 0.1, np.array([0.5, 0.5, 0.5, 0.5])),
        lambda: flt.step(TAU, 0.1, np.array([0.5, np.inf, 0.5, 0.5])),
        lambda: flt.step(TAU, 0.0, np.array([0.5, 0.5, 0.5, 0.5])),
    ]
    for call in bad_calls:
        with pytest.raises(ValueError):
            call()
        np.testing.assert_array_equal(flt.x, x)
        np.testing.assert_array_equal(flt.P, P)
    flt.predict(TAU, 0.1)  # and it still works
    assert np.all(np.isfinite(flt.x))


def test_x_and_P_cannot_be_changed_from_outside(rov):
    flt = rov_filter(rov)
    x = flt.x
    flt.x[0] = 1e9
    flt.P[0, 0] = -1.0
    np.testing.assert_array_equal(flt.x, x)
    assert flt.P[0, 0] > 0


@pytest.mark.parametrize(
    "kind, matrix",
    [
        ("non-symmetric", np.eye(12) + np.triu(np.ones((12, 12)), 1) * 0.1),
        ("indefinite", np.diag([1.0] * 11 + [-0.5])),
        ("non-finite", np.diag([1.0] * 11 + [np.nan])),
        ("wrong shape", np.eye(11)),
    ],
)
def test_bad_covariances_are_refused(rov, kind, matrix):
    n = rov.n_x
    with pytest.raises(ValueError):
        CKF(rov, np.zeros(n), matrix, 1e-3 * np.eye(n), 0.1 * np.eye(4))
    with pytest.raises(ValueError):
        CKF(rov, np.zeros(n), np.eye(n), matrix, 0.1 * np.eye(4))
    flt = rov_filter(rov)
    with pytest.raises(ValueError):
        flt.R = np.diag([0.1, 0.1, 0.0, -1.0])
    with pytest.raises(ValueError):
        flt.reset(np.zeros(n), matrix)


def test_the_runtimes_steps_flag_non_positive_definite_covariance_without_nan(rov):
    from abyssal.runtime.compiled.kalman import BatchStep

    n = rov.n_x
    x, u, p, Q = np.full(n, 0.5), TAU, rov.params(), 1e-3 * np.eye(n)
    v = np.arange(1.0, n + 1)[:, None]
    predict = BatchStep(rov, "ckf_predict")
    for P in (np.diag([1.0] * (n - 1) + [-1e-3]), v @ v.T):  # indefinite, rank one
        outs = [np.zeros(n), np.zeros((n, n), order="F"), np.zeros(1)]
        predict.bind_batch([x, np.asfortranarray(P), u, p, np.array([0.1]), np.asfortranarray(Q)], outs, 1)(1)
        assert outs[2][0] == 0.0
        assert np.all(np.isfinite(outs[0])) and np.all(np.isfinite(outs[1]))


@pytest.mark.parametrize("cls", [EKF, UKF, CKF])
def test_near_singular_and_indefinite_covariances_are_repaired(rov, cls):
    flt = rov_filter(rov, cls)
    n = rov.n_x
    v = np.linspace(1.0, 2.0, n)[:, None]
    flt.reset(np.full(n, 0.5), v @ v.T)  # positive semi-definite, rank one: Cholesky pivots fail
    flt.step(TAU, 0.1, np.array([0.5, 0.5, 0.5, 0.5]))
    assert np.all(np.isfinite(flt.x)) and np.all(np.linalg.eigvalsh(flt.P) > 0)
    # roundoff drift to an indefinite P (as a UKF with negative weights can produce)
    flt._P[flt._cur][...] = np.diag([1.0] * (n - 1) + [-1e-6])
    flt.step(TAU, 0.1, np.array([0.5, 0.5, 0.5, 0.5]))
    assert np.all(np.isfinite(flt.P)) and np.all(np.linalg.eigvalsh(flt.P) > 0)
    if cls is not EKF:  # the EKF predict factorises nothing; its update factorises S only
        assert flt.repairs >= 1


def test_repair_covariance_clips_eigenvalues():
    A = np.diag([4.0, 1.0, -1e-3])
    B = repair_covariance(A, floor=1e-6)
    np.testing.assert_allclose(np.linalg.eigvalsh(B), [4e-6, 1.0, 4.0])


def test_an_absurd_state_is_refused_naming_the_state_and_kept(rov):
    # the state itself blows the predict up: the message names x or P, never u (issue 33)
    n = rov.n_x
    flt = CKF(rov, np.full(n, 1e150), 1e290 * np.eye(n), np.eye(n), np.eye(4))
    x, P = flt.x, flt.P
    with pytest.raises(ValueError, match="state given to the filter.*x or P is outside"):
        flt.predict(TAU, 0.1)
    np.testing.assert_array_equal(flt.x, x)
    np.testing.assert_array_equal(flt.P, P)
    flt.reset(np.zeros(n), np.eye(n))
    flt.predict(TAU, 0.1)  # a sane state predicts again
    flt.reset(np.full(n, 1e150), 1e290 * np.eye(n))
    with pytest.raises(ValueError, match="state given to the filter"):
        flt.predict(TAU, 0.1)


@pytest.mark.parametrize("cls, option", [(MCUKF, {"sigma": 2.0}), (HuberUKF, {"gamma": 1.345})])
def test_robust_updates_down_weight_an_outlier(rov, cls, option):
    # gate off: this compares the robust update with the plain one on the same outlier
    plain, robust = rov_filter(rov, UKF, gate_probability=0), rov_filter(rov, cls, gate_probability=0, **option)
    for f in (plain, robust):
        f.predict(TAU, 0.1)
    z = rov.h(plain.x)
    z[0] += 30.0  # 95 sigma outlier on x
    x_prior = plain.x
    plain.update(z)
    robust.update(z)
    assert abs(robust.x[0] - x_prior[0]) < 0.05 * abs(plain.x[0] - x_prior[0])


@pytest.mark.parametrize("cls, option", [(MCUKF, {"sigma": 1e9}), (HuberUKF, {"gamma": 1e9})])
def test_robust_updates_tend_to_the_plain_update(rov, cls, option):
    # gate off: this compares the robust update with the plain one on the same outlier
    plain, robust = rov_filter(rov, UKF, gate_probability=0), rov_filter(rov, cls, gate_probability=0, **option)
    z = np.array([0.7, 0.3, 0.6, 0.4])
    for f in (plain, robust):
        f.step(TAU, 0.1, z)
    np.testing.assert_allclose(robust.x, plain.x, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(robust.P, plain.P, rtol=1e-12, atol=1e-14)


def test_example_script_runs():
    out = subprocess.run([sys.executable, str(ROOT / "examples" / "ckf_rov4dof.py")], capture_output=True, text=True,
                         timeout=120, check=True)
    assert "RMSE" in out.stdout


# ------------------------------------------------------------------ reliability


def _rov_track(rov, steps, seed=0, Q=1e-3, R=(0.1, 0.1, 0.05, 0.01)):
    """A consistent simulated track: truth with additive N(0, Q I) process noise, z with N(0, R)."""
    from abyssal.runtime.numerics import simulate_truth

    U = np.tile(TAU, (steps, 1)) * np.sin(np.arange(steps) / 50.0)[:, None]
    X, Z = simulate_truth(rov, np.full(rov.n_x, 0.5), U, 0.1, Q * np.eye(rov.n_x), np.diag(R), seed)
    return U, X, Z


@pytest.mark.parametrize("cls", [EKF, CKF, UKF])
@pytest.mark.parametrize("size", [1e4, 1e6])
def test_a_gross_outlier_is_gated_and_never_poisons(rov, cls, size):
    U, X, Z = _rov_track(rov, 300)
    Z[150, :3] += size
    flt = cls(rov, np.full(rov.n_x, 0.5), 0.2 * np.eye(rov.n_x), 1e-3 * np.eye(rov.n_x), np.diag([0.1, 0.1, 0.05, 0.01]))
    result = flt.run(U, Z, 0.1, truth=X)
    assert flt.gated == 3 and result.nis_dof[150] == 1  # the three outlying entries out, psi kept
    assert np.all(np.isfinite(result.x))
    assert np.abs(result.x[-1, :3] - X[-1, :3]).max() < 1.0


def test_the_gate_never_fires_on_consistent_measurements(linear):
    # 2 x 10^4 consistent steps: at the default tail probability 1e-10 a false gate has probability 2e-6 here
    sc = verify_filters.scenario(linear, steps=20_000, seed=5)
    flt = EKF(linear, sc.x0, sc.P0, sc.Q, sc.R)
    result = flt.run(sc.U, sc.Z, sc.dt, params=sc.p)
    assert flt.gated == 0 and np.all(result.nis_dof == linear.n_y)
    assert 0.9 < np.mean(result.nis) / linear.n_y < 1.1  # and the filter is consistent


def test_repeated_gating_inflates_the_covariance_until_the_filter_follows(rov):
    U, X, Z = _rov_track(rov, 200)
    Z[100:, 0] += 25.0  # the position fix jumps for good (a filter that cannot follow, not one outlier)
    flt = CKF(rov, np.full(rov.n_x, 0.5), 0.2 * np.eye(rov.n_x), 1e-3 * np.eye(rov.n_x), np.diag([0.1, 0.1, 0.05, 0.01]))
    result = flt.run(U, Z, 0.1)
    assert flt.inflations >= 1
    assert abs(result.x[-1, 0] - (X[-1, 0] + 25.0)) < 1.0  # re-acquired the jumped fix
    assert flt.gated < 100


def test_a_refused_update_leaves_its_reports(rov):
    flt = rov_filter(rov)
    flt.step(TAU, 0.1, np.array([0.5, 0.5, 0.5, 0.5]))
    flt.predict(TAU, 0.1)  # the next update writes into the buffers of the reported innovation
    innovation, S, nis, counters = flt.innovation, flt.S, flt.nis, (flt.gated, flt.repairs)
    with pytest.raises(ValueError, match="use NaN"):
        flt.update(np.array([np.inf, 0.0, 0.0, 0.0]))
    np.testing.assert_array_equal(flt.innovation, innovation)
    np.testing.assert_array_equal(flt.S, S)
    assert flt.nis == nis and (flt.gated, flt.repairs) == counters


@pytest.mark.parametrize("cls", [CKF, UKF])
def test_dt_beyond_the_stable_range_is_subdivided(rov, cls):
    flt = rov_filter(rov, cls)
    flt.step(TAU, 0.1, np.array([0.5, 0.5, 0.5, 0.5]))
    flt.step(TAU, 5.0, np.array([0.5, 0.5, 0.5, 0.5]))  # one RK4 step of 5 s blows up at this covariance
    assert flt.substeps == 1 and np.all(np.isfinite(flt.P)) and np.abs(flt.P).max() < 1e3
    for _ in range(20):
        flt.step(TAU, 0.1, np.array([0.5, 0.5, 0.5, 0.5]))
    assert np.all(np.isfinite(flt.x))


def test_a_filter_used_from_two_threads_at_once_raises(rov):
    flt = rov_filter(rov)
    x, P = flt.x, flt.P
    flt._lock.acquire()  # another thread is inside a call
    try:
        with pytest.raises(RuntimeError, match="two threads"):
            flt.step(TAU, 0.1, np.array([0.5, 0.5, 0.5, 0.5]))
    finally:
        flt._lock.release()
    np.testing.assert_array_equal(flt.x, x)
    np.testing.assert_array_equal(flt.P, P)


def test_huge_finite_covariances_are_validated_without_overflow(rov):
    n = rov.n_x
    CKF(rov, np.zeros(n), 1e307 * np.eye(n), 1e307 * np.eye(n), 1e307 * np.eye(4))
    with pytest.raises(ValueError, match="P0 must be positive semi-definite"):
        CKF(rov, np.zeros(n), -1e308 * np.eye(n), np.eye(n), np.eye(4))
    with pytest.raises(TypeError, match="P0"):
        CKF(rov, np.zeros(n), np.eye(n) + 0j, np.eye(n), np.eye(4))


@pytest.mark.parametrize("cls", [EKF, UKF, CKF])
def test_run_loops_in_c_and_equals_stepping_bit_for_bit(rov, cls):
    """run() is one call of the C runtime (abyssal_kalman_run); its results and reports are those of step()."""
    rng = np.random.default_rng(4)
    T = 120
    U = np.tile(TAU, (T, 1)) + rng.normal(size=(T, 4))
    Z = rng.normal(size=(T, 4)) * 0.1
    Z[::7, 1] = np.nan
    Z[10] = np.nan
    Z[40, 0] = 1e4  # gated
    params = np.tile(rov.params(), (T, 1))
    params[60:, 0] = 30.0  # p changes mid-run
    a, b = rov_filter(rov, cls), rov_filter(rov, cls)
    result = a.run(U, Z, 0.1, params=params)
    for k in range(T):
        updated = b.step(U[k], 0.1, None if np.isnan(Z[k]).all() else Z[k], params[k])
        assert np.array_equal(result.x[k], b.x) and np.array_equal(result.P[k], b.P)
        assert (result.nis[k] == b.nis) if updated else np.isnan(result.nis[k])
    assert a._committed.tobytes() == b._committed.tobytes()
    assert np.array_equal(a.p, b.p) and a.gated == b.gated == 1


def test_a_refused_row_of_run_restores_the_filter_and_names_the_row(rov):
    flt = rov_filter(rov, CKF)
    before = flt._committed.copy()
    U = np.tile(TAU, (20, 1))
    params = np.tile(rov.params(), (20, 1))
    params[13, 0] = -1e300  # a mass that blows the predict up
    with pytest.raises(ValueError, match="run: row 13 refused"):
        flt.run(U, None, 0.1, params=params)
    assert flt._committed.tobytes() == before.tobytes()
