"""`abyssal verify` section for seed 003 (terrain-aided navigation), on the tan3dof bundle only.

* fuzzy_sigma (generated C) vs scikit-fuzzy's ControlSystem (an independent Mamdani
  implementation) on a grid over the domain and beyond it (inputs clipped): Table 1's rules, the
  same triangular memberships; scikit-fuzzy's input universe [-20, 20] in steps of 2/3 (the
  membership peaks are nodes, so its interpolated memberships are exact) and its output universe
  [1, 7] in steps of 1e-3. Our centroid is the exact one of the continuous aggregated membership;
  scikit-fuzzy's is that of a piecewise-linear interpolant on its universe (plus the cut points it
  inserts), which converges to it as O(h^2): measured 1.6e-3 / 1.5e-5 / 1.5e-7 m at h = 0.1 / 0.01
  / 0.001. Tolerance 1e-6 m at h = 1e-3.
* fuzzy_sigma (generated C) vs CasADi's evaluation of the SX expression: <= 1e-12.
* The bathymetry lookup (compiled kernel) vs scipy's RegularGridInterpolator (linear) at random
  points of both maps, inside the grid: depth <= 1e-9 m; the kernel's gradient vs central
  differences of its own depth away from cell edges <= 1e-6.
* tan3dof's step through omega = 0: f at omega = 0 vs the straight-line step, and f at small
  omega vs the arc formula of eq. 1 (corrected y row) in extended precision (mpmath-free: the
  arc in long double via numpy.longdouble).
"""
from __future__ import annotations

import numpy as np

from .report import Check

SKFUZZY_OUTPUT_STEP = 1e-3


def _skfuzzy_system():
    import skfuzzy as fuzz
    from skfuzzy import control as ctrl

    from abyssal.symbolic import fuzzy

    lo, hi = fuzzy.INPUT_DOMAIN
    u_in = np.linspace(lo, hi, 61)
    u_out = np.linspace(1.0, 7.0, int(round(6.0 / SKFUZZY_OUTPUT_STEP)) + 1)
    gradient = ctrl.Antecedent(u_in, "gradient")
    rate = ctrl.Antecedent(u_in, "gradient_rate")
    sigma = ctrl.Consequent(u_out, "sigma", defuzzify_method="centroid")
    half = (hi - lo) / 6.0
    for peak, term in zip(fuzzy.input_peaks(), fuzzy.INPUT_TERMS):
        gradient[term] = fuzz.trimf(u_in, [peak - half, peak, peak + half])
        rate[term] = fuzz.trimf(u_in, [peak - half, peak, peak + half])
    for peak, term in zip(fuzzy.OUTPUT_PEAKS, fuzzy.OUTPUT_TERMS):
        sigma[term] = fuzz.trimf(u_out, [peak - 1.0, peak, peak + 1.0])
    rules = [ctrl.Rule(rate[fuzzy.INPUT_TERMS[i]] & gradient[fuzzy.INPUT_TERMS[j]], sigma[fuzzy.RULES[i][j]])
             for i in range(7) for j in range(7)]
    return ctrl.ControlSystemSimulation(ctrl.ControlSystem(rules))


def _fuzzy_points() -> np.ndarray:
    grid = np.linspace(-24.0, 24.0, 9)
    G, R = np.meshgrid(grid, grid)
    rng = np.random.default_rng(3)
    return np.vstack([np.column_stack([G.ravel(), R.ravel()]), rng.uniform(-20, 20, (20, 2))])


def fuzzy_checks(bundle) -> list[Check]:

    from abyssal.symbolic import fuzzy

    compiled = bundle.function("fuzzy_sigma")
    symbolic = fuzzy.fuzzy_sigma_function()
    points = _fuzzy_points()
    ours = np.array([float(compiled(g, r)[0]) for g, r in points])
    casadi_values = np.array([float(symbolic(g, r)) for g, r in points])
    out = [Check(bundle.name, "fuzzy_sigma C vs CasADi on the domain grid", "CasADi SX evaluation",
                 float(np.abs(ours - casadi_values).max()), 1e-12)]
    try:
        sim = _skfuzzy_system()
    except ImportError as exc:
        return out + [Check.skip(bundle.name, "fuzzy_sigma vs scikit-fuzzy", "skfuzzy.control",
                                 f"scikit-fuzzy (and networkx) are needed: {exc}")]
    reference = np.empty(len(points))
    for k, (g, r) in enumerate(points):
        sim.input["gradient"], sim.input["gradient_rate"] = g, r
        sim.compute()
        reference[k] = sim.output["sigma"]
    worst = int(np.argmax(np.abs(ours - reference)))
    out.append(Check(bundle.name, f"fuzzy_sigma vs scikit-fuzzy ({len(points)} points)",
                     f"skfuzzy.control, output universe step {SKFUZZY_OUTPUT_STEP:g}",
                     float(np.abs(ours - reference).max()), 1e-6,
                     f"worst at gradient, rate = {points[worst]}: {ours[worst]} vs {reference[worst]}"))
    return out


def map_checks(name: str) -> list[Check]:
    from scipy.interpolate import RegularGridInterpolator

    from abyssal.runtime.experiments.tan.scenario import get_map

    terrain = get_map(name)
    xg, yg = terrain.node_coordinates()
    x_min, x_max, y_min, y_max = terrain.extent
    rng = np.random.default_rng(7)
    x = np.concatenate([rng.uniform(x_min, x_max, 20000), xg[[0, -1]], [x_max, x_min]])
    y = np.concatenate([rng.uniform(y_min, y_max, 20000), yg[[0, -1]], [y_min, y_max]])
    depth, gx, gy, inside = terrain.lookup(x, y)
    reference = RegularGridInterpolator((yg, xg), terrain.depth, method="linear")(np.column_stack([y, x]))
    out = [Check("tan3dof", f"{name} map: bilinear depth", "scipy RegularGridInterpolator",
                 float(np.abs(depth - reference).max()), 1e-9),
           Check("tan3dof", f"{name} map: inside flag on the grid", "extent", float((~inside).sum()), 0.0)]
    # gradient vs central differences of the kernel's own depth, away from cell edges
    frac_x = (x - x_min) / terrain.resolution % 1.0
    frac_y = (y - y_min) / terrain.resolution % 1.0
    sel = (np.abs(frac_x - 0.5) < 0.45) & (np.abs(frac_y - 0.5) < 0.45)
    h = 1e-3
    dx = (terrain.depth_at(x[sel] + h, y[sel]) - terrain.depth_at(x[sel] - h, y[sel])) / (2 * h)
    dy = (terrain.depth_at(x[sel], y[sel] + h) - terrain.depth_at(x[sel], y[sel] - h)) / (2 * h)
    out.append(Check("tan3dof", f"{name} map: gradient", "central differences of the depth",
                     float(max(np.abs(dx - gx[sel]).max(), np.abs(dy - gy[sel]).max())), 1e-6))
    # outside: clamped onto the grid, flagged, gradient 0 -- never an index error
    d_out, gx_out, _, in_out = terrain.lookup(np.array([x_min - 1e4, np.nan]), np.array([y_max + 1.0, 0.0]))
    out.append(Check("tan3dof", f"{name} map: outside points flagged, finite", "definition",
                     float(in_out.sum() + (~np.isfinite(d_out)).sum() + np.abs(gx_out).sum()), 0.0))
    return out


def step_checks(bundle) -> list[Check]:
    x = np.array([100.0, -50.0, 0.7])
    dt = 1.0
    worst_zero = float(np.abs(bundle.f(x, [0.5, 0.0], [0.0, 0.0], dt) - (x + [0.5 * np.cos(0.7), 0.5 * np.sin(0.7), 0.0])).max())
    worst_arc = 0.0
    for omega in (1e-6, 1e-4, 3e-3, 2e-2, 0.3, -0.3):
        v, w, th = np.longdouble(0.5), np.longdouble(omega), np.longdouble(0.7)
        arc = np.array([x[0] + float(v / w * (np.sin(th + w) - np.sin(th))),
                        x[1] + float(v / w * (np.cos(th) - np.cos(th + w))), x[2] + omega])
        worst_arc = max(worst_arc, float(np.abs(bundle.f(x, [0.5, omega], [0.0, 0.0], dt) - arc).max()))
    return [Check(bundle.name, "step at omega = 0", "straight line", worst_zero, 1e-12),
            Check(bundle.name, "step vs the arc of eq. 1 (y row corrected)", "arc in long double, |omega| >= 1e-6",
                  worst_arc, 1e-9)]


def checks(bundle, target=None) -> list[Check]:
    if bundle.name != "tan3dof" or (target is not None and not getattr(target, "builtin", True)):
        return []
    return fuzzy_checks(bundle) + step_checks(bundle) + map_checks("arctic") + map_checks("topobathy")
