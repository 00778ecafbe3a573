"""Seed 003's Mamdani system (abyssal.symbolic.fuzzy): closed-form centroid vs brute force, rules, symmetry."""
import casadi as ca
import numpy as np
import pytest

from abyssal.symbolic import fuzzy
from abyssal.symbolic.models.tan3dof import sinc, tan3dof

SIGMA = fuzzy.fuzzy_sigma_function()


def brute_force_sigma(g: float, r: float, step: float = 1e-4) -> float:
    """Min/max Mamdani with the centroid of the aggregated membership sampled every `step` (NumPy, no SX)."""
    lo, hi = fuzzy.INPUT_DOMAIN
    half = (hi - lo) / 6
    g, r = np.clip(g, lo, hi), np.clip(r, lo, hi)
    mu_g = [max(0.0, 1 - abs(g - c) / half) for c in fuzzy.input_peaks()]
    mu_r = [max(0.0, 1 - abs(r - c) / half) for c in fuzzy.input_peaks()]
    y = np.arange(1.0, 7.0 + step / 2, step)
    strength = dict.fromkeys(fuzzy.OUTPUT_TERMS, 0.0)
    for i in range(7):
        for j in range(7):
            term = fuzzy.RULES[i][j]
            strength[term] = max(strength[term], min(mu_r[i], mu_g[j]))
    mu = np.zeros_like(y)
    for term, peak in zip(fuzzy.OUTPUT_TERMS, fuzzy.OUTPUT_PEAKS):
        mu = np.maximum(mu, np.minimum(strength[term], np.maximum(0.0, 1 - np.abs(y - peak))))
    return float(np.trapezoid(y * mu, y) / np.trapezoid(mu, y))


@pytest.mark.parametrize("g, r", [(0.0, 0.0), (20.0, 20.0), (-20.0, 20.0), (3.1, -7.7), (-11.0, 16.2), (9.5, 2.2),
                                  (6.6667, -13.3333), (19.0, -1.0)])
def test_closed_form_centroid_matches_brute_force(g, r):
    assert float(SIGMA(g, r)) == pytest.approx(brute_force_sigma(g, r), abs=1e-6)


def test_a_single_fired_rule_gives_its_term_centroid():
    peaks = fuzzy.input_peaks()
    for i in range(7):
        for j in range(7):
            term = fuzzy.RULES[i][j]
            expected = {"SS": 4 / 3, "LL": 20 / 3}.get(term, float(fuzzy.OUTPUT_TERMS.index(term) + 1))
            assert float(SIGMA(peaks[j], peaks[i])) == pytest.approx(expected, abs=1e-12), (i, j, term)


def test_table_1_is_point_symmetric_and_inputs_are_clipped():
    rng = np.random.default_rng(0)
    for g, r in rng.uniform(-20, 20, (50, 2)):
        assert float(SIGMA(g, r)) == pytest.approx(float(SIGMA(-g, -r)), abs=1e-12)
    assert float(SIGMA(35.0, -99.0)) == float(SIGMA(20.0, -20.0))
    values = [float(SIGMA(g, r)) for g, r in rng.uniform(-30, 30, (200, 2))]
    assert min(values) >= 4 / 3 - 1e-12 and max(values) <= 20 / 3 + 1e-12


def test_steep_terrain_gives_small_and_flat_terrain_large_sigma():
    assert float(SIGMA(0.0, 0.0)) == pytest.approx(20 / 3)   # flat: LL
    assert float(SIGMA(20.0, 20.0)) == pytest.approx(4 / 3)  # steep and steepening: SS


def test_scikit_fuzzy_agrees_on_a_fine_universe():
    pytest.importorskip("networkx")
    from abyssal.verify.tan import _skfuzzy_system

    sim = _skfuzzy_system()
    for g, r in [(0.0, 0.0), (4.0, -3.0), (-15.0, 12.0)]:
        sim.input["gradient"], sim.input["gradient_rate"] = g, r
        sim.compute()
        assert sim.output["sigma"] == pytest.approx(float(SIGMA(g, r)), abs=1e-6)


def test_sinc_is_exact_and_smooth_through_zero():
    a = ca.SX.sym("a")
    f = ca.Function("f", [a], [sinc(a), ca.jacobian(sinc(a), a)])
    for value in [0.0, 1e-12, -1e-6, 5e-3, -9.99e-3, 1.001e-2, 0.3, -2.0]:
        s, ds = (float(v) for v in f(value))
        if value == 0.0:
            assert s == 1.0 and ds == 0.0
            continue
        exact = np.sin(np.longdouble(value)) / np.longdouble(value)
        d_exact = (np.cos(np.longdouble(value)) * value - np.sin(np.longdouble(value))) / np.longdouble(value) ** 2
        assert s == pytest.approx(float(exact), rel=1e-15, abs=1e-16)
        assert ds == pytest.approx(float(d_exact), rel=1e-9, abs=1e-12)


def test_tan3dof_is_a_discrete_model_with_the_misprint_fixed():
    model = tan3dof()
    assert model.is_discrete and model.n_w == 4 and [p.name for p in model.parameters] == ["d_x", "d_y"]
    step = ca.Function("s", [model.x, model.u, model.p, model.w, model.dt], [model.x_next])
    x = np.array([1.0, 2.0, 0.4])
    out = np.array(step(x, [0.5, 0.2], [0.1, -0.2], [0, 0, 0, 0], 2.0)).ravel()
    v, w, th, dt = 0.5, 0.2, 0.4, 2.0
    arc = [x[0] + v / w * (np.sin(th + w * dt) - np.sin(th)) + 0.1 * dt,
           x[1] + v / w * (np.cos(th) - np.cos(th + w * dt)) - 0.2 * dt, th + w * dt]  # eq. 1, y row corrected
    np.testing.assert_allclose(out, arc, rtol=0, atol=1e-13)
