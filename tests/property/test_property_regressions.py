"""Deterministic reproducers of the bugs the property tests found, one per finding.

Found in code owned by other helpers while this folder was written; most were fixed the same
day and these tests now guard against their return. A test of a bug still open is marked
``xfail(strict=True)`` by its key in ``property_strategies.KNOWN_BUGS``: when the fix lands it
passes, strict xfail fails the run, and the key is deleted (the test stays as a regression test).
"""
from __future__ import annotations

import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime.contract import registered_filters
from abyssal.runtime.noise.mixtures import GaussianMixture
from property_strategies import CLASS_BUGS, KNOWN_BUGS, SOAK_BUGS

Q = np.diag([1e-4] * 4 + [1e-3] * 4 + [1e-5] * 4)
R = np.diag([0.05, 0.05, 0.02, 0.01])
X0, P0 = np.zeros(12), 0.3 * np.eye(12)
EXTREME_U = np.array([-1e300, 1e200, 0.0, 0.0])  # finite thrust far beyond the model's range


def known(key: str):
    return pytest.mark.xfail(key in KNOWN_BUGS, strict=True, reason=f"known bug [{key}]: {KNOWN_BUGS.get(key)}")


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


def make(name: str, model):
    classes = {cls.__name__: (cls, kind) for cls, kind in registered_filters().items()}
    cls, kind = classes[name]
    if kind == "kalman":
        return cls(model, X0, P0, Q, R)
    process = GaussianMixture.gaussian(np.zeros(12), Q)
    measurement = GaussianMixture(np.array([0.9, 0.1]), np.zeros((2, 4)), np.array([R, 100 * R]))
    return cls(model, X0, P0, process, measurement, 2 if kind == "gaussian-sum" else 16, np.random.default_rng(0))


@known("bundle_complex")
def test_bundle_refuses_complex_arguments(rov):
    with pytest.raises(TypeError, match="u"):
        rov.f(X0, np.zeros(4) + 0j, None, 0.1)
    with pytest.raises(TypeError, match="X"):
        rov.h_batch(np.zeros((12, 2)) + 0j)
    with pytest.raises(TypeError, match="x"):
        rov.functions["h"](X0 + 0j, rov.p_default)


@known("bundle_text_and_bool")
def test_bundle_refuses_strings_and_bool_naming_them(rov):
    with pytest.raises((TypeError, ValueError), match="dt"):
        rov.f(X0, np.zeros(4), None, "0.1")
    with pytest.raises(TypeError, match="dt"):
        rov.f(X0, np.zeros(4), None, True)
    with pytest.raises((TypeError, ValueError), match="u"):
        rov.f(X0, "xxxx", None, 0.1)


@known("bundle_batch_nonfinite")
def test_batch_entry_points_check_their_outputs(rov):
    X = np.zeros((12, 2))
    X[4, 1] = 1e200  # the single call raises FloatingPointError here
    with pytest.raises(FloatingPointError):
        rov.f(X[:, 1], np.zeros(4), None, 0.1)
    with pytest.raises(FloatingPointError):
        rov.f_batch(X, np.zeros(4), None, 0.1)
    with pytest.raises(FloatingPointError):
        rov.functions["f"].batch(1, X0, np.zeros(4), np.zeros(17), 0.1)  # p = 0: divisions by zero mass


@known("update_ignores_p_without_z")
def test_update_checks_p_even_without_a_measurement(rov):
    ekf = make("EKF", rov)
    with pytest.raises(ValueError, match="p"):
        ekf.update(None, np.full(17, np.nan))


@known("run_names_p_not_params")
def test_run_names_params(rov):
    ekf = make("EKF", rov)
    with pytest.raises(ValueError, match=r"\bparams\b"):
        ekf.run(np.zeros((2, 4)), None, 0.1, np.full(17, np.nan))


@known("particle_floating_point_error")
@pytest.mark.parametrize("name", ["ParticleFilter", "CubatureParticleFilter"])
def test_particle_filters_refuse_extreme_inputs_with_value_error(rov, name):
    filt = make(name, rov)
    with pytest.raises(ValueError):
        filt.predict(EXTREME_U, 0.1)


@known("mixture_filter_internal_message")
@pytest.mark.parametrize("name", ["GaussianSumCKF", "MixtureCubatureParticleFilter", "EMMixtureCubatureParticleFilter"])
def test_mixture_filters_refuse_extreme_inputs_naming_the_cause(rov, name):
    filt = make(name, rov)
    with pytest.raises(ValueError, match=r"\bu\b|\bdt\b|diverg|stable"):
        filt.predict(EXTREME_U, 0.1)


def test_no_linalg_error_escapes_after_a_long_step(rov):
    cpf = make("CubatureParticleFilter", rov)
    try:
        cpf.predict(np.zeros(4), 5.0)
        cpf.step(np.zeros(4), 0.1, rov.h(X0))
    except (ValueError, FloatingPointError) as error:  # a refusal is fine; numpy's LinAlgError (a ValueError) is not
        assert not isinstance(error, np.linalg.LinAlgError), repr(error)


@known("particle_long_dt_poisons")
@pytest.mark.parametrize("name", ["ParticleFilter", "CubatureParticleFilter", "MixtureCubatureParticleFilter"])
def test_one_long_step_does_not_poison_a_particle_filter(rov, name):
    filt = make(name, rov)
    try:
        filt.predict(np.zeros(4), 5.0)  # refusing it (naming dt) would be fine too
    except ValueError:
        pass
    accepted = 0
    for _ in range(5):
        try:
            filt.step(np.zeros(4), 0.1, rov.h(X0))
            accepted += 1
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            pass
    assert accepted > 0, "every step after one 5 s predict was refused"


@known("load_manifest_missing_keys")
def test_load_refuses_a_manifest_without_the_model_description(isolated_cache, tmp_path):
    folder = tmp_path / "model"
    folder.mkdir()
    (folder / "manifest.json").write_text('{"model": "abc", "files": {}}')
    with pytest.raises((ValueError, abyssal.generated.GeneratedFolderError), match="manifest"):
        abyssal.generated.load(folder)
    assert not any(isolated_cache.glob("*/*.so")), "a library was built from an incomplete manifest"


@known("ivbckf_defaults")
def test_every_registered_kalman_filter_builds_from_model_x0_P0_Q_R(rov):
    for cls, kind in registered_filters().items():
        if kind == "kalman" and not hasattr(cls, "contract_example"):  # GPUKF: a learned predict, its own constructor
            cls(rov, X0, P0, Q, R)


@known("kalman_gate_overflow")
def test_gross_outliers_near_the_float_limit_are_gated(rov):
    ckf = make("CKF", rov)
    ckf.predict(np.zeros(4), 0.1)
    ckf.update(np.array([1e-8, 1e200, -1e300, 0.0]))
    assert ckf.gated >= 2, "entries of 1e200 and -1e300 passed the gate"
    assert not np.isinf(ckf.nis)


@known("refused_step_keeps_substeps")
def test_a_refused_step_leaves_the_counters(rov):
    ckf = make("CKF", rov)
    before = ckf.substeps
    with pytest.raises(ValueError, match="z"):
        ckf.step(np.zeros(4), 60.0, np.zeros((1, 4)))
    assert ckf.substeps == before


@known("linalg_error_escapes")
def test_no_linalg_error_escapes_from_the_cubature_particle_filter(rov):
    cpf = make("CubatureParticleFilter", rov)
    cpf.step(np.zeros(4), 0.1, np.array([1e200, 0.0, 0.0, 1e-8]))
    try:
        cpf.step(np.array([1e-8, 1e-300, -1e300, -8.5]), 0.001, np.zeros(4))
    except ValueError as error:  # a refusal naming the cause is fine; numpy's LinAlgError (a ValueError) is not
        assert not isinstance(error, np.linalg.LinAlgError), repr(error)


@known("load_unknown_home")
def test_load_of_a_path_under_an_unknown_home_is_a_clear_refusal():
    with pytest.raises((KeyError, FileNotFoundError, ValueError), match="nosuchuser"):
        abyssal.generated.load("~nosuchuser_abyssal/model")


@pytest.fixture(scope="module")
def quick_soak(rov):
    import bench_soak  # benchmarks/ ([tool.pytest.ini_options] pythonpath)

    return {group: bench_soak.soak_run(rov, steps) for group, steps in
            (("kalman", 2000), ("particle", 300))}


def _soak_params():
    params = []
    for cls, kind in sorted(registered_filters().items(), key=lambda item: item[0].__name__):
        key = CLASS_BUGS.get(cls.__name__) or SOAK_BUGS.get(cls.__name__)
        marks = [known(key)] if key in KNOWN_BUGS else []
        if hasattr(cls, "contract_example"):  # its own model, noise form or learned step: not the soak's set-up
            marks.append(pytest.mark.skip(reason=f"{cls.__name__} has a constructor outside the soak's kinds; "
                                                 "tests/runtime/test_contract.py covers it"))
        params.append(pytest.param(cls, kind, id=cls.__name__, marks=marks))
    return params


@pytest.mark.parametrize("cls, kind", _soak_params())
def test_quick_soak_has_no_nan_and_no_permanent_divergence(rov, quick_soak, cls, kind):
    """The soak benchmark's run, short: gross outliers (1e4 m, 1e6 m), NaN entries and rows, an outage
    and one 5 s step. Refusals may happen (the 5 s step), but never a non-finite state, and the filter
    must accept measurements again in the last 10 % of the run."""
    import bench_soak  # benchmarks/ ([tool.pytest.ini_options] pythonpath)

    run = quick_soak["kalman" if kind == "kalman" else "particle"]
    report = bench_soak.soak_filter(bench_soak.build_filter(cls, kind, rov, run, 50), run)
    assert report["nan_steps"] == 0
    assert report["refusals_last_10pct"] == 0, report["first_refusal"]
    assert report["rms_position_error_last_10pct_m"] < 5.0, report


@known("kalman_bool_dt_after_long_step")
@pytest.mark.parametrize("name", ["EKF", "CKF"])
def test_dt_true_is_refused_even_after_a_long_step(rov, name):
    filt = make(name, rov)
    filt.predict(np.zeros(4), 1.0)
    with pytest.raises(TypeError, match="dt"):
        filt.predict(np.zeros(4), True)


@known("batch_shared_column_refused")
def test_batch_takes_a_shared_argument_of_its_declared_shape(rov):
    X = np.zeros((12, 2))
    out = rov.functions["f"].batch(2, X, np.zeros((4, 1)), rov.p_default, np.array([[0.1]]))
    assert out.shape == (12, 2) and np.array_equal(out, rov.functions["f"].batch(2, X, np.zeros(4), rov.p_default, 0.1))
