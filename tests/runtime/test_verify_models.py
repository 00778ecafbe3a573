"""The model checks of `abyssal verify` pass, and fail when either side is perturbed."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from abyssal.verify import models as verify_models
from abyssal.verify import reference_models
from abyssal.verify.reference_models import REFERENCES


@pytest.fixture(scope="module")
def rov_checks(rov):
    return verify_models.checks(rov)


def by_name(checks, fragment):
    found = [c for c in checks if fragment in c.name]
    assert found, f"no check named like {fragment!r} in {[c.name for c in checks]}"
    return found


def failing(checks):
    return sorted(c.name for c in checks if not c.ok)


def test_rov4dof_checks_all_pass_and_cover_every_model_function(rov_checks):
    assert failing(rov_checks) == []
    names = " | ".join(c.name for c in rov_checks)
    for fragment in ("f: compiled C vs CasADi", "F: compiled C vs CasADi", "G: compiled C vs CasADi",
                     "h: compiled C vs CasADi", "H: compiled C vs CasADi", "xdot: compiled C vs CasADi",
                     "xdot vs NumPy model", "h vs NumPy model", "f vs NumPy rk4 step",
                     "F vs central differences", "G vs central differences", "H vs central differences",
                     "one step vs solve_ivp", "order 4", "f_batch (SIMD, U shared)", "f_batch (SIMD, U per-column)",
                     "f _batch entry", "h_batch"):
        assert fragment in names


def test_cn2d_checks_pass_with_exactness_instead_of_order(cn):
    checks = verify_models.checks(cn)
    assert failing(checks) == []
    assert by_name(checks, "exact for held input vs solve_ivp")
    assert not [c for c in checks if "order" in c.name]


def test_rk4_order_ratio_is_near_sixteen(rov_checks):
    (order,) = by_name(rov_checks, "order 4")
    ratio = float(re.search(r"ratio ([0-9.]+)", order.reference).group(1))
    assert 12 <= ratio <= 20
    assert order.error == pytest.approx(abs(ratio - 16), abs=0.01)


def test_perturbed_reference_dynamics_fail(rov):
    """A sign error in the surge Coriolis term of the NumPy model (+m22 v r) is caught."""
    original = REFERENCES["rov4dof"]

    def wrong_coriolis(x, u, p, w=None):
        xdot = original.xdot(x, u, p, w)
        m22 = p[0] - p[3]
        m11 = p[0] - p[2]
        return xdot + np.stack([0 * x[0]] * 4 + [-2 * m22 * x[5] * x[7] / m11] + [0 * x[0]] * 7)

    checks = verify_models.checks(rov, reference=dataclasses.replace(original, xdot=wrong_coriolis))
    bad = failing(checks)
    assert "xdot vs NumPy model" in bad and "f vs NumPy rk4 step" in bad
    assert any(name.startswith("F vs central differences") for name in bad)
    assert not any("compiled C vs CasADi" in name for name in bad)  # the other oracle still agrees


def test_perturbed_reference_measurement_fails(cn):
    original = REFERENCES["cn2d"]
    wrong_range = dataclasses.replace(original, h=lambda x, p: original.h(x, p) * (1 + 1e-9))
    bad = failing(verify_models.checks(cn, reference=wrong_range))
    assert bad == ["h vs NumPy model"]


def test_parameter_order_mismatch_is_a_failure(cn):
    renamed = dataclasses.replace(REFERENCES["cn2d"], parameter_names=("x_leader", "y_leader"))
    checks = verify_models.checks(cn, reference=renamed)
    assert "parameter order vs NumPy model" in failing(checks)


class PerturbedBundle:
    """A bundle whose chosen outputs are off by a relative `eps`: stands in for a faulty build."""

    def __init__(self, bundle, eps, methods):
        self._bundle, self._eps, self._methods = bundle, eps, methods

    def __getattr__(self, name):
        attr = getattr(self._bundle, name)
        if name in self._methods:
            return lambda *args, **kwargs: attr(*args, **kwargs) * (1 + self._eps)
        return attr


@pytest.mark.parametrize("method, expected_failure", [
    ("F", "F vs central differences (NumPy step in x)"),
    ("H", "H vs central differences (NumPy measurement)"),
    ("f_batch", "f_batch (SIMD, U shared) vs one-at-a-time f"),
    ("xdot", "xdot vs NumPy model"),
])
def test_perturbed_bundle_output_fails(rov, method, expected_failure):
    eps = 1e-4 if method in ("F", "H") else 1e-12
    checks = verify_models.checks(PerturbedBundle(rov, eps, {method}))
    assert expected_failure in failing(checks)


def test_perturbed_casadi_side_fails(cn):
    """Compiled C vs CasADi fails when the symbolic F differs from what was compiled."""
    symbolic = verify_models.symbolic_functions("cn2d")
    F = symbolic["F"]
    args = [ca.MX.sym(F.name_in(i), F.sparsity_in(i)) for i in range(F.n_in())]
    symbolic["F"] = ca.Function("cn2d_F", args, [F(*args) * (1 + 1e-9)])
    bad = failing(verify_models.checks(cn, symbolic=symbolic))
    assert bad == ["F: compiled C vs CasADi"]


def test_relative_error_and_central_difference():
    assert verify_models.relative_error([1.0, 2.0], [1.0, 2.0]) == 0
    assert verify_models.relative_error([1.0, 2.2], [1.0, 2.0]) == pytest.approx(0.1)
    assert verify_models.relative_error([1e-3], [0.0]) == pytest.approx(1e-3)
    J = verify_models.central_difference(lambda z: np.array([z[0] * z[1], np.sin(z[0])]), np.array([0.5, 3.0]))
    np.testing.assert_allclose(J, [[3.0, 0.5], [np.cos(0.5), 0.0]], rtol=1e-9)


def test_reference_step_is_fourth_order_on_its_own(rov):
    """The NumPy RK4 of reference_models is itself 4th order (the oracle is sound)."""
    ref = REFERENCES["rov4dof"]
    x0, u = ref.cruise
    p = rov.params()
    exact = verify_models._integrate(ref, x0, u, p, 1.0)
    errors = []
    for n in (10, 20):
        x = x0.copy()
        for _ in range(n):
            x = reference_models.step(ref, x, u, p, 1.0 / n, "rk4")
        errors.append(np.max(np.abs(x - exact)))
    assert 12 < errors[0] / errors[1] < 20


# ----------------------------------------------------------------- a user's model inside its envelope
ATTITUDE = '''
"""A user's vehicle: Euler-angle attitude kinematics (singular at theta = +-pi/2) with |w| w damping."""
import casadi as ca

from abyssal import Envelope, Model, Parameter, Quantity, symbols

STATES = (Quantity("phi", "rad"), Quantity("theta", "rad"), Quantity("psi", "rad"),
          Quantity("p", "rad/s"), Quantity("q", "rad/s"), Quantity("r", "rad/s"))
INPUTS = (Quantity("K", "N m"), Quantity("M", "N m"), Quantity("N", "N m"))
PARAMS = (Parameter("I", "kg m^2", 2.0), Parameter("d_lin", "N m s", 0.5), Parameter("d_quad", "N m s^2", 1.0))
NOISES = (Quantity("w_K", "N m"), Quantity("w_M", "N m"), Quantity("w_N", "N m"))
OUTPUTS = (Quantity("phi", "rad"), Quantity("theta", "rad"), Quantity("psi", "rad"))


def attitude():
    x, u, p, w = symbols("x", STATES), symbols("u", INPUTS), symbols("p", PARAMS), symbols("w", NOISES)
    phi, theta = x[0], x[1]
    rates = x[3:6]
    sf, cf, ct, tt = ca.sin(phi), ca.cos(phi), ca.cos(theta), ca.tan(theta)
    euler_rates = ca.vertcat(rates[0] + (rates[1] * sf + rates[2] * cf) * tt,
                             rates[1] * cf - rates[2] * sf,
                             (rates[1] * sf + rates[2] * cf) / ct)
    rates_dot = (u + w - p[1] * rates - p[2] * ca.fabs(rates) * rates) / p[0]
    return Model(name="attitude", states=STATES, inputs=INPUTS, parameters=PARAMS, noises=NOISES, outputs=OUTPUTS,
                 x=x, u=u, p=p, w=w, xdot=ca.vertcat(euler_rates, rates_dot), y=x[0:3],
                 angle_states=(0, 1, 2), angle_outputs=(0, 1, 2),
                 # phi not listed: the default [-1, 1]
                 envelope=Envelope(states={"theta": (-1.4, 1.4), "psi": (-3.14, 3.14), "p": (-1.0, 1.0),
                                           "q": (-1.0, 1.0), "r": (-1.0, 1.0)},
                                   inputs={"K": (-2.0, 2.0), "M": (-2.0, 2.0), "N": (-2.0, 2.0)}, max_dt=0.2))
'''


@pytest.fixture(scope="module")
def attitude_folder(tmp_path_factory):
    """The user's model file and gen/attitude, written by the CLI (one compile per session via the cache)."""
    from abyssal.runtime import cli

    folder = tmp_path_factory.mktemp("attitude-project")
    (folder / "attitude.py").write_text(ATTITUDE)
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(folder)
        assert cli.main(["regenerate", "--model", "attitude.py:attitude", "--out", "gen"]) == 0
    return folder / "gen" / "attitude"


@pytest.fixture(scope="module")
def attitude(attitude_folder):
    from abyssal.verify import driver as verify

    return verify.folder_target(attitude_folder)


class WithEnvelope:
    """The same compiled bundle with another manifest envelope (what verify samples from)."""

    def __init__(self, bundle, envelope):
        self._bundle, self.envelope = bundle, envelope

    def __getattr__(self, name):
        return getattr(self._bundle, name)


def test_manifest_records_the_envelope_with_defaults_resolved(attitude):
    bundle = attitude.bundle
    env = bundle.envelope
    assert env["declared"] is True and env["max_dt"] == 0.2 and env["min_dt"] == 0.01
    assert env["states"]["theta"] == [-1.4, 1.4] and env["states"]["phi"] == [-1.0, 1.0]  # phi: the default
    assert set(env["states"]) == set(bundle.state_names) and set(env["inputs"]) == set(bundle.input_names)


def test_user_model_is_sampled_inside_its_envelope(attitude):
    points = verify_models._Points(attitude.bundle, None, np.random.default_rng(1))
    X = np.array([points.state() for _ in range(2000)])
    U = np.array([points.inputs() for _ in range(2000)])
    dts = np.array([points.dt() for _ in range(2000)])
    assert np.all(np.abs(X[:, 1]) <= 1.4) and np.max(np.abs(X[:, 1])) > 1.3  # theta fills [-1.4, 1.4]
    assert np.all(np.abs(X[:, 0]) <= 1.0) and np.all(np.abs(U) <= 2.0) and np.max(np.abs(U)) > 1.9
    assert dts.min() >= 0.01 and dts.max() <= 0.2 and dts.max() > 0.19
    batch = points.state(500)
    assert batch.shape == (6, 500) and np.all(np.abs(batch[1]) <= 1.4)


def test_euler_angle_model_passes_every_check_inside_its_envelope(attitude_folder):
    from abyssal.verify import driver as verify

    report = verify.run_all(folders=[attitude_folder])
    assert report.ok, report.table()
    assert not [c.name for c in report.checks if c.skipped]  # every filter runs on every model
    names = " | ".join(c.name for c in report.checks)
    for fragment in ("f: compiled C vs CasADi", "f vs rk4 of compiled xdot", "F vs central differences (compiled f in x)",
                     "G vs central differences", "one step vs solve_ivp", "order 4", "f_batch", "ekf step (Joseph)"):
        assert fragment in names
    assert "NOTE" not in report.table()  # it declares an envelope: nothing to say about defaults


def test_envelope_matters_the_same_model_fails_far_outside_it(attitude):
    """Sampled like the old N(0,1) draws at their tails (theta to +-3, dt to 0.5 s) the correct model fails."""
    wide = dict(attitude.bundle.envelope, states={n: [-3.0, 3.0] for n in attitude.bundle.state_names}, max_dt=0.5)
    checks = verify_models.checks(WithEnvelope(attitude.bundle, wide), target=attitude)
    assert failing(checks)


def test_fail_line_names_point_entry_both_values_and_tolerance(attitude):
    eps = 1e-4
    checks = verify_models.checks(PerturbedBundle(attitude.bundle, eps, {"F"}), target=attitude)
    (bad,) = [c for c in checks if not c.ok]
    assert bad.name == "F vs central differences (compiled f in x)"
    match = re.fullmatch(r"derivative disagrees at x=\[(.*?)\], u=\[(.*?)\], p=\[(.*?)\], dt=([0-9.e-]+): "
                         r"F\[(\d),(\d)\] = (\S+) vs (\S+), error (\S+), tolerance 1e-06", bad.worst)
    assert match, bad.worst
    x = np.array(match.group(1).split(", "), dtype=float)
    assert x.shape == (6,) and abs(x[1]) <= 1.4 and 0.01 <= float(match.group(4)) <= 0.2  # inside the envelope
    got, expected = float(match.group(7)), float(match.group(8))
    assert got / expected == pytest.approx(1 + eps, rel=1e-6)  # the perturbed entry and its reference value
    assert float(match.group(9)) == pytest.approx(bad.error, rel=1e-2) and bad.error > bad.tolerance
    from abyssal.verify.report import Report

    table = Report(checks).table()
    assert f"FAIL attitude {bad.name}: {bad.worst}; " in table


def test_a_diverging_step_is_reported_as_diverged(attitude):
    """dt up to 5 s and rates to +-20 rad/s: RK4 on |w| w damping blows up; that is divergence, not disagreement."""
    env = attitude.bundle.envelope
    wild = dict(env, states=dict(env["states"], p=[-20.0, 20.0], q=[-20.0, 20.0], r=[-20.0, 20.0]),
                min_dt=4.0, max_dt=5.0)
    checks = verify_models.checks(WithEnvelope(attitude.bundle, wild), target=attitude)
    by = {c.name: c for c in checks}
    for name in ("f vs rk4 of compiled xdot", "F vs central differences (compiled f in x)", "f: compiled C vs CasADi"):
        c = by[name]
        assert not c.ok and c.error == float("inf")
        assert c.worst.startswith("diverged at x=[") and "dt=" in c.worst, c.worst
        assert "left 10x its envelope" in c.worst and "disagrees" not in c.worst
    assert by["H vs central differences (compiled h)"].ok  # the measurement did not diverge


def test_no_envelope_declared_is_said_once_with_the_defaults(attitude):
    from abyssal.symbolic.model import envelope_record
    from abyssal.verify.report import Report

    undeclared = envelope_record(None, attitude.bundle.state_names, attitude.bundle.input_names)
    for envelope, why in ((undeclared, "no envelope declared: "), (None, "none recorded in its manifest")):
        checks = verify_models.checks(WithEnvelope(attitude.bundle, envelope), target=attitude)
        notes = [c.note for c in checks if c.note]
        assert len(notes) == 1 and why in notes[0]
        assert "states and inputs in [-1, 1], dt in [0.01, 0.5] s" in notes[0]
        assert Report(checks).table().count("NOTE attitude: no envelope declared") == 1
    points = verify_models._Points(WithEnvelope(attitude.bundle, undeclared), None, np.random.default_rng(2))
    X = np.array([points.state() for _ in range(500)])
    assert np.all(np.abs(X) <= 1.0) and 0.01 <= min(points.dt() for _ in range(200))


def test_builtins_with_a_twin_keep_their_draws(rov):
    """A NumPy twin's plausible states still drive the built-ins' checks (not the envelope box)."""
    points = verify_models._Points(rov, REFERENCES["rov4dof"], np.random.default_rng(3))
    assert points.bounds is None
    x = np.array([points.state() for _ in range(200)])
    assert np.max(np.abs(x[:, 8])) > 20  # the twin's bias draws N(0, 10), not the unit box


def test_a_missing_or_renamed_section_is_an_error_not_a_silent_skip(monkeypatch):
    import bench  # benchmarks/ ([tool.pytest.ini_options] pythonpath)

    from abyssal.verify import driver as verify

    monkeypatch.setattr(verify, "SECTIONS", verify.SECTIONS + ("abyssal.verify.renamed",))
    with pytest.raises(ModuleNotFoundError, match="abyssal.verify.renamed"):
        list(verify._sections())
    monkeypatch.setattr(bench, "SECTIONS", ("bench_renamed",))
    with pytest.raises(ModuleNotFoundError, match="bench_renamed"):
        bench.main(json_output=True, out=None, quick=True)


def test_every_section_file_is_listed():
    """A section file that SECTIONS does not name would never run: verify/ and benchmarks/ hold only listed
    sections besides their drivers and helpers."""
    import bench  # benchmarks/ ([tool.pytest.ini_options] pythonpath)

    from abyssal.runtime import cli
    from abyssal.verify import driver as verify

    here = Path(verify.__file__).parent
    assert {f"abyssal.verify.{f.stem}" for f in here.glob("*.py")} - set(verify.SECTIONS) == {
        "abyssal.verify.__init__", "abyssal.verify.driver", "abyssal.verify.report", "abyssal.verify.reference_models"}
    bench_files = {f.stem for f in cli.benchmarks_folder().glob("bench*.py")}
    assert bench_files - set(bench.SECTIONS) == {"bench", "bench_folder"}
    assert set(bench.SECTIONS) <= bench_files


def test_bench_outside_a_source_checkout_is_one_clear_line(monkeypatch, tmp_path, capsys):
    """A non-editable install has no benchmarks/ (it is never installed): `abyssal bench`, with or without
    model folders, says so in one line and exits 2."""
    from abyssal.runtime import cli

    installed = tmp_path / "site-packages" / "abyssal" / "runtime"
    installed.mkdir(parents=True)
    monkeypatch.setattr(cli, "__file__", str(installed / "cli.py"))
    for argv in (["bench", "--quick"], ["bench", str(tmp_path)]):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "the benchmarks ship with the source checkout only (git clone" in err, err


def test_the_public_verify_stays_a_function_beside_its_package():
    """abyssal.verify (the function) is not replaced by the package abyssal.verify once its modules load."""
    import abyssal
    from abyssal.verify import driver, models  # noqa: F401

    assert callable(abyssal.verify) and abyssal.verify.__module__ == "abyssal"
    assert driver.run_all.__module__ == "abyssal.verify.driver"


def test_the_bench_timing_driver_links_every_timed_function(rov):
    """The pure-C driver of `abyssal bench` finds each function in the file the manifest names (F sits in
    the EKF's file): a timing for every one, not a link error."""
    import bench_models  # benchmarks/ ([tool.pytest.ini_options] pythonpath)

    args = {"x": np.zeros(12), "u": np.zeros(4), "p": rov.params(), "dt": np.array([0.1])}
    times = bench_models.pure_c_times(rov, args, quick=True)
    assert set(times) == set(bench_models.PER_CALL)
    assert all(np.isfinite(t) and t > 0 for t in times.values())
