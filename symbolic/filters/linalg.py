"""Small dense linear algebra on CasADi SX, written out so the generated C never produces NaN.

CasADi's SX ``chol`` has no pivoting and returns NaN on a matrix that is not positive
definite. ``guarded_cholesky`` instead clamps every pivot and returns a flag ``ok`` (1 when all
pivots passed, else 0): the C stays finite and the runtime decides (eigenvalue repair, see
abyssal.runtime.filters.kalman). Everything here works on dense SX matrices of known size.
"""
from __future__ import annotations

import math

import casadi as ca

#: a pivot d_j of A = L L^T passes when d_j > PIVOT_RELATIVE * A_jj + PIVOT_ABSOLUTE. d_j / A_jj is the
#: variance of state j given the states before it over its variance, so the guard trips on matrices that
#: are indefinite or singular to within roundoff (condition number beyond ~1e13).
PIVOT_RELATIVE = 1e-13
PIVOT_ABSOLUTE = 1e-300


def is_mirrored(A: ca.SX) -> bool:
    """Whether A is symmetric by construction: every A[j, i] is the same expression as A[i, j].

    Same expression means the same node, or the same operation on the same nodes (CasADi's
    ``is_equal`` at depth 1, which also matches a commutative operation with swapped operands:
    the sum of two mirrored matrices is mirrored).
    """
    n = A.size1()
    if A.size2() != n:
        return False
    return all(ca.is_equal(A[i, j], A[j, i], 1) for i in range(n) for j in range(i + 1, n))


def symmetrise(A: ca.SX) -> ca.SX:
    """(A + A^T) / 2, as one expression per pair i < j mirrored below the diagonal.

    Costs nothing where it is not needed: the diagonal is A[i, i] itself ((a + a) / 2 == a in
    IEEE arithmetic, barring overflow), and a matrix that is already symmetric by construction
    (``is_mirrored``: a step's own P_pred, a congruence, a weighted outer product) is returned
    as it is instead of paying two additions and two halvings per pair.
    """
    if is_mirrored(A):
        return A
    n = A.size1()
    entries = {(i, j): A[i, i] if i == j else (A[i, j] + A[j, i]) / 2 for i in range(n) for j in range(i, n)}
    return symmetric_from_upper(entries, n)


def symmetric_from_upper(entries: dict[tuple[int, int], ca.SX], n: int) -> ca.SX:
    """n x n SX matrix from its entries (i, j), i <= j, mirrored below the diagonal."""
    A = ca.SX.zeros(n, n)
    for (i, j), value in entries.items():
        A[i, j] = value
        A[j, i] = value
    return A


def upper_mirrored(A: ca.SX) -> ca.SX:
    """A's upper triangle mirrored below the diagonal (exactly symmetric output for any input)."""
    n = A.size1()
    return symmetric_from_upper({(i, j): A[i, j] for i in range(n) for j in range(i, n)}, n)


def weight_groups(weights) -> list[tuple[ca.SX, list[int]]]:
    """(weight, [k, ...]) for each distinct weight (the same expression), in order of first use."""
    groups: list[tuple[ca.SX, list[int]]] = []
    for k, w in enumerate(weights):
        w = ca.SX(w)
        for weight, ks in groups:
            if ca.is_equal(weight, w, 1):
                ks.append(k)
                break
        else:
            groups.append((w, [k]))
    return groups


def _grouped_sum(weights, term) -> ca.SX:
    """sum_k w_k term(k), with each distinct weight multiplied once onto the sum of its terms.

    Sigma-point rules repeat one weight over almost all points (cubature: 1/(2n) for all 2n;
    unscented: one centre weight and 1/(2c) for the 2n others), so this takes one or two
    products per entry instead of one per point. Equal to the per-point weighting up to
    rounding; only the overflow threshold moves (the unweighted sum of a group overflows when
    its terms approach 1e308 / (number of points), which then gives ok = 0).
    """
    return sum((w * ca.sum1(ca.vertcat(*[term(k) for k in ks])) for w, ks in weight_groups(weights)), ca.SX(0))


def weighted_sum(Y: ca.SX, weights) -> ca.SX:
    """sum_k w_k Y[:, k] (a weighted mean of points), weights grouped as in _grouped_sum."""
    return ca.vertcat(*[_grouped_sum(weights, lambda k, i=i: Y[i, k]) for i in range(Y.size1())])


def weighted_outer(D: ca.SX, weights, E: ca.SX | None = None) -> ca.SX:
    """sum_k w_k D[:, k] E[:, k]^T; symmetric (computed once per pair) when E is None. Weights grouped."""
    if E is None:
        n = D.size1()
        entries = {(i, j): _grouped_sum(weights, lambda k, i=i, j=j: D[i, k] * D[j, k])
                   for i in range(n) for j in range(i, n)}
        return symmetric_from_upper(entries, n)
    C = ca.SX.zeros(D.size1(), E.size1())
    for i in range(D.size1()):
        for j in range(E.size1()):
            C[i, j] = _grouped_sum(weights, lambda k, i=i, j=j: D[i, k] * E[j, k])
    return C


def congruence(A: ca.SX, P: ca.SX, PAt: ca.SX | None = None) -> ca.SX:
    """A P A^T for symmetric P, computed on and above the diagonal only and mirrored (exactly symmetric).

    PAt = P A^T (computed here unless given). Entry (i, j) is A[i, :] PAt[:, j], or equally
    (P symmetric) A[j, :] PAt[:, i]: the row of A with fewer structural nonzeros is used, so a
    sparse A (the Jacobian of a step: rov4dof's F has rows of 1 to 8 nonzeros) costs about half
    the products of always taking row i.
    """
    if PAt is None:
        PAt = ca.mtimes(P, A.T)
    m = A.size1()
    row_nnz = [A[i, :].nnz() for i in range(m)]

    def entry(i, j):
        if row_nnz[j] < row_nnz[i]:
            i, j = j, i
        return ca.mtimes(A[i, :], PAt[:, j])

    return symmetric_from_upper({(i, j): entry(i, j) for i in range(m) for j in range(i, m)}, m)


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

    Each distinct expression is summed once (a symmetric matrix built by mirroring contributes
    its upper triangle only: the mirrored entries are the same values). Relies on IEEE
    semantics: compiling with -ffast-math (-ffinite-math-only) would let the compiler fold this
    test to 1.
    """
    seen: set[int] = set()
    terms = []
    for e in exprs:
        for k in range(e.nnz()):
            term = e.nz[k]
            key = term.element_hash()
            if key not in seen:
                seen.add(key)
                terms.append(term)
    return ca.fabs(ca.sum1(ca.vertcat(*terms))) < math.inf
