"""Maximum correntropy Kalman filter (Chen, Liu, Zhao, Principe, Automatica 80, 2017).

Algorithm 2 of Candan & Li is garbled; this is the original MCKF.

1. Predict as the KF: x̄ = F x̂, P̄ = F P Fᵀ + Q.
2. Lower Cholesky factors P̄ = B_p B_pᵀ, R = B_r B_rᵀ, B = blkdiag(B_p, B_r).
3. Whitened regression D = W x + e with D = B⁻¹[x̄; y], W = B⁻¹[I; H].
4. Fixed point from x̂⁽⁰⁾ = x̄: e = D − W x̂⁽ᵗ⁻¹⁾, G(e) = exp(−e²/(2σ²)) per element,
   C_x = diag(G(e_1..e_n)), C_y = diag(G(e_n+1..e_n+m)), P̃ = B_p C_x⁻¹ B_pᵀ, R̃ = B_r C_y⁻¹ B_rᵀ,
   K̃ = P̃ Hᵀ (H P̃ Hᵀ + R̃)⁻¹, x̂⁽ᵗ⁾ = x̄ + K̃ (y − H x̄)   (innovation against the prior).
   Stop when ‖x̂⁽ᵗ⁾ − x̂⁽ᵗ⁻¹⁾‖ / max(‖x̂⁽ᵗ⁻¹⁾‖, 1) ≤ ε or after ``max_iter`` iterations.
5. P = (I − K̃ H) P̄ (I − K̃ H)ᵀ + K̃ R K̃ᵀ with the ORIGINAL P̄ and R.

Implementation (algebraically identical, numerically guarded)
-------------------------------------------------------------
With u = B_p⁻¹(x̂ − x̄) (whitened correction), ν = y − H x̄, ν_w = B_r⁻¹ ν, A = B_r⁻¹ H B_p the
residuals are e_x = −u and e_y = ν_w − A u.  Writing s = √diag(C_y) and c = diag(C_x), the
gain of step 4 is, by the matrix-inversion lemma,

    K̃ = B_p C_x⁻¹ Aᵀ S_y (I + S_y A C_x⁻¹ Aᵀ S_y)⁻¹ S_y B_r⁻¹,     S_y = diag(s),

which never forms C_y⁻¹: a measurement channel whose kernel underflows to 0 (|e| ≳ 38.6 σ)
simply drops out (K̃ column 0) instead of producing inf/NaN.  The state weights are floored at
``kernel_floor`` (default 1e-12, must be > 0) so C_x⁻¹ stays finite.  The m×m matrix inverted
is I + PSD.  B_p: the Cholesky factor of P̄ if every pivot d passes ``d > REL_PIVOT · P̄_jj``,
else the jittered / eigen-floored factor of :func:`safe_cholesky` (P̄ ill-conditioned).

Where the law lives: the compiled row functions of this module, on one filter's arrays —
:func:`mckf_fixed_point_row` (step 4) and :func:`mckf_update_row` (innovation, B_r⁻¹, the
Cholesky handling, the fixed point, the rejection count and the lock-out recovery rules, the
Joseph update), built on the KF rows of :mod:`estimators.kf` and the helpers of
:mod:`estimators._linalg`.  :class:`MCKF` calls them on its own arrays (a batch of one);
:class:`estimators.batched.BatchMCKF` loops over its rows calling them.  The adaptive
bandwidth rule (below) is a row function too, :func:`adapt_kernel_row`, wrapped with the update
as :func:`mckf_adaptive_update_row`: :class:`MCKF` (``adaptive_sigma=True``) and the INS's GNSS
update (:mod:`estimators._ins_laws`, ``INSConfig.mckf_kernel = "adaptive"``) call that one
function; :class:`estimators.batched.BatchMCKF` still refuses ``adaptive_sigma``.

Options
-------
- ``sigma``: scalar, or a vector of length n+m (one kernel per row of the whitened regression:
  the multi-kernel MCKF of Li, Shi, Zou, Shi 2021).  σ is dimensionless (residuals are
  whitened); ``np.inf`` entries give weight 1 (plain least squares on that row).
- ``adaptive_sigma``: σ_k = σ · max(1, √ŝ_k), where ŝ_k is an exponentially weighted mean
  (factor ``adapt_lambda``) of the per-channel normalised innovation power NIS_k/m, each sample
  clipped at ``adapt_clip²·max(ŝ_{k−1}, 1)`` so that isolated outliers cannot widen the kernel.
  When the innovations are persistently larger than the model says (coloured noise,
  manoeuvres, mis-set R) the kernel widens instead of rejecting good fixes; with a consistent
  model ŝ ≈ 1 and σ stays at its nominal value.
- Lock-out recovery (``recovery``): a fix counts as *rejected* when any channel's weight C_y
  is below ``reject_weight`` (default 0.05, i.e. |e| > 4.9 σ).  After ``lockout_n``
  consecutive rejections (default 10, 0.5 s at 20 Hz) the filter assumes that it, not the
  sensor, is wrong (outage, sharp turn):
  ``"kf"`` (default) fuses that fix with a plain KF update (a reset towards GPS, as navigation
  filters do after persistent innovation-gate failures) and restarts the count;
  ``"inflate"`` tries, on the j-th rejected fix from the ``lockout_n``-th on, the inflated prior
  α P̄ with α = ``inflate``^j (capped at ~1e12): if the fix is consistent with it (KF NIS
  νᵀ(H α P̄ Hᵀ + R)⁻¹ν ≤ ``inflate_gate``, the χ²_m 99.9 % quantile) it is fused by a KF update
  on α P̄, which is also the prior of the Joseph update (a covariance reset), and the count
  restarts; otherwise the MCKF result stands.  (The first version multiplied P̄ itself by
  ``inflate``^j before the fixed point: the inflation compounded through P to ~1e190 — the
  fixed point started at x̄ cannot accept a far fix whatever P̄, as its first weight
  exp(−ν_w²/(4σ²)) does not depend on P̄ — and the result then hung on rounding.)
  ``None`` disables recovery.
- ``eps``, ``max_iter``: stop rule and iteration cap (the relative rule misbehaves near the
  origin and in large coordinates, so the cap always applies).

Diagnostics after an update: ``n_iter`` (fixed-point iterations), ``weights`` (diag C_y),
``weights_x`` (diag C_x), ``sigma_k`` (kernel widths used), ``rejected`` (bool),
``n_rejected`` (consecutive rejections), ``recovered`` (recovery used on this fix), and
``y``, ``S`` (= H P̄ Hᵀ + R), ``K`` (= K̃), ``nis`` (KF NIS of the innovation).
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass, replace

import numpy as np

from numkit import Layout

from ._jit import njit
from ._linalg import (
    add_into,
    chol,
    chol_inv_lower,
    copy_vec,
    inv_small_into,
    mat_mul,
    mat_vec,
    quad_form,
    safe_cholesky_into,
    scale,
)
from .kf import (
    KF_WORK_FIELDS,
    LinearGaussianBase,
    as_matrix,
    as_vector,
    joseph_from,
    joseph_row,
    kf_gain_row,
    kf_innovation_row,
    kf_work_in,
    kf_work_size,
    kf_work_spec,
)

__all__ = ["AP", "FP", "IP", "MCKF", "MCKFOptions", "MCKFWork", "MCKF_A", "MCKF_F", "MCKF_I",
           "MCKF_ST", "REL_PIVOT", "ST", "RECOVERY", "adapt_kernel_row", "adapt_kernels_row",
           "kernel_coeffs", "mckf_adaptive_update_row", "mckf_fixed_point_row", "mckf_update_row",
           "mckf_work", "mckf_work_in", "mckf_work_layout", "mckf_work_size", "safe_cholesky",
           "MCKF_WORK_FIELDS"]

#: Cholesky pivots below REL_PIVOT · P̄_jj send P̄ to :func:`safe_cholesky` (jitter), so the
#: positive-definite decision never hinges on the summation order
REL_PIVOT = 1e-8

#: recovery rule → code of the row functions (``ipar[IP.RECOVERY]``)
RECOVERY = {None: 0, "kf": 1, "inflate": 2}

#: the row functions' float options ``fpar``: the state weights' floor, ε² of the stop rule,
#: the rejection weight, the inflation factor and its gate (:func:`mckf_update_row`)
MCKF_F = Layout("floor eps2 reject inflate gate")
FP = MCKF_F.at
#: their integer options ``ipar``: the iteration cap, the lock-out count, the recovery rule
#: (:data:`RECOVERY`), the inflation's largest power
MCKF_I = Layout("max_iter lockout recovery jmax")
IP = MCKF_I.at
#: a row's state ``ist``: consecutive rejections, fixed-point iterations, the last fix rejected
#: (0/1), recovered (0/1)
MCKF_ST = Layout("n_rejected n_iter rejected recovered")
ST = MCKF_ST.at
#: the adaptive bandwidth rule's options as the INS passes them (``apar``): on (0/1), λ, clip
MCKF_A = Layout("adaptive lam clip")
AP = MCKF_A.at

#: the names of one MCKF update's work arrays, in their order in the buffer: the KF update's
#: (:data:`estimators.kf.KF_WORK_FIELDS`), then B_p, B_r, B_r⁻¹, G = B_r⁻¹ H, A, ν_w, T, M,
#: M⁻¹, √C_y, S ν_w, β, C_x⁻¹, u, x̂ before, e_y, C_x, N, V and the inflated prior's α P̄,
#: α P̄ Hᵀ, S_α, S_α⁻¹ (:func:`mckf_work_in`)
MCKF_WORK_FIELDS = KF_WORK_FIELDS + (
    "Lp", "Lr", "Brinv", "G", "Aw", "nw", "T", "M", "Mi", "sy", "sn", "be", "q", "u", "ox", "e",
    "cx", "Nm", "V", "Pa", "PaHT", "Sa", "Sai")
MCKFWork = namedtuple("MCKFWork", MCKF_WORK_FIELDS)


def safe_cholesky(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor; symmetrises and adds growing jitter if P is not numerically PD
    (:func:`estimators._linalg.safe_cholesky_into`)."""
    Pc = np.array(P, dtype=float, order="C")
    L = np.zeros_like(Pc)
    safe_cholesky_into(Pc, L)
    return L


def kernel_coeffs(sigma: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(−1/(2σ²) for the n state rows, −1/(4σ²) for the measurement rows): G(e) = exp(e² kx)
    and √G(e) = exp(e² ky).  σ = inf gives 0, a weight of exactly 1."""
    c = -1.0 / (2.0 * sigma * sigma)
    return np.ascontiguousarray(c[:n]), np.ascontiguousarray(0.5 * c[n:])


# ------------------------------------------------------------------------------ the law, rows
@njit
def _whitened_A(G, L, A):
    """A = G L (= B_r⁻¹ H B_p), L lower triangular: its zeros skipped."""
    n = L.shape[0]
    for i in range(G.shape[0]):
        for j in range(n):
            acc = 0.0
            for k in range(j, n):
                acc += G[i, k] * L[k, j]
            A[i, j] = acc


@njit
def _fixed_point_gain(L, A, Brinv, Mi, s, q, Nm, V, K):
    """K̃ = L C_x⁻¹ Aᵀ N, N = S M⁻¹ S B_r⁻¹ (the last iteration's M⁻¹, S = diag(s), C_x⁻¹ =
    diag(q)), L lower triangular."""
    n, m = L.shape[0], s.shape[0]
    for i in range(m):
        for col in range(m):
            acc = 0.0
            for h in range(m):
                acc += Mi[i, h] * s[h] * Brinv[h, col]
            Nm[i, col] = s[i] * acc
    mat_mul(A.T, Nm, V)
    for k in range(n):
        for col in range(m):
            V[k, col] = q[k] * V[k, col]
    for j in range(n):
        for col in range(m):
            acc = 0.0
            for k in range(j + 1):
                acc += L[j, k] * V[k, col]
            K[j, col] = acc


@njit
def mckf_fixed_point_row(xb, L, nu, Brinv, G, kx, ky, fpar, ipar, fw):
    """MCKF step 4 in whitened coordinates given L = chol(P̄) and G = B_r⁻¹ H; ``kx``, ``ky``,
    ``fpar``, ``ipar`` as :func:`mckf_update_row` (the floor, ε² and the iteration cap read
    here); ``fw`` = (A, ν_w, T, M, M⁻¹, s, S ν_w, β, q, u, x̂, x̂ before, e, c, K̃, N, V), the
    fixed point's part of the update's work (:func:`mckf_work_in`: only what it uses, as a
    call passes each array's fields).  Writes x̂, K̃, C_x into c (when more than one iteration
    ran) and √C_y into s; returns the number of iterations.  Iteration 1 starts at
    x̂⁽⁰⁾ = x̄ (C_x = I, e_y = ν_w); each solves T = A C_x⁻¹ Aᵀ, M = I + S T S,
    β = S M⁻¹ S ν_w, u = C_x⁻¹ Aᵀ β, x̂ = x̄ + L u; the stop rule is
    ‖x̂⁽ᵗ⁾ − x̂⁽ᵗ⁻¹⁾‖² ≤ ε² max(‖x̂⁽ᵗ⁻¹⁾‖², 1) or t = max_iter; the next weights are
    e_y = ν_w − A u, c_j = max(exp(u_j² kx_j), floor), q = 1/c, s_i = exp(e_y,i² ky_i).
    Finally K̃ = L C_x⁻¹ Aᵀ N, N = S M⁻¹ S B_r⁻¹.  One straight loop (helper calls inside the
    iteration measured slower)."""
    A, nw, T, M, Mi, s, sn, be, q, u, xn, o, e, c, K, Nm, V = fw
    floor, eps2, max_iter = fpar[FP.FLOOR], fpar[FP.EPS2], ipar[IP.MAX_ITER]
    n = xb.shape[0]
    m = nu.shape[0]
    _whitened_A(G, L, A)
    mat_vec(Brinv, nu, nw)
    for i in range(m):
        s[i] = math.exp(nw[i] * nw[i] * ky[i])
    for j in range(n):
        q[j] = 1.0
    nrm2 = 0.0
    for j in range(n):
        o[j] = xb[j]
        nrm2 += xb[j] * xb[j]
    it = 1
    while True:
        # solve: T = A C_x⁻¹ Aᵀ, M = I + S T S, β = S M⁻¹ S ν_w, u = C_x⁻¹ Aᵀ β, x̂ = x̄ + L u
        for i in range(m):
            for k in range(i, m):
                acc = 0.0
                for j in range(n):
                    acc += A[i, j] * A[k, j] * q[j]
                T[i, k] = acc
        for i in range(m):
            for k in range(i, m):
                v = s[i] * s[k] * T[i, k]
                M[i, k] = 1.0 + v if i == k else v
                M[k, i] = M[i, k]
        inv_small_into(M, Mi)
        for i in range(m):
            sn[i] = s[i] * nw[i]
        mat_vec(Mi, sn, be)
        for i in range(m):
            be[i] = s[i] * be[i]
        mat_vec(A.T, be, u)
        for j in range(n):
            u[j] = q[j] * u[j]
        for j in range(n):
            acc = 0.0
            for k in range(j + 1):
                acc += L[j, k] * u[k]
            xn[j] = xb[j] + acc
        if it >= max_iter:
            break
        d2 = 0.0
        for j in range(n):
            d2 += (xn[j] - o[j]) * (xn[j] - o[j])
        if d2 <= eps2 * (nrm2 if nrm2 > 1.0 else 1.0):
            break
        it += 1
        nrm2 = 0.0
        for j in range(n):
            o[j] = xn[j]
            nrm2 += xn[j] * xn[j]
        mat_vec(A, u, e)
        for i in range(m):
            e[i] = nw[i] - e[i]
        for j in range(n):
            cj = math.exp(u[j] * u[j] * kx[j])
            if cj < floor:
                cj = floor
            c[j] = cj
            q[j] = 1.0 / cj
        for i in range(m):
            s[i] = math.exp(e[i] * e[i] * ky[i])
    _fixed_point_gain(L, A, Brinv, Mi, s, q, Nm, V, K)
    return it


def mckf_work_layout(n: int, m: int) -> Layout:
    """The layout of :func:`mckf_work_in`'s buffer for n states and m measurements:
    :func:`estimators.kf.kf_work_layout`'s fields, then the fixed point's and the recovery's
    (:data:`MCKF_WORK_FIELDS`)."""
    nn, mm, nm = f"{n}x{n}", f"{m}x{m}", f"{n}x{m}"
    return Layout(kf_work_spec(n, m) + " " + " ".join(
        f"{name}:{shape}" for name, shape in (
            ("Lp", nn), ("Lr", mm), ("Brinv", mm), ("G", f"{m}x{n}"), ("Aw", f"{m}x{n}"),
            ("nw", m), ("T", mm), ("M", mm), ("Mi", mm), ("sy", m), ("sn", m), ("be", m),
            ("q", n), ("u", n), ("ox", n), ("e", m), ("cx", n), ("Nm", mm), ("V", nm),
            ("Pa", nn), ("PaHT", nm), ("Sa", mm), ("Sai", mm))))


@njit
def mckf_work_size(n, m):
    """Length of a buffer holding :func:`mckf_work_in`'s arrays (the size of
    :func:`mckf_work_layout`)."""
    return kf_work_size(n, m) + 2 * n * n + 8 * m * m + 4 * n * m + 4 * n + 5 * m


@njit(inline="always")
def mckf_work_in(buf, n, m):
    """The work arrays of one MCKF update (:func:`mckf_update_row`) as views of ``buf`` (≥
    :func:`mckf_work_size`), laid out as :func:`mckf_work_layout`: those of
    :func:`estimators.kf.kf_work_in` (ν, P Hᵀ, S, S⁻¹, K, x̂, …) then the fixed point's — a
    per-tick caller allocates nothing.  Returns a :class:`MCKFWork` (fields by name)."""
    nu, PHT, S, Si, K, xo, A, AP, KR = kf_work_in(buf, n, m)
    o = kf_work_size(n, m)
    nn, mm, mn = n * n, m * m, m * n
    Lp = buf[o:o + nn].reshape((n, n))
    o += nn
    Lr, Brinv = buf[o:o + mm].reshape((m, m)), buf[o + mm:o + 2 * mm].reshape((m, m))
    o += 2 * mm
    G, Aw = buf[o:o + mn].reshape((m, n)), buf[o + mn:o + 2 * mn].reshape((m, n))
    o += 2 * mn
    nw = buf[o:o + m]
    o += m
    T, M = buf[o:o + mm].reshape((m, m)), buf[o + mm:o + 2 * mm].reshape((m, m))
    Mi = buf[o + 2 * mm:o + 3 * mm].reshape((m, m))
    o += 3 * mm
    s, sn, be = buf[o:o + m], buf[o + m:o + 2 * m], buf[o + 2 * m:o + 3 * m]
    o += 3 * m
    q, u, ox = buf[o:o + n], buf[o + n:o + 2 * n], buf[o + 2 * n:o + 3 * n]
    o += 3 * n
    e, c = buf[o:o + m], buf[o + m:o + m + n]
    o += m + n
    Nm, V = buf[o:o + mm].reshape((m, m)), buf[o + mm:o + mm + mn].reshape((n, m))
    o += mm + mn
    Pa, PaHT = buf[o:o + nn].reshape((n, n)), buf[o + nn:o + nn + mn].reshape((n, m))
    o += nn + mn
    Sa, Sai = buf[o:o + mm].reshape((m, m)), buf[o + mm:o + 2 * mm].reshape((m, m))
    return MCKFWork(nu, PHT, S, Si, K, xo, A, AP, KR, Lp, Lr, Brinv, G, Aw, nw, T, M, Mi, s, sn,
                    be, q, u, ox, e, c, Nm, V, Pa, PaHT, Sa, Sai)


@njit
def mckf_work(n, m):
    """Work arrays of one MCKF update (:func:`mckf_update_row`), freshly allocated:
    :func:`mckf_work_in` on a new buffer."""
    return mckf_work_in(np.empty(mckf_work_size(n, m)), n, m)


@njit
def _recover(x, P, R, H, nu, fpar, ipar, ist, rw):
    """The lock-out recovery rule after a rejected fix (count in ist[0] already raised; ``rw``
    = (P̄ Hᵀ, S⁻¹ of the innovation, K, x̂, Pa, Pa Hᵀ, Sa, Sa⁻¹) of the update's work):
    ``"kf"`` (recovery 1) K = P̄ Hᵀ S⁻¹, x̂ = x̄ + K ν; ``"inflate"`` (2) the same on α P̄,
    α = inflate^j, if νᵀ (H α P̄ Hᵀ + R)⁻¹ ν ≤ gate.  Returns 0 (no recovery), 1 (recovered on
    P̄) or 2 (recovered on α P̄, now in w's Pa: the prior of the Joseph update)."""
    PHT, Si, K, xo, Pa, PaHT, Sa, Sai = rw
    if ist[ST.N_REJECTED] < ipar[IP.LOCKOUT]:
        return 0
    if ipar[IP.RECOVERY] == 1:
        kf_gain_row(x, PHT, Si, nu, K, xo)  # K = P̄ Hᵀ S⁻¹, x̂ = x̄ + K ν
        ist[ST.N_REJECTED] = 0
        return 1
    if ipar[IP.RECOVERY] == 2:
        j = min(ist[ST.N_REJECTED] - ipar[IP.LOCKOUT] + 1, ipar[IP.JMAX])
        alpha = math.pow(fpar[FP.INFLATE], float(j))  # α = inflate^j
        scale(alpha, PHT, PaHT)
        mat_mul(H, PaHT, Sa)
        add_into(Sa, R)
        inv_small_into(Sa, Sai)
        if quad_form(Sai, nu) <= fpar[FP.GATE]:  # νᵀ (H α P̄ Hᵀ + R)⁻¹ ν ≤ gate
            scale(alpha, P, Pa)
            kf_gain_row(x, PaHT, Sai, nu, K, xo)
            ist[ST.N_REJECTED] = 0
            return 2
    return 0


@njit
def mckf_update_row(x, P, R, H, z, mp, st, w):
    """The MCKF update of one filter in place (x, P); returns the KF NIS of the innovation (not
    finite: no fix, x and P untouched).

    ``mp`` = (kx, ky, fpar, ipar) the row's parameters: kx, ky the kernel coefficients
    (:func:`kernel_coeffs`), fpar = (kernel_floor, ε², reject_weight, inflate, inflate_gate),
    ipar = (max_iter, lockout_n, recovery 0/1/2 = None/"kf"/"inflate", inflate_jmax);
    ``st`` = (ist, wy) its state: ist = (n_rejected, n_iter, rejected, recovered) (updated),
    wy ← diag C_y (layouts :data:`MCKF_F`, :data:`MCKF_I`, :data:`MCKF_ST`); w =
    :func:`mckf_work` (or :func:`mckf_work_in` on the caller's buffer); after a fix w holds ν
    (``w.nu``), S (``w.S``), K̃ (``w.K``) and C_x (``w.cx``, valid when n_iter > 1)."""
    kx, ky, fpar, ipar = mp
    ist, wy = st
    (nu, PHT, S, Si, K, xo, A, AP, KR, Lp, Lr, Brinv, G, Aw, nw, T, M, Mi, s, sn, be, q, u,
     o, e, c, Nm, V, Pa, PaHT, Sa, Sai) = w
    v = kf_innovation_row(x, P, R, H, z, nu, PHT, S, Si)
    if not math.isfinite(v):
        return v
    chol_inv_lower(R, Brinv, Lr)
    mat_mul(Brinv, H, G)
    if not chol(P, Lp, REL_PIVOT):
        safe_cholesky_into(P, Lp)
    it = mckf_fixed_point_row(x, Lp, nu, Brinv, G, kx, ky, fpar, ipar,
                              (Aw, nw, T, M, Mi, s, sn, be, q, u, xo, o, e, c, K, Nm, V))
    wmin = np.inf
    for a in range(nu.shape[0]):
        wy[a] = s[a] * s[a]
        if wy[a] < wmin:
            wmin = wy[a]
    rejected = wmin < fpar[FP.REJECT]  # some channel's weight C_y below reject_weight
    rec = 0
    if rejected:
        ist[ST.N_REJECTED] += 1
        rec = _recover(x, P, R, H, nu, fpar, ipar, ist, (PHT, Si, K, xo, Pa, PaHT, Sa, Sai))
    else:
        ist[ST.N_REJECTED] = 0
    copy_vec(xo, x)
    # the original P̄ and R (P̄ Hᵀ and S as the innovation formed them), or the inflated prior
    # after an "inflate" reset
    if rec == 2:
        joseph_row(Pa, K, H, R, P, A, AP, KR)
    else:
        joseph_from(P, K, PHT, S, P, KR)
    ist[ST.N_ITER] = it
    ist[ST.REJECTED] = 1 if rejected else 0
    ist[ST.RECOVERED] = 1 if rec else 0
    return v


@njit
def adapt_kernel_row(nis, m, sigma, lam, clip, st, kx, ky):
    """The adaptive bandwidth rule (module docstring, ``adaptive_sigma``) on one filter:
    ŝ ← λ ŝ + (1 − λ) min(NIS/m, clip² max(ŝ, 1)) with ŝ in ``st[0]``, then σ_k = σ max(1, √ŝ)
    per row of ``sigma`` (n + m values; ∞ stays ∞) and the kernel coefficients of
    :func:`kernel_coeffs`: kx = −1/(2σ_k²) (n state rows), ky = −1/(4σ_k²) (m measurement rows).
    Returns the factor max(1, √ŝ)."""
    s2 = st[0]
    lim = clip * clip * (s2 if s2 > 1.0 else 1.0)
    r = nis / m
    s2 = lam * s2 + (1.0 - lam) * (r if r < lim else lim)
    st[0] = s2
    f = math.sqrt(s2)
    if f < 1.0:
        f = 1.0
    n = kx.shape[0]
    for j in range(sigma.shape[0]):
        sk = sigma[j] * f
        c = -1.0 / (2.0 * sk * sk)
        if j < n:
            kx[j] = c
        else:
            ky[j - n] = 0.5 * c
    return f


@njit(inline="always")
def adapt_kernels_row(x, P, R, H, z, w, ad):
    """The first half of :func:`mckf_adaptive_update_row`: the KF NIS of the innovation
    (into the work ``w``) feeds :func:`adapt_kernel_row` with ``ad`` = (base widths σ, λ,
    clip, state ŝ, kx, ky; kx, ky are written).  Returns the NIS (not finite: no fix, nothing
    changes)."""
    sigma, lam, clip, ast, kx, ky = ad
    v = kf_innovation_row(x, P, R, H, z, w.nu, w.PHT, w.S, w.Si)
    if math.isfinite(v):
        adapt_kernel_row(v, z.shape[0], sigma, lam, clip, ast, kx, ky)
    return v


@njit
def mckf_adaptive_update_row(x, P, R, H, z, ad, mp, st, w):
    """:func:`mckf_update_row` with the adaptive bandwidth: the KF NIS of the innovation feeds
    :func:`adapt_kernel_row` (``ad`` = (base widths σ, λ, clip, state ŝ); ``mp``'s kx, ky are
    written), then the MCKF update with those kernels (:func:`adapt_kernels_row`, then
    :func:`mckf_update_row`).  Returns the NIS (not finite: no fix, nothing changes)."""
    sigma, lam, clip, ast = ad
    v = adapt_kernels_row(x, P, R, H, z, w, (sigma, lam, clip, ast, mp[0], mp[1]))
    if not math.isfinite(v):
        return v
    return mckf_update_row(x, P, R, H, z, mp, st, w)


# ------------------------------------------------------------------------------ the class
@dataclass(frozen=True)
class MCKFOptions:
    """The options of :class:`MCKF` (module docstring, *Options*), declared once.

    sigma : kernel bandwidth, scalar or vector of length n+m (multi-kernel).
    eps, max_iter : fixed-point stop rule and cap.
    kernel_floor : lower bound (> 0) of the state weights C_x.
    adaptive_sigma, adapt_lambda, adapt_clip : adaptive bandwidth rule.
    recovery, lockout_n, reject_weight, inflate : lock-out recovery rule.
    """

    sigma: float | np.ndarray = 2.0
    eps: float = 1e-6
    max_iter: int = 10
    kernel_floor: float = 1e-12
    adaptive_sigma: bool = False
    adapt_lambda: float = 0.98
    adapt_clip: float = 3.0
    recovery: str | None = "kf"
    lockout_n: int = 10
    reject_weight: float = 0.05
    inflate: float = 4.0


class MCKF(LinearGaussianBase):
    """Maximum correntropy Kalman filter; see the module docstring for every option.

    Parameters
    ----------
    F, H, Q, R, x0, P0 : as :class:`estimators.KF`.
    options : the options (:class:`MCKFOptions`; its defaults when omitted).
    **changes : any :class:`MCKFOptions` field by name, over ``options``
        (``MCKF(F, H, Q, R, sigma=3.0, recovery="inflate")``); an unknown name is a TypeError.
    """

    def __init__(self, F, H, Q, R, x0=None, P0=None, options: MCKFOptions | None = None,
                 **changes) -> None:
        opts = replace(options or MCKFOptions(), **changes)  # TypeError names a bad keyword
        self._ist = np.zeros(MCKF_ST.size, dtype=np.int64)
        super().__init__(F, H, Q, R, x0, P0)
        if opts.recovery not in RECOVERY:
            raise ValueError(f"recovery must be None, 'kf' or 'inflate', got {opts.recovery!r}")
        if opts.max_iter < 1:
            raise ValueError("max_iter must be >= 1")
        if not opts.kernel_floor > 0.0:
            raise ValueError("kernel_floor must be > 0")
        self.sigma = opts.sigma
        self.eps = float(opts.eps)
        self.max_iter = int(opts.max_iter)
        self.kernel_floor = float(opts.kernel_floor)
        self.adaptive_sigma = bool(opts.adaptive_sigma)
        self.adapt_lambda = float(opts.adapt_lambda)
        self.adapt_clip = float(opts.adapt_clip)
        self.recovery = opts.recovery
        self.lockout_n = int(opts.lockout_n)
        self.reject_weight = float(opts.reject_weight)
        self.inflate = float(opts.inflate)
        if opts.recovery == "inflate" and not self.inflate > 1.0:
            raise ValueError("inflate must be > 1")
        from scipy.special import gammaincinv

        self.inflate_gate = 2.0 * float(gammaincinv(0.5 * self.m, 0.999))
        self._ast = np.ones(1)  # ŝ_k of the adaptive rule (adapt_kernel_row's state)
        self.weights = np.ones(self.m)
        self.weights_x = np.ones(self.n)
        self.sigma_k = self._sigma.copy()
        self._w = mckf_work(self.n, self.m)

    # state of the lock-out rule and the last fixed point (views of the row's ``ist``) ---------
    n_rejected = property(lambda self: int(self._ist[ST.N_REJECTED]),
                          lambda self, v: self._ist.__setitem__(ST.N_REJECTED, int(v)))
    n_iter = property(lambda self: int(self._ist[ST.N_ITER]),
                      lambda self, v: self._ist.__setitem__(ST.N_ITER, int(v)))
    rejected = property(lambda self: bool(self._ist[ST.REJECTED]),
                        lambda self, v: self._ist.__setitem__(ST.REJECTED, int(bool(v))))
    recovered = property(lambda self: bool(self._ist[ST.RECOVERED]),
                         lambda self, v: self._ist.__setitem__(ST.RECOVERED, int(bool(v))))

    scale2 = property(lambda self: float(self._ast[0]),
                      lambda self, v: self._ast.__setitem__(0, float(v)))

    @property
    def sigma(self) -> np.ndarray:
        return self._sigma

    @sigma.setter
    def sigma(self, value) -> None:
        s = np.atleast_1d(np.asarray(value, dtype=float))
        if s.size == 1:
            s = np.full(self.n + self.m, float(s[0]))
        if s.shape != (self.n + self.m,) or np.any(s <= 0):
            n_m = self.n + self.m
            raise ValueError(f"sigma must be a positive scalar or have length n+m={n_m}")
        self._sigma = s
        self._ncx, self._ncy_half = kernel_coeffs(s, self.n)

    @property
    def kernels(self) -> tuple[np.ndarray, np.ndarray]:
        """The kernel coefficients of ``sigma`` (:func:`kernel_coeffs`): (kx (n,), ky (m,)),
        the rows' ``kx``, ``ky`` of :func:`mckf_update_row` (read them, do not write)."""
        return self._ncx, self._ncy_half

    def _on_model_change(self) -> None:
        R = getattr(self, "_R", None)
        if R is not None and R is not getattr(self, "_R_checked", None):
            np.linalg.cholesky(R)  # R must be SPD (B_r = chol R); raises LinAlgError
            self._R_checked = R

    def params(self) -> tuple[np.ndarray, np.ndarray]:
        """The row functions' parameters ``(fpar, ipar)`` from the attributes (see
        :func:`mckf_update_row`)."""
        jmax = max(1, int(12.0 / math.log10(self.inflate))) if self.inflate > 1.0 else 1
        fpar = np.empty(MCKF_F.size)
        fpar[FP.FLOOR], fpar[FP.EPS2], fpar[FP.REJECT] = (self.kernel_floor, self.eps * self.eps,
                                                           self.reject_weight)
        fpar[FP.INFLATE], fpar[FP.GATE] = self.inflate, self.inflate_gate
        ipar = np.empty(MCKF_I.size, dtype=np.int64)
        ipar[IP.MAX_ITER], ipar[IP.LOCKOUT] = self.max_iter, self.lockout_n
        ipar[IP.RECOVERY], ipar[IP.JMAX] = RECOVERY[self.recovery], jmax
        return fpar, ipar

    def update(self, z) -> bool:
        """Fuse fix ``z`` (:func:`mckf_update_row`); returns ``False`` (nothing changes) for
        "no fix": ``None``, NaN/inf in ``z``, or a fix so large that its NIS overflows."""
        zz = self._fix(z)
        if zz is None:
            return False
        n = self.n
        x = as_vector(self.x, n)
        P = as_matrix(self.P, "P", (n, n))
        w = self._w
        fpar, ipar = self.params()
        wy = np.empty(self.m)
        if self.adaptive_sigma:
            kx, ky = np.empty(n), np.empty(self.m)
            v = mckf_adaptive_update_row(
                x, P, self._R, self._H, zz,
                (self._sigma, self.adapt_lambda, self.adapt_clip, self._ast),
                (kx, ky, fpar, ipar), (self._ist, wy), w)
            if not math.isfinite(v):
                return False
            self.sigma_k = self._sigma * max(1.0, math.sqrt(self.scale2))
        else:
            v = mckf_update_row(x, P, self._R, self._H, zz,
                                (self._ncx, self._ncy_half, fpar, ipar), (self._ist, wy), w)
            if not math.isfinite(v):
                return False
        self.x, self.P = x, P
        self.weights = wy
        self.weights_x = np.ones(n) if self._ist[ST.N_ITER] == 1 else w.cx.copy()
        self.y, self.S, self.K = w.nu.copy(), w.S.copy(), w.K.copy()
        self.nis = float(v)
        return True
