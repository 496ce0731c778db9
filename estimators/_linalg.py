"""Small dense linear algebra on one filter's arrays, for the compiled row functions.

The laws of the bank (:func:`estimators.kf.kf_update_row`, :func:`estimators.mckf.mckf_update_row`,
:func:`estimators.pca.pca_row`, …) are written once, as :func:`estimators._jit.njit` functions on
one filter's float64 arrays; the scalar classes call them on their own arrays and the batched
kernels of :mod:`estimators.batched` loop over the rows calling them.  These are their building
blocks.

Every product accumulates its sum from 0.0 in index order and stores it before any further
operation, so results do not depend on where a row lives (determinism of the lockstep engine).
Products with a transpose pass a transposed view (``mat_mul(P, H.T, PHT)`` = P Hᵀ): same
elements, same order.
"""

from __future__ import annotations

import math

import numpy as np

from numkit import X, Y, Z

from ._jit import njit

__all__ = ["add_into", "chol", "chol_inv_lower", "copy_vec", "inv_small_into", "mat_mul",
           "mat_vec", "quad_form", "safe_cholesky_into", "scale"]


@njit(inline="always")
def mat_vec(A, x, out):
    """out = A x."""
    for r in range(A.shape[0]):
        s = 0.0
        for k in range(A.shape[1]):
            s += A[r, k] * x[k]
        out[r] = s


@njit(inline="always")
def mat_mul(A, B, out):
    """out = A B."""
    for r in range(A.shape[0]):
        for c in range(B.shape[1]):
            s = 0.0
            for k in range(A.shape[1]):
                s += A[r, k] * B[k, c]
            out[r, c] = s


@njit(inline="always")
def mat_mul_sparse(A, B, out):
    """out = A B skipping A's zero entries (a measurement matrix H: few states per row).  The
    sums are those of :func:`mat_mul` (a skipped term adds an exact 0) for finite B: each
    out[r, c] starts at 0 and takes A[r, k] B[k, c] in ascending k.  P Hᵀ is
    ``mat_mul_sparse(H, P.T, PHT.T)``: the same products, summed in the same order."""
    for r in range(A.shape[0]):
        for c in range(B.shape[1]):
            out[r, c] = 0.0
        for k in range(A.shape[1]):
            a = A[r, k]
            if a != 0.0:
                for c in range(B.shape[1]):
                    out[r, c] += a * B[k, c]


@njit
def copy_vec(a, out):
    """out[:] = a (1-D; a plain loop compiles much faster than numba's slice assignment)."""
    for k in range(a.shape[0]):
        out[k] = a[k]


@njit
def add_into(out, B):
    """out += B."""
    for r in range(out.shape[0]):
        for c in range(out.shape[1]):
            out[r, c] = out[r, c] + B[r, c]


@njit
def scale(alpha, A, out):
    """out = α A."""
    for r in range(A.shape[0]):
        for c in range(A.shape[1]):
            out[r, c] = alpha * A[r, c]


@njit
def quad_form(M, v):
    """vᵀ M v, summed as Σ_a v_a (Σ_b M_ab v_b)."""
    q = 0.0
    for a in range(v.shape[0]):
        s = 0.0
        for b in range(v.shape[0]):
            s += M[a, b] * v[b]
        q += v[a] * s
    return q


@njit
def inv_small_into(S, Si):
    """Si = S⁻¹: closed forms (adjugate / determinant) for m ≤ 3, as
    :func:`estimators.kf.inv_small`; LAPACK (``numpy.linalg.inv``) above."""
    m = S.shape[0]
    if m == 1:
        Si[0, 0] = 1.0 / S[0, 0]
    elif m == 2:
        a, b, c, d = S[0, 0], S[0, 1], S[1, 0], S[1, 1]
        det = a * d - b * c
        Si[0, 0] = d / det
        Si[0, 1] = -b / det
        Si[1, 0] = -c / det
        Si[1, 1] = a / det
    elif m == 3:  # a 3-axis covariance (x, y, z): S⁻¹ = adj(S) / det S
        a, b, c = S[X, X], S[X, Y], S[X, Z]
        d, e, f = S[Y, X], S[Y, Y], S[Y, Z]
        g, h, k = S[Z, X], S[Z, Y], S[Z, Z]
        c00, c01, c02 = e * k - f * h, f * g - d * k, d * h - e * g  # cofactors of row x
        det = a * c00 + b * c01 + c * c02
        Si[X, X] = c00 / det
        Si[X, Y] = (c * h - b * k) / det
        Si[X, Z] = (b * f - c * e) / det
        Si[Y, X] = c01 / det
        Si[Y, Y] = (a * k - c * g) / det
        Si[Y, Z] = (c * d - a * f) / det
        Si[Z, X] = c02 / det
        Si[Z, Y] = (b * g - a * h) / det
        Si[Z, Z] = (a * e - b * d) / det
    else:
        _inv_lapack(S, Si)


@njit
def _inv_lapack(S, Si):
    """Si = S⁻¹ by LAPACK (m > 3; kept out of :func:`inv_small_into` so that the closed forms
    stay small enough to inline)."""
    m = S.shape[0]
    Sc = np.empty((m, m))
    for r in range(m):
        for c in range(m):
            Sc[r, c] = S[r, c]
    inv = np.linalg.inv(Sc)
    for r in range(m):
        for c in range(m):
            Si[r, c] = inv[r, c]


@njit
def chol(P, L, rel):
    """Lower Cholesky factor of P into L; False if a pivot d fails the test: LAPACK's dpotrf
    ``d > 0`` for rel = 0, ``d > rel · P_jj`` for rel > 0 (the MCKF's relative pivot test
    ``REL_PIVOT``: a nearly singular P̄ is left to :func:`safe_cholesky_into`)."""
    n = P.shape[0]
    for j in range(n):
        acc = 0.0
        for k in range(j):
            acc += L[j, k] * L[j, k]
        d = P[j, j] - acc
        if not (d > rel * P[j, j] if rel > 0.0 else d > 0.0):
            return False
        ljj = math.sqrt(d)
        L[j, j] = ljj
        for i in range(j + 1, n):
            acc = 0.0
            for k in range(j):
                acc += L[i, k] * L[j, k]
            L[i, j] = (P[i, j] - acc) / ljj
        for i in range(j):
            L[i, j] = 0.0
    return True


@njit
def safe_cholesky_into(P, L):
    """Lower Cholesky factor of a covariance that may have lost definiteness in floating point:
    P as it is; else symmetrised with a jitter 1e-12 · max|diag| growing ×10 (20 tries); else
    its eigenvalues floored at 1e-12 · max|diag|."""
    if chol(P, L, 0.0):
        return
    n = P.shape[0]
    Ps = 0.5 * (P + P.T)
    sc = 0.0
    for j in range(n):
        v = abs(Ps[j, j])
        if v > sc:
            sc = v
    sc = max(sc, 1e-300)
    jitter = 1e-12 * sc
    for _ in range(20):
        Pj = Ps.copy()
        for j in range(n):
            Pj[j, j] += jitter
        if chol(Pj, L, 0.0):
            return
        jitter *= 10.0
    w, V = np.linalg.eigh(Ps)
    w = np.maximum(w, 1e-12 * sc)
    Pr = (V * w) @ V.T
    chol(Pr, L, 0.0)


@njit
def chol_inv_lower(R, Binv, Lr):
    """B⁻¹ with R = B Bᵀ (B lower, into Lr); B⁻¹ by forward substitution."""
    m = R.shape[0]
    chol(R, Lr, 0.0)
    for c in range(m):
        for r in range(m):
            if r < c:
                Binv[r, c] = 0.0
                continue
            s = 1.0 if r == c else 0.0
            for k in range(c, r):
                s -= Lr[r, k] * Binv[k, c]
            Binv[r, c] = s / Lr[r, r]
