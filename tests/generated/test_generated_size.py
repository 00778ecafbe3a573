"""Generated filter steps grow with the work, not with its expansion (symbolic/filters/common.py).

A chain of damped pendulums (n = 2k states) is generated in memory; these check the structure the
size rests on: the model's step is emitted once per C file and called per sigma point, fused steps
call their predict and update, and a bigger step (more substeps) adds its own size once to a
filter file instead of once per sigma point. Steps small enough to be emitted flat (common.FLAT_MAX_INSTRUCTIONS)
are flat by design, so the structure tests turn flattening off; the last tests check the flat form.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from abyssal.generated.regenerate import model_files
from abyssal.symbolic.filters import common
from abyssal.symbolic.model import Model, Parameter, Quantity, symbols


def pendulum_chain(k: int, substeps: int = 1) -> Model:
    """k pendulums (angle, rate), neighbours coupled by springs; torque inputs; angles measured."""
    states = [Quantity(f"{q}{i}", unit) for i in range(k) for q, unit in (("th", "rad"), ("om", "rad/s"))]
    inputs = [Quantity(f"tau{i}", "N m") for i in range(k)]
    parameters = [Parameter("g_over_l", "1/s^2", 9.81), Parameter("damping", "1/s", 0.3), Parameter("spring", "1/s^2", 2.0)]
    x, u, p = symbols("x", states), symbols("u", inputs), symbols("p", parameters)
    theta, omega = x[0::2], x[1::2]
    xdot = []
    for i in range(k):
        coupling = sum((theta[j] - theta[i] for j in (i - 1, i + 1) if 0 <= j < k), ca.SX(0))
        xdot += [omega[i], -p[0] * ca.sin(theta[i]) - p[1] * omega[i] + p[2] * coupling + u[i]]
    return Model(name=f"chain{k}", states=tuple(states), inputs=tuple(inputs), parameters=tuple(parameters),
                 noises=(), outputs=tuple(Quantity(f"y{i}", "rad") for i in range(k)), x=x, u=u, p=p, w=ca.SX(0, 1),
                 xdot=ca.vertcat(*xdot), y=theta, substeps=substeps)


def leaf_definitions(text: str, name: str) -> int:
    """How many functions named `name` the C text defines (CasADi writes "/* name:(...) */" above each)."""
    return text.count(f"/* {name}:(")


@pytest.fixture(scope="module")
def chain_files():
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(common, "FLAT_MAX_INSTRUCTIONS", 0)  # every step as calls, however small
        return model_files(pendulum_chain(3), families=("ekf", "ukf", "ckf", "robust"))


def test_the_model_step_is_emitted_once_for_every_sigma_point_family(chain_files):
    text = chain_files["chain3_sigma_points.c"]
    for shared in ("chain3_step", "chain3_cholesky", "chain3_kalman", "chain3_predicted", "chain3_outer"):
        assert leaf_definitions(text, shared) == 1, shared
    # the points' loop calls the step: a map over the 2n (+1) points of n = 6 states, not 2n copies
    for points in (12, 13):
        assert leaf_definitions(text, f"map{points}_chain3_step") == 1, points


def test_fused_steps_call_predict_and_update_in_the_same_file(chain_files):
    assert set(chain_files) == {"chain3_model.c", "chain3_ekf.c", "chain3_sigma_points.c", "chain3_soa.c",
                                "chain3_descriptor.c", "abyssal_model.h", "manifest.json"}
    for family, file in (("ekf", "chain3_ekf.c"), ("ckf", "chain3_sigma_points.c")):
        for part in ("predict", "update", "step"):
            assert leaf_definitions(chain_files[file], f"chain3_{family}_{part}") == 1, (family, part)


def test_the_ekf_and_the_model_jacobian_share_one_step_and_jacobian(chain_files):
    assert leaf_definitions(chain_files["chain3_ekf.c"], "chain3_step_and_jacobian") == 1
    assert leaf_definitions(chain_files["chain3_ekf.c"], "chain3_F") == 1
    assert leaf_definitions(chain_files["chain3_model.c"], "chain3_F") == 0


def test_robust_updates_share_the_unscented_points(chain_files):
    text = chain_files["chain3_sigma_points.c"]
    assert leaf_definitions(text, "chain3_ukf_points") == 1
    for name in ("chain3_ukf_update", "chain3_mcukf_update", "chain3_huber_ukf_update"):
        assert leaf_definitions(text, name) == 1, name


def test_a_bigger_step_adds_its_size_once_not_once_per_point(monkeypatch):
    monkeypatch.setattr(common, "FLAT_MAX_INSTRUCTIONS", 0)
    small, big = (model_files(pendulum_chain(4, substeps), families=("ckf",)) for substeps in (1, 8))
    grown_model = len(big["chain4_model.c"]) - len(small["chain4_model.c"])
    grown_ckf = len(big["chain4_sigma_points.c"]) - len(small["chain4_sigma_points.c"])
    assert grown_model > 20_000  # eight RK4 substeps are much more code than one (f, F and xdot)
    # the CKF file holds one more copy of the bigger step (f alone is about a third of what the model file gained);
    # an inlined step would add it once per point: 8 points, several times the model file's growth
    assert 0 < grown_ckf < 0.6 * grown_model


def test_generated_steps_keep_their_values_when_restructured():
    """The C structure is an MX graph of SX leaves: evaluated in CasADi it equals the plain SX algebra."""
    from abyssal.symbolic.filters import filter_units
    from abyssal.symbolic.filters.linalg import guarded_cholesky, symmetrise, weighted_outer, weighted_sum
    from abyssal.symbolic.filters.sigma_points import cubature_rule
    from abyssal.symbolic.filters.common import transition

    model = pendulum_chain(2)
    predict = {fn.name(): fn for unit in filter_units(model, ("ckf",)) for fn in unit.functions}["chain2_ckf_predict"]
    rng = np.random.default_rng(3)
    n = model.n_x
    A = rng.normal(size=(n, n))
    x, P, u, p, dt, Q = rng.normal(size=n), A @ A.T + np.eye(n), rng.normal(size=2), [9.81, 0.3, 2.0], 0.05, 0.01 * np.eye(n)
    # the same predict written as one SX expression, from the shared algebra helpers
    L, _ = guarded_cholesky(symmetrise(ca.SX(P)))
    rule = cubature_rule(n)
    f = transition(model)
    X = rule.points(ca.SX(x), L)
    Y = ca.horzcat(*[f(X[:, j], u, p, dt) for j in range(rule.n_points)])
    mean = weighted_sum(Y, rule.wm)
    cov = weighted_outer(Y - ca.repmat(mean, 1, rule.n_points), rule.wc) + Q
    x_pred, P_pred, ok = predict(x, P, u, p, dt, Q)
    np.testing.assert_allclose(np.array(x_pred).ravel(), np.array(ca.evalf(mean)).ravel(), rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(np.array(P_pred), np.array(ca.evalf(cov)), rtol=1e-12, atol=1e-15)
    assert float(ok) == 1.0


def test_soa_kernels_compute_shared_work_once_before_the_loop(chain_files):
    """What depends only on p, dt and constants (here g/l, the damping, the spring, dt/2, dt/6) is evaluated once
    per call, before the loop over particles; sin stays in the loop (libmvec's vector sin)."""
    text = chain_files["chain3_soa.c"]
    kernel = text[text.index("int chain3_f_soa("):]
    before, loop = kernel.split("ABYSSAL_SIMD_LOOP", 1)
    assert before.count("const casadi_real c") >= 6 and "a2[" in before and "a3[" in before
    loop = loop[: loop.index("return 0;")]
    assert "a2[" not in loop and "a3[" not in loop and "sin(" in loop and "sin(" not in before


def _steps(model, families):
    from abyssal.symbolic.filters import filter_units

    return {fn.name(): fn for unit in filter_units(model, families) for fn in unit.functions}


def test_small_steps_are_flat_and_equal_their_calls(monkeypatch):
    """A 2-state model's steps are one SX expression each (no calls left); evaluated in CasADi they equal the
    same steps built as calls to leaves, to rounding."""
    families = ("ekf", "ukf", "ckf", "robust")
    flat = _steps(pendulum_chain(1), families)
    monkeypatch.setattr(common, "FLAT_MAX_INSTRUCTIONS", 0)
    calls = _steps(pendulum_chain(1), families)
    rng = np.random.default_rng(5)
    for name, fn in flat.items():
        assert fn.is_a("SXFunction") and not any(fn.instruction_id(k) == ca.OP_CALL for k in range(fn.n_instructions())), name
        assert calls[name].is_a("MXFunction") or name.endswith("ekf_update"), name  # (the EKF update is one leaf)
        args = []
        for i in range(fn.n_in()):
            a = rng.normal(size=fn.size_in(i))
            if fn.name_in(i) in ("P", "Q", "R"):
                a = a @ a.T + 2.0 * np.eye(a.shape[0])
            elif fn.name_in(i) == "mask":
                a = np.ones(fn.size_in(i))
            elif fn.name_in(i) == "abk":
                a = np.array([1.0, 0.0, 1.0])
            elif fn.name_in(i) in ("dt", "sigma", "gamma"):
                a = np.array([[0.1 if fn.name_in(i) == "dt" else 1.5]])
            args.append(a)
        for a, b in zip(fn.call(args), calls[name].call(args)):
            np.testing.assert_allclose(np.array(a), np.array(b), rtol=1e-12, atol=1e-14, err_msg=name)


def test_large_steps_keep_their_calls():
    steps = _steps(pendulum_chain(6), ("ckf",))  # n = 12: tens of thousands of operations inlined
    assert common.inlined_size(steps["chain6_ckf_step"]) > common.FLAT_MAX_INSTRUCTIONS
    assert steps["chain6_ckf_step"].is_a("MXFunction")
