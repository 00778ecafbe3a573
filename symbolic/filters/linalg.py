"""Small dense linear algebra on CasADi SX, written out so the generated C never produces NaN.

CasADi's SX ``chol`` has no pivoting and returns NaN on a matrix that is not positive
definite. ``guarded_cholesky`` instead clamps every pivot and returns a flag ``ok`` (1 when all
pivots passed, else 0): the C stays finite and the runtime decides (eigenvalue repair, see
abyssal.runtime.kalman). Everything here works on dense SX matrices of known size.
"""
from __future__ import annotations

import math

import casadi as ca

#: a pivot d_j of A = L L^T passes when d_j > PIVOT_RELATIVE * A_jj + PIVOT_ABSOLUTE. d_j / A_jj is the
#: variance of state j given the states before it over its variance, so the guard trips on matrices that
#: are indefinite or singular to within roundoff (condition number beyond ~1e13).
PIVOT_RELATIVE = 1e-13
PIVOT_ABSOLUTE = 1e-300


def symmetrise(A: ca.SX) -> ca.SX:
    """(A + A^T) / 2."""
    return (A + A.T) / 2


def symmetric_from_upper(entries: dict[tuple[int, int], ca.SX], n: int) -> ca.SX:
    """n x n SX matrix from its entries (i, j), i <= j, mirrored below the diagonal."""
    A = ca.SX.zeros(n, n)
    for (i, j), value in entries.items():
        A[i, j] = value
        A[j, i] = value
    return A


def weighted_outer(D: ca.SX, weights, E: ca.SX | None = None) -> ca.SX:
    """sum_k w_k D[:, k] E[:, k]^T; symmetric (computed once per pair) when E is None."""
    npts = D.size2()
    if E is None:
        n = D.size1()
        entries = {
            (i, j): ca.sum1(ca.vertcat(*[weights[k] * D[i, k] * D[j, k] for k in range(npts)]))
            for i in range(n) for j in range(i, n)
        }
        return symmetric_from_upper(entries, n)
    C = ca.SX.zeros(D.size1(), E.size1())
    for i in range(D.size1()):
        for j in range(E.size1()):
            C[i, j] = ca.sum1(ca.vertcat(*[weights[k] * D[i, k] * E[j, k] for k in range(npts)]))
    return C


def congruence(A: ca.SX, P: ca.SX) -> ca.SX:
    """A P A^T for symmetric P, computed on and below the diagonal only and mirrored (exactly symmetric)."""
    AP = ca.mtimes(A, P)
    n = A.size1()
    entries = {(i, j): ca.mtimes(AP[j, :], A[i, :].T) for i in range(n) for j in range(i, n)}
    return symmetric_from_upper(entries, n)


def guarded_cholesky(A: ca.SX) -> tuple[ca.SX, ca.SX]:
    """Lower-triangular L with A ~ L L^T, and ok (1 or 0).

    Reads only the lower triangle of A (symmetrise first). A pivot that fails the guard
    (see PIVOT_RELATIVE) is replaced by its threshold, so L is always finite for finite A.
    """
    n = A.size1()
    L = ca.SX.zeros(n, n)
    ok = ca.SX(1)
    for j in range(n):
        d = A[j, j] - sum((L[j, k] * L[j, k] for k in range(j)), ca.SX(0))
        threshold = PIVOT_RELATIVE * ca.fabs(A[j, j]) + PIVOT_ABSOLUTE
        ok = ok * (d > threshold)
        L[j, j] = ca.sqrt(ca.fmax(d, threshold))
        inverse_pivot = 1 / L[j, j]  # one division per column
        for i in range(j + 1, n):
            L[i, j] = (A[i, j] - sum((L[i, k] * L[j, k] for k in range(j)), ca.SX(0))) * inverse_pivot
    return L, ok


def forward_substitute(L: ca.SX, B: ca.SX) -> ca.SX:
    """X with L X = B for lower-triangular L."""
    n, m = B.shape
    X = ca.SX.zeros(n, m)
    for c in range(m):
        for i in range(n):
            X[i, c] = (B[i, c] - sum((L[i, k] * X[k, c] for k in range(i)), ca.SX(0))) / L[i, i]
    return X


def backward_substitute_transposed(L: ca.SX, B: ca.SX) -> ca.SX:
    """X with L^T X = B for lower-triangular L."""
    n, m = B.shape
    X = ca.SX.zeros(n, m)
    for c in range(m):
        for i in reversed(range(n)):
            X[i, c] = (B[i, c] - sum((L[k, i] * X[k, c] for k in range(i + 1, n)), ca.SX(0))) / L[i, i]
    return X


def cholesky_solve(L: ca.SX, B: ca.SX) -> ca.SX:
    """X with (L L^T) X = B."""
    return backward_substitute_transposed(L, forward_substitute(L, B))


def wrap_angle(d):
    """d wrapped to (-pi, pi]; exactly d (bitwise) when d is already in that interval."""
    return d - 2 * math.pi * ca.ceil((d - math.pi) / (2 * math.pi))


def all_finite(*exprs) -> ca.SX:
    """1 when every entry of the expressions is finite (a NaN or inf makes the sum non-finite).

    Relies on IEEE semantics: compiling with -ffast-math (-ffinite-math-only) would let the
    compiler fold this test to 1.
    """
    total = ca.sum1(ca.vertcat(*[ca.vec(e) for e in exprs]))
    return ca.fabs(total) < math.inf
