"""Hypothesis strategies for arguments of the public entry points, valid and invalid, and the
classification of a drawn argument (is it one the contract must refuse?).

An argument is drawn as a ``Drawn(value, problem)`` where ``problem`` is None for a value the
contract accepts and a short description otherwise, so a test can state the expected outcome:
a refusal (ValueError/TypeError naming one of the arguments with a problem) or a result.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from hypothesis import strategies as st

#: finite values that stress arithmetic without being invalid
AWKWARD_FINITE = (0.0, -0.0, 1e-300, -5e-324, 1e-8, 1e8, 1e200, -1e300, 1.7e308)
NON_FINITE = (np.nan, np.inf, -np.inf)


@dataclass(frozen=True)
class Drawn:
    value: object
    problem: str | None = None

    def __repr__(self):
        return f"Drawn({self.value!r}, problem={self.problem!r})"


def moderate(scale: float = 10.0):
    return st.floats(-scale, scale, allow_nan=False, allow_infinity=False)


def _finite_entries(scale: float, awkward: bool):
    if not awkward:
        return moderate(scale)
    return st.one_of(moderate(scale), moderate(scale), moderate(scale), st.sampled_from(AWKWARD_FINITE))


@st.composite
def vectors(draw, n: int, *, scale: float = 10.0, nan_ok: bool = False, none_ok: bool = False,
            awkward: bool = True, name: str = "v"):
    """A (n,) argument: mostly valid (float64 arrays, other real dtypes, lists), sometimes not
    (non-finite entries, wrong shape, complex, strings, None)."""
    base = np.array(draw(st.lists(_finite_entries(scale, awkward), min_size=n, max_size=n)), dtype=np.float64)
    kind = draw(st.sampled_from(["float64"] * 6 + ["list", "float32", "nonfinite", "nonfinite", "shape",
                                                   "complex", "string", "none", "scalar", "2d"]))
    if kind == "float64":
        return Drawn(base)
    if kind == "list":
        return Drawn(base.tolist())
    if kind == "float32":
        with np.errstate(over="ignore"):
            v = base.astype(np.float32)
        return Drawn(v, None if np.all(np.isfinite(v)) else "non-finite after float32 conversion")
    if kind == "nonfinite":
        v = base.copy()
        i = draw(st.integers(0, n - 1))
        v[i] = draw(st.sampled_from(NON_FINITE))
        if nan_ok and not np.isinf(v).any():
            return Drawn(v)  # NaN marks a missing entry
        return Drawn(v, "non-finite entry")
    if kind == "shape":
        m = draw(st.sampled_from([0, n - 1, n + 1]))
        return Drawn(np.zeros(m), "wrong shape") if m != n else Drawn(base)
    if kind == "complex":
        return Drawn(base + 0j, "complex")
    if kind == "string":
        return Drawn("x" * n, "string")
    if kind == "none":
        return Drawn(None, None if none_ok else "None")
    if kind == "scalar":
        return Drawn(1.0, "scalar") if n != 1 else Drawn(np.array([1.0]))
    return Drawn(base[None, :], "2-D")  # "2d"


def seconds():
    """dt: mostly valid (positive finite), sometimes zero, negative, non-finite, huge, of another type."""
    return st.one_of(
        st.floats(1e-3, 0.5).map(Drawn),
        st.floats(1e-3, 0.5).map(Drawn),
        st.sampled_from([1e-300, 1.0, 5.0, 60.0, 1e6]).map(Drawn),  # valid but beyond a model's stable range
        st.sampled_from([0.0, -0.1, -np.inf, np.inf, np.nan]).map(lambda v: Drawn(v, "not a positive finite number")),
        st.just(Drawn(1, None)),
        st.just(Drawn(np.float64(0.1), None)),
        st.sampled_from([True, "0.1", None, 0.1 + 0j, [0.1]]).map(lambda v: Drawn(v, "not a real number")),
    )


def named(message: str, names) -> bool:
    """Does the error message name one of the arguments (as a word, quoted or not)?"""
    return any(re.search(rf"(?<![A-Za-z0-9_]){re.escape(n)}(?![A-Za-z0-9_])", message) for n in names)


def all_finite(*arrays) -> bool:
    return all(np.all(np.isfinite(np.asarray(a, dtype=np.float64))) for a in arrays)


# ---------------------------------------------------------------------------------------------
# Known bugs in code owned by others, still open. Each is pinned by a strict xfail test
# in test_property_regressions.py (marked with its key) and avoided by the property tests (a class
# in CLASS_BUGS is xfail there; other keys are avoided where `known_bug(key)` is used), so they keep
# checking everything else. When the owner fixes one, its xfail test passes and strict xfail fails
# the run: delete the key below (the xfail test becomes a regression test) and its `known_bug` use.

KNOWN_BUGS = {
}

#: registered filter classes that cannot be fuzzed until a known bug is fixed (their property tests are
#: marked xfail(strict=True) with the bug's reason)
CLASS_BUGS: dict[str, str] = {}



def known_bug(key: str) -> bool:
    return key in KNOWN_BUGS
