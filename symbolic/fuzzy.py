"""Mamdani fuzzy inference as CasADi SX: the process-noise rule base of seed 003 (section 3.2).

Seed 003 sets the particle filter's environment process noise sigma from two terrain inputs,
gradient and gradient rate, with a 7 x 7 Mamdani rule base (Table 1). This module writes that
inference as one closed SX expression, so it is generated to C like any model equation
(``tan3dof_fuzzy_sigma``) and evaluated in a few dozen floating-point operations.

The system (decisions where the paper is silent or inconsistent are marked DECISION):

* Inputs: gradient and gradient rate, each with seven terms NB, NM, NS, ZO, PS, PM, PB.
  Domain [-20, 20] for both (Table 2; the text of section 4.1 says [-25, 25] -- DECISION: the
  table, which also matches Fig. 6). Triangular memberships with peaks evenly spaced at
  -20, -13.3, ..., 20 and one spacing (40/6) as half-width, so the memberships of any input sum
  to one. Inputs are clipped to the domain first.
* Output: sigma in metres on the universe [1, 7] with seven terms SS, S, SM, M, ML, L, LL:
  triangles with peaks 1, 2, ..., 7 and half-width 1 (the outer halves of SS and LL fall outside
  the universe, so the output spans 1.33 ... 6.67 m, as scikit-fuzzy's does).
* Rules: Table 1, rows = gradient rate, columns = gradient. AND and implication by min,
  aggregation by max, defuzzification by the centroid.
* Centroid: the exact centroid of the continuous aggregated membership function, in closed
  form (``_cell_area_and_moment``). DECISION: no discretised output universe -- between two
  adjacent output peaks only two clipped triangles overlap, so the area and first moment of
  each unit cell are polynomials of the two firing strengths, written with ``fmin`` only
  (branch-free, vectorisable, exact). A discretised centroid (scikit-fuzzy's) converges to this
  value as its universe is refined; ``abyssal verify`` measures the difference.
"""
from __future__ import annotations

import casadi as ca

INPUT_TERMS = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")
OUTPUT_TERMS = ("SS", "S", "SM", "M", "ML", "L", "LL")

#: Table 1 of seed 003: RULES[rate_term][gradient_term] -> output term (process noise).
RULES = (
    ("SS", "S", "S", "SM", "ML", "L", "LL"),    # rate NB
    ("S", "S", "SM", "M", "L", "ML", "ML"),     # rate NM
    ("S", "SM", "M", "ML", "L", "ML", "SM"),    # rate NS
    ("S", "M", "ML", "LL", "ML", "M", "S"),     # rate ZO
    ("SM", "ML", "L", "ML", "M", "SM", "S"),    # rate PS
    ("ML", "ML", "L", "M", "SM", "S", "S"),     # rate PM
    ("LL", "L", "ML", "SM", "S", "S", "SS"),    # rate PB
)

INPUT_DOMAIN = (-20.0, 20.0)   # Table 2 (gradient range, gradient rate range)
OUTPUT_PEAKS = tuple(float(k) for k in range(1, 8))  # m; universe [1, 7] (Table 2 process noise range)


def input_peaks(domain=INPUT_DOMAIN) -> tuple[float, ...]:
    lo, hi = domain
    return tuple(lo + k * (hi - lo) / 6.0 for k in range(7))


def triangular_memberships(value, domain=INPUT_DOMAIN) -> list:
    """Memberships of the seven input terms at `value` (clipped to the domain); they sum to one."""
    lo, hi = domain
    half_width = (hi - lo) / 6.0
    v = ca.fmin(ca.fmax(value, lo), hi)
    return [ca.fmax(0.0, 1.0 - ca.fabs(v - c) / half_width) for c in input_peaks(domain)]


def rule_strengths(gradient, gradient_rate, domain=INPUT_DOMAIN) -> list:
    """Firing strength of each output term: max over its rules of min(mu_rate, mu_gradient)."""
    mu_g = triangular_memberships(gradient, domain)
    mu_r = triangular_memberships(gradient_rate, domain)
    strengths: list = [None] * len(OUTPUT_TERMS)
    for i, row in enumerate(RULES):
        for j, term in enumerate(row):
            o = OUTPUT_TERMS.index(term)
            fired = ca.fmin(mu_r[i], mu_g[j])
            strengths[o] = fired if strengths[o] is None else ca.fmax(strengths[o], fired)
    return strengths


def _cell_area_and_moment(a, b):
    """Area and first moment (about the cell's left end) of max(min(a, 1-t), min(b, t)), t in [0, 1].

    The descending half of the left term clipped at a, the ascending half of the right term
    clipped at b: int max(f, g) = int f + int g - int min(f, g), and min(f, g) is the unit tent
    min(t, 1-t) clipped at min(a, b), whose integrals depend on c = min(a, b, 1/2) only.
    """
    c = ca.fmin(ca.fmin(a, b), 0.5)
    area = (a - a * a / 2) + (b - b * b / 2) - (c - c * c)
    moment = (a / 2 - a * a / 2 + a ** 3 / 6) + (b / 2 - b ** 3 / 6) - 0.5 * (c - c * c)
    return area, moment


def centroid(strengths) -> ca.SX:
    """Exact centroid over [1, 7] of the max-aggregated output terms clipped at their strengths."""
    area, moment = 0, 0
    for k in range(len(OUTPUT_PEAKS) - 1):  # cell [peak_k, peak_k + 1]
        a_k, m_k = _cell_area_and_moment(strengths[k], strengths[k + 1])
        area = area + a_k
        moment = moment + OUTPUT_PEAKS[k] * a_k + m_k
    # some rule always fires with strength >= 1/2 (the input memberships sum to one), so the
    # area is >= 1/8; the guard only keeps the expression total
    return moment / ca.fmax(area, 1e-12)


def fuzzy_sigma(gradient, gradient_rate, domain=INPUT_DOMAIN) -> ca.SX:
    """Process-noise sigma (m) of seed 003's fuzzy logic for one (gradient, gradient rate) pair."""
    return centroid(rule_strengths(gradient, gradient_rate, domain))


def fuzzy_sigma_function(name: str = "fuzzy_sigma", domain=INPUT_DOMAIN) -> ca.Function:
    """``name(gradient, gradient_rate) -> sigma`` as a CasADi Function (scalars)."""
    g, r = ca.SX.sym("gradient"), ca.SX.sym("gradient_rate")
    return ca.Function(name, [g, r], [fuzzy_sigma(g, r, domain)], ["gradient", "gradient_rate"], ["sigma"],
                       {"cse": True})
