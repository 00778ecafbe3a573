"""Model validation at construction, parameter tables, discrete models and Fossen's DOF subsets."""
from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from abyssal.symbolic import codegen, discretise, fossen
from abyssal.symbolic.model import Model, Parameter, Quantity, symbols

STATES = (Quantity("a", "m"), Quantity("b", "m"))
INPUTS = (Quantity("c", "m/s"),)
PARAMS = (Parameter("k", "1/s", 1.0), Parameter("m", "kg", 2.0))
OUTPUTS = (Quantity("y", "m"), Quantity("psi", "rad"))


def make_model(**overrides) -> Model:
    x, u, p, w = symbols("x", STATES), symbols("u", INPUTS), symbols("p", PARAMS), ca.SX(0, 1)
    fields = dict(name="toy", states=STATES, inputs=INPUTS, parameters=PARAMS, noises=(), outputs=OUTPUTS,
                  x=x, u=u, p=p, w=w, xdot=ca.vertcat(x[1], (-p[0] * x[0] + u[0]) / p[1]), y=ca.vertcat(x[0], x[1]))
    fields.update(overrides)
    return Model(**fields)


def test_free_symbol_in_xdot_is_named():
    x = symbols("x", STATES)
    stray = ca.SX.sym("g")
    with pytest.raises(ValueError, match=r"xdot uses symbols \['g'\].*declare each as a Parameter"):
        make_model(x=x, xdot=ca.vertcat(x[1], stray * x[0]), y=ca.vertcat(x[0], x[1]))


def test_free_symbol_in_y_is_named():
    x = symbols("x", STATES)
    with pytest.raises(ValueError, match=r"h may depend on x and p only, found \['bias'\]"):
        make_model(x=x, xdot=ca.vertcat(x[1], x[0]), y=ca.vertcat(x[0], x[1] + ca.SX.sym("bias")))


@pytest.mark.parametrize("overrides, message", [
    (dict(name="my-vessel"), "not a valid C identifier"),
    (dict(name="2boat"), "not a valid C identifier"),
    (dict(name="double"), "reserved word"),
    (dict(states=(Quantity("a", "m"), Quantity("b dot", "m"))), r"states: name 'b dot' is not a valid C identifier"),
    (dict(states=(Quantity("a", "m"), Quantity("a", "m"))), "states: duplicate name 'a'"),
    (dict(parameters=(Parameter("k", "1/s", 1.0), Parameter("k", "kg", 2.0))), "parameters: duplicate name 'k'"),
    (dict(parameters=(Parameter("k", "1/s", 1.0), Parameter("m", "kg", float("nan")))), "default must be a finite"),
    (dict(angle_outputs=(2,)), r"angle_outputs index 2 is out of range: the model has 2 outputs"),
    (dict(angle_outputs=(-1,)), "angle_outputs index -1 is out of range"),
    (dict(angle_outputs=(1, 1)), "repeats an index"),
    (dict(angle_states=(5,)), r"angle_states index 5 is out of range: the model has 2 states"),
    (dict(discretisation="discrete"), "discretisation must be 'rk4' or 'euler'"),
    (dict(dt=ca.SX.sym("dt")), "dt= is only for a discrete model"),
    (dict(xdot=None), "give xdot"),
])
def test_invalid_models_are_refused_with_a_clear_message(overrides, message):
    with pytest.raises(ValueError, match=message):
        make_model(**overrides)


def test_mx_is_refused_saying_sx_is_required():
    x = ca.MX.sym("x", 2)
    with pytest.raises(ValueError, match="casadi.MX expression; abyssal generates C from SX"):
        make_model(x=x)


def test_angle_outputs_in_range_wrap_the_innovation():
    """The bug the range check prevents: psi's innovation wrapped (0.28, not -6.0) only if declared."""
    model = make_model(angle_outputs=(1,), angle_states=(1,))
    assert model.angle_outputs == (1,) and model.angle_states == (1,)


def test_parameter_table_and_vector_by_name():
    model = make_model()
    assert model.defaults == {"k": 1.0, "m": 2.0}
    assert model.parameter_vector(m=30.0) == [1.0, 30.0]
    with pytest.raises(KeyError, match=r"no parameter\(s\) \['mass'\]; its parameters: \['k', 'm'\]"):
        model.parameter_vector(mass=30.0)
    table = model.parameter_table()
    assert "name" in table.splitlines()[0] and "m" in table and "kg" in table


# ----------------------------------------------------------------- discrete models
def discrete_unicycle(**overrides) -> Model:
    """x_next = f_d(x, u, p, w, dt): a planar velocity motion model (seed 003's eq. 1 kind)."""
    states = (Quantity("px", "m"), Quantity("py", "m"), Quantity("heading", "rad"))
    inputs = (Quantity("speed", "m/s"), Quantity("turn", "rad/s"))
    params = (Parameter("gain", "-", 1.0),)
    noises = (Quantity("w_s", "m/s"), Quantity("w_t", "rad/s"))
    x, u, p, w, dt = symbols("x", states), symbols("u", inputs), symbols("p", params), symbols("w", noises), ca.SX.sym("dt")
    speed = p[0] * u[0] + w[0]
    x_next = ca.vertcat(x[0] + dt * speed * ca.cos(x[2]), x[1] + dt * speed * ca.sin(x[2]), x[2] + dt * (u[1] + w[1]))
    fields = dict(name="unicycle_d", states=states, inputs=inputs, parameters=params, noises=noises,
                  outputs=(Quantity("range", "m"),), x=x, u=u, p=p, w=w, xdot=None, y=ca.sqrt(x[0] ** 2 + x[1] ** 2 + 1),
                  x_next=x_next, dt=dt, angle_states=(2,))
    fields.update(overrides)
    return Model(**fields)


def test_discrete_model_builds_and_its_step_is_used():
    model = discrete_unicycle()
    assert model.is_discrete and model.discretisation == "discrete" and model.kind == "discrete"
    fns = {fn.name(): fn for fn in codegen.model_functions(model)}
    assert "unicycle_d_xdot" not in fns and "unicycle_d_x_next" in fns
    x, u, p, dt = [0.0, 0.0, 0.3], [2.0, 0.1], [1.0], 0.5
    np.testing.assert_allclose(np.array(fns["unicycle_d_f"](x, u, p, dt)).ravel(),
                               [dt * 2 * np.cos(0.3), dt * 2 * np.sin(0.3), 0.3 + dt * 0.1], rtol=1e-15)
    F = np.array(fns["unicycle_d_F"](x, u, p, dt))
    np.testing.assert_allclose(F[0, 2], -dt * 2 * np.sin(0.3), rtol=1e-15)
    G = np.array(fns["unicycle_d_G"](x, u, p, dt))
    np.testing.assert_allclose(G, [[dt * np.cos(0.3), 0], [dt * np.sin(0.3), 0], [0, dt]], rtol=1e-15)


@pytest.mark.parametrize("overrides, message", [
    (dict(dt=None), "needs dt="),
    (dict(xdot=ca.SX.zeros(3, 1)), "either xdot .* or x_next"),
    (dict(discretisation="rk4"), "discretisation must be 'discrete'"),
    (dict(substeps=2), "substeps only applies"),
    (dict(x_next=ca.SX.sym("q", 3)), r"x_next uses symbols \['q_0', 'q_1', 'q_2'\]"),
])
def test_discrete_model_validation(overrides, message):
    with pytest.raises(ValueError, match=message):
        discrete_unicycle(**overrides)


def test_discrete_equations_hash_depends_on_the_step():
    base = discrete_unicycle()
    other = dataclasses.replace(base, x_next=base.x_next * 2)
    assert base.equations_hash() != other.equations_hash()
    assert base.equations_hash() == discrete_unicycle().equations_hash()
    assert discretise.discrete_step(base, base.x, base.u, base.p, base.w, base.dt).shape == (3, 1)


# ----------------------------------------------------------------- Fossen DOF subsets
def evaluate(expr, *symbols_and_values):
    syms = [s for s, _ in symbols_and_values]
    return np.array(ca.Function("e", syms, [expr])(*[v for _, v in symbols_and_values]))


def test_horizontal_coriolis_is_fossen_eq_6_99_and_does_no_work():
    rng = np.random.default_rng(0)
    m11, m22, m23, m33 = 25.8, 33.8, 1.09, 2.76
    M = ca.SX(ca.DM([[m11, 0, 0], [0, m22, m23], [0, m23, m33]]))
    nu = ca.SX.sym("nu", 3)
    C = fossen.coriolis(M, nu, fossen.HORIZONTAL)
    for _ in range(5):
        u, v, r = rng.normal(size=3)
        got = evaluate(C, (nu, [u, v, r]))
        expected = [[0, 0, -m22 * v - m23 * r], [0, 0, m11 * u], [m22 * v + m23 * r, -m11 * u, 0]]
        np.testing.assert_allclose(got, expected, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(got + got.T, 0, atol=1e-14)


def test_horizontal_mass_blocks_match_the_textbook():
    m, xg, Iz = 23.8, 0.046, 1.76
    M_rb = np.array(ca.DM(ca.evalf(fossen.rigid_body_mass_horizontal(m, xg, Iz))))
    np.testing.assert_allclose(M_rb, [[m, 0, 0], [0, m, m * xg], [0, m * xg, Iz]], rtol=1e-15)
    M_a = np.array(ca.DM(ca.evalf(fossen.added_mass_horizontal(-2.0, -10.0, -0.4, -0.2, -1.0))))
    np.testing.assert_allclose(M_a, [[2, 0, 0], [0, 10, 0.3], [0, 0.3, 1]], rtol=1e-15)
    D = np.array(ca.DM(ca.evalf(fossen.linear_damping_horizontal(-0.7, -0.9, -7.25, 0.03, -1.9))))
    np.testing.assert_allclose(D, [[0.7, 0, 0], [0, 0.9, 7.25], [0, -0.03, 1.9]], rtol=1e-15)


def test_subset_kinematics_and_6dof_coriolis_need_no_embedding():
    rng = np.random.default_rng(1)
    eta, nu = ca.SX.sym("eta", 3), ca.SX.sym("nu", 3)
    psi, vel = rng.normal(), rng.normal(size=3)
    got = evaluate(fossen.kinematics(eta, nu, fossen.HORIZONTAL), (eta, [1.0, 2.0, psi]), (nu, vel)).ravel()
    c, s = np.cos(psi), np.sin(psi)
    np.testing.assert_allclose(got, [c * vel[0] - s * vel[1], s * vel[0] + c * vel[1], vel[2]], rtol=1e-14)
    np.testing.assert_allclose(
        got, evaluate(fossen.kinematics_horizontal(psi, nu), (nu, vel)).ravel(), rtol=1e-15)
    A = rng.normal(size=(6, 6))
    M6 = ca.SX(ca.DM(A @ A.T + 6 * np.eye(6)))
    nu6 = ca.SX.sym("nu6", 6)
    v6 = rng.normal(size=6)
    np.testing.assert_allclose(evaluate(fossen.coriolis(M6, nu6), (nu6, v6)),
                               evaluate(fossen.coriolis_from_mass(M6, nu6), (nu6, v6)), rtol=1e-15)
    with pytest.raises(ValueError, match="DOFs"):
        fossen.embed(ca.SX.zeros(2, 2), fossen.HORIZONTAL)


# ----------------------------------------------------------------- operating envelope
from abyssal.symbolic import Envelope  # noqa: E402
from abyssal.symbolic.model import DEFAULT_RANGE  # noqa: E402


@pytest.mark.parametrize("kwargs, message", [
    (dict(states={"a": (1.0, -1.0)}), r"Envelope states\['a'\] = \(1.0, -1.0\): low must be < high"),
    (dict(states={"a": (1.0, 1.0)}), r"states\['a'\].*low must be < high"),
    (dict(inputs={"c": (0.0, float("inf"))}), r"Envelope inputs\['c'\].*must be finite"),
    (dict(inputs={"c": (float("nan"), 1.0)}), r"inputs\['c'\].*must be finite"),
    (dict(states={"a": (0.0,)}), r"states\['a'\] must be a pair \(low, high\)"),
    (dict(states={"a": ("x", 1.0)}), r"states\['a'\] must be a pair"),
    (dict(max_dt=0.0), r"max_dt = 0.0 s: must be positive and finite"),
    (dict(max_dt=-1.0), r"max_dt = -1.0 s: must be positive"),
    (dict(min_dt=0.2, max_dt=0.1), r"min_dt = 0.2 s is larger than max_dt = 0.1 s"),
    (dict(min_dt=0.0), r"min_dt = 0.0 s: must be positive"),
])
def test_envelope_refuses_bad_ranges_naming_the_entry(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Envelope(**kwargs)


@pytest.mark.parametrize("envelope, message", [
    (Envelope(states={"theta": (-1.4, 1.4)}), r"envelope states: \['theta'\] is not a state name of the model; "
                                              r"its states: \['a', 'b'\]"),
    (Envelope(inputs={"c": (-1, 1), "d": (0, 1), "e": (0, 1)}), r"envelope inputs: \['d', 'e'\] are not input names"),
    ({"states": {}}, r"envelope must be an abyssal Envelope"),
])
def test_model_refuses_an_envelope_naming_unknown_quantities(envelope, message):
    with pytest.raises(ValueError, match=message):
        make_model(envelope=envelope)


def test_envelope_is_recorded_with_defaults_and_does_not_change_the_equations_hash():
    plain = make_model()
    enveloped = make_model(envelope=Envelope(states={"a": (-2, 3)}, max_dt=0.2))
    assert enveloped.equations_hash() == plain.equations_hash()
    record = enveloped.envelope_record()
    assert record == {"declared": True, "states": {"a": [-2.0, 3.0], "b": list(DEFAULT_RANGE)},
                      "inputs": {"c": list(DEFAULT_RANGE)}, "max_dt": 0.2, "min_dt": 0.01, "default_range": [-1.0, 1.0]}
    # no envelope, or no max_dt: not declared (None), derived by `abyssal verify` from the model
    assert plain.envelope_record()["declared"] is False and plain.envelope_record()["max_dt"] is None
    assert make_model(envelope=Envelope(states={"a": (-2, 3)})).envelope_record()["max_dt"] is None
    assert Envelope(min_dt=0.7).min_dt == 0.7  # a min_dt alone: nothing to compare it with
    assert codegen.generate_model(enveloped, [], codegen.BUILTIN)["manifest.json"].count('"envelope"') == 1


def test_envelope_copies_its_ranges_and_is_hashable():
    ranges = {"a": (0, 1)}
    env = Envelope(states=ranges)
    ranges["a"] = (5, 6)
    assert env.states == {"a": (0.0, 1.0)} and hash(env) == hash(Envelope(states={"a": (0.0, 1.0)}))
    with pytest.raises(dataclasses.FrozenInstanceError):
        env.max_dt = 1.0


def test_builtin_models_declare_envelopes_covering_every_state_and_input():
    from abyssal.symbolic.models import REGISTRY

    for name, build in REGISTRY.items():
        model = build()
        assert model.envelope is not None, name
        assert set(model.envelope.states) == {q.name for q in model.states}, name
        assert set(model.envelope.inputs) == {q.name for q in model.inputs}, name
