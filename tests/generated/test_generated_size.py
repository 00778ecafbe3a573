"""Generated code is the model's: f with its substeps, F, G, each sensor's h and H, the SoA kernels and the
descriptor; no filter algebra (the C runtime holds it once, generic over the dimensions).

A chain of damped pendulums (n = 2k states) is generated in memory; these check what a folder holds, that its C
grows with the model's own operation count (not with the filters or the sigma points), and the SoA kernels'
structure.
"""
from __future__ import annotations

import json

import casadi as ca
import pytest

from abyssal.generated.regenerate import model_files
from abyssal.symbolic.model import Model, Parameter, Quantity, Sensor, symbols


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


@pytest.fixture(scope="module")
def chain_files():
    return model_files(pendulum_chain(3))


def test_a_folder_holds_the_model_and_no_filter(chain_files):
    assert set(chain_files) == {"chain3_model.c", "chain3_soa.c", "chain3_descriptor.c", "abyssal_model.h",
                                "manifest.json"}
    functions = json.loads(chain_files["manifest.json"])["functions"]
    assert set(functions) == {"chain3_f", "chain3_F", "chain3_h", "chain3_H", "chain3_xdot"}
    for text in chain_files.values():
        for filter_step in ("ekf_", "ukf_", "ckf_", "mcukf", "huber"):
            assert filter_step not in text


def test_the_c_grows_with_the_models_own_operations():
    """Doubling the chain doubles f's and F's operations; the folder's C must grow by about the same factor (a
    filter step written out per model grew as n^2.2 and its compile time as n^2.4)."""
    sizes, operations = [], []
    for k in (3, 6, 12):
        files = model_files(pendulum_chain(k))
        sizes.append(sum(len(t) for name, t in files.items() if name.endswith(".c")))
        spec = json.loads(files["manifest.json"])["functions"]
        operations.append(sum(spec[f"chain{k}_{s}"]["instructions"] for s in ("f", "F", "h", "H")))
    for a in range(2):
        size_growth, work_growth = sizes[a + 1] / sizes[a], operations[a + 1] / operations[a]
        assert size_growth <= 1.25 * work_growth, (sizes, operations)


def test_every_sensor_gets_its_h_h_jacobian_and_kernel():
    model = pendulum_chain(2)
    x, ys = model.x, [model.x[0], ca.vertcat(model.x[1], model.x[3])]
    two = Model(name="chain2s", states=model.states, inputs=model.inputs, parameters=model.parameters, x=x, u=model.u,
                p=model.p, xdot=model.xdot, sensors=(
                    Sensor(name="angle", outputs=(Quantity("th0", "rad"),), y=ys[0], noise=(0.01,)),
                    Sensor(name="gyro", outputs=(Quantity("om0", "rad/s"), Quantity("om1", "rad/s")), y=ys[1])))
    files = model_files(two)
    functions = json.loads(files["manifest.json"])["functions"]
    for name in ("chain2s_angle_h", "chain2s_angle_H", "chain2s_gyro_h", "chain2s_gyro_H", "chain2s_h", "chain2s_H"):
        assert name in functions, name
    assert functions["chain2s_gyro_h"]["soa_batched_inputs"] == ["x"]
    descriptor = files["chain2s_descriptor.c"]
    assert '{"angle", 1, 0, 3, 0, sensor0_R,' in descriptor and '{"gyro", 2, 1, 3, 0, 0,' in descriptor
    assert "chain2s_gyro_h_soa}" in descriptor


def test_soa_kernels_compute_shared_work_once_before_the_loop(chain_files):
    """What depends only on p, dt and constants (here g/l, the damping, the spring, dt/2, dt/6) is evaluated once
    per call, before the loop over particles; sin stays in the loop (libmvec's vector sin)."""
    text = chain_files["chain3_soa.c"]
    kernel = text[text.index("int chain3_f_soa("):]
    before, loop = kernel.split("ABYSSAL_SIMD_LOOP", 1)
    assert before.count("const casadi_real c") >= 6 and "a2[" in before and "a3[" in before
    loop = loop[: loop.index("return 0;")]
    assert "a2[" not in loop and "a3[" not in loop and "sin(" in loop and "sin(" not in before
