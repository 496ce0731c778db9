"""The INS's model: the nominal and covariance prediction (its quaternion algebra from
:mod:`numkit.geometry`), the error injection and reset, and the measurement models (h, H)
with the innovation gate; formulas and sources in :mod:`estimators.ins`.  Each model ``h_*``
has a twin ``h_*_w`` taking its scratch (the tick's path allocates nothing; the public ``h_*``
allocate it, for tests and callers outside the kernel)."""

from __future__ import annotations

import math

import numpy as np

from numkit.geometry import quat_exp, quat_log_err, quat_mul, quat_normalize, quat_to_rot

from .._jit import njit
from .layout import (
    PRM_CONING,
    PRM_COSMAX,
    PRM_DT,
    PRM_G,
    PRM_QV,
    PRM_RANT,
    PRM_RB,
    PRM_RMAX,
    PRM_RRAD,
    PRM_ZG,
)

__all__ = ["cov_step", "gate_ratio", "h_gnss_pos", "h_gnss_pos_w", "h_gnss_vel", "h_gnss_vel_w",
           "h_heading", "h_heading_w", "h_radar", "h_radar_w", "inject_reset", "inject_reset_w",
           "increments", "innov_var", "nominal_step", "nominal_step_R", "quat_exp", "quat_log_err",
           "quat_mul", "quat_to_rot", "skew_mul", "step_llr"]


@njit
def skew_mul(M, r, out):
    """out = M [r]× (3×3)."""
    for i in range(3):
        out[i, 0] = M[i, 1] * r[2] - M[i, 2] * r[1]
        out[i, 1] = M[i, 2] * r[0] - M[i, 0] * r[2]
        out[i, 2] = M[i, 0] * r[1] - M[i, 1] * r[0]


# ------------------------------------------------------------------------ prediction
@njit
def increments(x, u, up, dt, coning, w):
    """The bias-corrected body-frame rotation vector ``w[3:6]`` and velocity increment
    ``w[0:3]`` of one IMU sample ``u = (f̃, ω̃)`` (the means of the sample's delta-velocity and
    delta-angle over Δt), with ``up`` the previous sample; ``w`` (≥ 18): scratch.

    α = (ω̃ − b_g)Δt, ν = (f̃ − b_a)Δt (and α', ν' of ``up``, with the same bias estimate); with
    ``coning`` the two-sample (previous-sample) corrections of Savage, *Strapdown inertial
    navigation integration algorithm design, part 1: attitude algorithms*, JGCD 21(1) 1998
    (coning) and *part 2: velocity and position algorithms*, JGCD 21(2) 1998 (sculling); also
    Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems* (2nd
    ed., 2013), ch. 5::

        φ  = α + (1/12) α' × α                                        (coning)
        Δv = ν + ½ α × ν + (1/12) (α' × ν + ν' × α)      (rotation + sculling)

    without ``coning``: φ = α, Δv = ν (rates held over the step)."""
    a = w[0:3]
    phi = w[3:6]
    ap = w[12:15]
    vp = w[15:18]
    for k in range(3):
        a[k] = (u[k] - x[10 + k]) * dt
        phi[k] = (u[3 + k] - x[13 + k]) * dt
        vp[k] = (up[k] - x[10 + k]) * dt
        ap[k] = (up[3 + k] - x[13 + k]) * dt
    if not coning:
        return
    c0 = ap[1] * phi[2] - ap[2] * phi[1]
    c1 = ap[2] * phi[0] - ap[0] * phi[2]
    c2 = ap[0] * phi[1] - ap[1] * phi[0]
    r0 = 0.5 * (phi[1] * a[2] - phi[2] * a[1])
    r1 = 0.5 * (phi[2] * a[0] - phi[0] * a[2])
    r2 = 0.5 * (phi[0] * a[1] - phi[1] * a[0])
    s0 = (ap[1] * a[2] - ap[2] * a[1] + vp[1] * phi[2] - vp[2] * phi[1]) / 12.0
    s1 = (ap[2] * a[0] - ap[0] * a[2] + vp[2] * phi[0] - vp[0] * phi[2]) / 12.0
    s2 = (ap[0] * a[1] - ap[1] * a[0] + vp[0] * phi[1] - vp[1] * phi[0]) / 12.0
    a[0] += r0 + s0
    a[1] += r1 + s1
    a[2] += r2 + s2
    phi[0] += c0 / 12.0
    phi[1] += c1 / 12.0
    phi[2] += c2 / 12.0


@njit
def nominal_step_R(x, u, up, prm, R, w):
    """:func:`nominal_step` given R = R(q) of the current x; ``w`` (≥ 18): scratch."""
    dt, g = prm[PRM_DT], prm[PRM_G]
    increments(x, u, up, dt, prm[PRM_CONING] > 0.0, w)
    dv = w[0:3]
    for i in range(3):
        acc = (R[i, 0] * dv[0] + R[i, 1] * dv[1] + R[i, 2] * dv[2]) / dt
        if i == 2:
            acc -= g
        x[i] += x[3 + i] * dt + 0.5 * acc * dt * dt
        x[3 + i] += acc * dt
    dq = w[6:10]
    quat_exp(w[3:6], dq)
    qn = w[10:14]
    quat_mul(x[6:10], dq, qn)
    quat_normalize(qn, x[6:10])


@njit
def nominal_step(x, u, up, prm, S3, w):
    """One IMU sample u = (f̃, ω̃) after the sample ``up`` on the nominal x = [p, v, q, b_a,
    b_g] (module docstring; :func:`increments`).  ``S3`` (≥ 1, 3, 3), ``w`` (≥ 18): scratch
    (the per-tick path allocates nothing)."""
    quat_to_rot(x[6:10], S3[0])
    nominal_step_R(x, u, up, prm, S3[0], w)


@njit
def _fill_F(x, u, dt, R, S3, w):
    """F's non-identity blocks from R = R(q): S3[1] = F_vθ = −R [a]× Δt, S3[2] = F_vba = −R Δt,
    S3[3] = F_θθ = Exp(−ω Δt) as a rotation matrix (F_pv = I Δt, F_θbg = −I Δt are scalars);
    ``S3`` (≥ 5, 3, 3), ``w`` (≥ 10): scratch."""
    a = w[0:3]
    phi = w[3:6]
    for k in range(3):
        a[k] = u[k] - x[10 + k]
        phi[k] = -(u[3 + k] - x[13 + k]) * dt
    Ra = S3[4]
    skew_mul(R, a, Ra)
    dq = w[6:10]
    quat_exp(phi, dq)  # Exp(ω Δt)ᵀ = Exp(−ω Δt)
    quat_to_rot(dq, S3[3])
    Fv, Fa = S3[1], S3[2]
    for i in range(3):
        for j in range(3):
            Fv[i, j] = -Ra[i, j] * dt
            Fa[i, j] = -R[i, j] * dt


@njit
def _fp_rows(P, dt, Fv, Fa, E, M):
    """M[0:9] = rows 0-8 of F P (rows 9-14 of F P are P's), each entry summed in F's column
    order; M[3:6, 0:3] and M[6:9, 0:6] are not needed by :func:`cov_step` and not formed."""
    mdt = -dt
    for i in range(3):
        for c in range(15):
            M[i, c] = P[i, c] + dt * P[3 + i, c]
        for c in range(3, 15):
            M[3 + i, c] = (P[3 + i, c] + Fv[i, 0] * P[6, c] + Fv[i, 1] * P[7, c]
                           + Fv[i, 2] * P[8, c] + Fa[i, 0] * P[9, c] + Fa[i, 1] * P[10, c]
                           + Fa[i, 2] * P[11, c])
        for c in range(6, 15):
            M[6 + i, c] = (E[i, 0] * P[6, c] + E[i, 1] * P[7, c] + E[i, 2] * P[8, c]
                           + mdt * P[12 + i, c])


@njit
def cov_step(P, x, u, prm, R, M, S3, w):
    """P ← F P Fᵀ + Q with F's blocks written out (module docstring), R = R(q) of x; M (≥ 9,
    15), S3 (≥ 5, 3, 3), w (≥ 10): scratch.  M = F P (first 9 rows), then the upper triangle
    of M Fᵀ, mirrored: the 15×15 block of the bias rows (F = I there) is P's own."""
    dt = prm[PRM_DT]
    _fill_F(x, u, dt, R, S3, w)
    Fv, Fa, E = S3[1], S3[2], S3[3]
    _fp_rows(P, dt, Fv, Fa, E, M)
    mdt = -dt
    for r in range(9):
        for c in range(r, 3):
            s = M[r, c] + M[r, 3 + c] * dt
            P[r, c] = s
            P[c, r] = s
        for c in range(max(r, 3), 6):
            i = c - 3
            s = (M[r, c] + M[r, 6] * Fv[i, 0] + M[r, 7] * Fv[i, 1] + M[r, 8] * Fv[i, 2]
                 + M[r, 9] * Fa[i, 0] + M[r, 10] * Fa[i, 1] + M[r, 11] * Fa[i, 2])
            P[r, c] = s
            P[c, r] = s
        for c in range(max(r, 6), 9):
            i = c - 6
            s = M[r, 6] * E[i, 0] + M[r, 7] * E[i, 1] + M[r, 8] * E[i, 2] + M[r, 12 + i] * mdt
            P[r, c] = s
            P[c, r] = s
        for c in range(9, 15):
            s = M[r, c]
            P[r, c] = s
            P[c, r] = s
    for r in range(9, 15):
        for c in range(r + 1, 15):
            P[c, r] = P[r, c]
    for b in range(4):
        q = prm[PRM_QV + b]
        for k in range(3):
            d = 3 + 3 * b + k
            P[d, d] += q


# ------------------------------------------------------------------------ error injection
@njit
def inject_reset_w(x, P, dx, w):
    """:func:`inject_reset` with ``w`` (≥ 8) as scratch."""
    for k in range(6):
        x[k] += dx[k]
    for k in range(6):
        x[10 + k] += dx[9 + k]
    dq = w[0:4]
    quat_exp(dx[6:9], dq)
    qn = w[4:8]
    quat_mul(x[6:10], dq, qn)
    quat_normalize(qn, x[6:10])
    h0, h1, h2 = 0.5 * dx[6], 0.5 * dx[7], 0.5 * dx[8]
    # G = [[1, h2, −h1], [−h2, 1, h0], [h1, −h0, 1]]: rows 6-8 ← G P[6:9], then cols ← · Gᵀ
    g01, g02, g10, g12, g20, g21 = h2, -h1, -h2, h0, h1, -h0
    for c in range(15):
        p6, p7, p8 = P[6, c], P[7, c], P[8, c]
        P[6, c] = 1.0 * p6 + g01 * p7 + g02 * p8
        P[7, c] = g10 * p6 + 1.0 * p7 + g12 * p8
        P[8, c] = g20 * p6 + g21 * p7 + 1.0 * p8
    for r in range(15):
        p6, p7, p8 = P[r, 6], P[r, 7], P[r, 8]
        P[r, 6] = p6 * 1.0 + p7 * g01 + p8 * g02
        P[r, 7] = p6 * g10 + p7 * 1.0 + p8 * g12
        P[r, 8] = p6 * g20 + p7 * g21 + p8 * 1.0
    for r in range(15):  # keep P exactly symmetric
        for c in range(r + 1, 15):
            s = 0.5 * (P[r, c] + P[c, r])
            P[r, c] = s
            P[c, r] = s


@njit
def inject_reset(x, P, dx):
    """x ← x ⊕ δx, then P ← G P Gᵀ with G_θθ = I − [½ δθ]× (Solà eqs 282-287)."""
    inject_reset_w(x, P, dx, np.empty(8))


# ------------------------------------------------------------------------ measurement models
@njit
def h_gnss_pos_w(x, prm, z, nu, H, S3):
    R, S = S3[0], S3[1]
    quat_to_rot(x[6:10], R)
    r = prm[PRM_RANT:PRM_RANT + 3]
    skew_mul(R, r, S)
    for i in range(3):
        nu[i] = z[i] - (x[i] + R[i, 0] * r[0] + R[i, 1] * r[1] + R[i, 2] * r[2])
        for c in range(15):
            H[i, c] = 0.0
        H[i, i] = 1.0
        for j in range(3):
            H[i, 6 + j] = -S[i, j]


@njit
def h_gnss_pos(x, prm, z, nu, H):
    """ν = z − (p + R r_ant), H = [I, 0, −R [r_ant]×, 0, 0]."""
    h_gnss_pos_w(x, prm, z, nu, H, np.empty((2, 3, 3)))


@njit
def h_gnss_vel_w(x, w, prm, z, nu, H, S3, wr):
    R, S1, S2 = S3[0], S3[1], S3[2]
    quat_to_rot(x[6:10], R)
    r = prm[PRM_RANT:PRM_RANT + 3]
    o0, o1, o2 = w[0] - x[13], w[1] - x[14], w[2] - x[15]
    wr[0] = o1 * r[2] - o2 * r[1]
    wr[1] = o2 * r[0] - o0 * r[2]
    wr[2] = o0 * r[1] - o1 * r[0]
    skew_mul(R, wr, S1)
    skew_mul(R, r, S2)
    for i in range(3):
        nu[i] = z[i] - (x[3 + i] + R[i, 0] * wr[0] + R[i, 1] * wr[1] + R[i, 2] * wr[2])
        for c in range(15):
            H[i, c] = 0.0
        H[i, 3 + i] = 1.0
        for j in range(3):
            H[i, 6 + j] = -S1[i, j]
            H[i, 12 + j] = S2[i, j]


@njit
def h_gnss_vel(x, w, prm, z, nu, H):
    """ν = z − (v + R (ω × r_ant)), H = [0, I, −R [ω × r_ant]×, 0, R [r_ant]×]; w = ω̃."""
    h_gnss_vel_w(x, w, prm, z, nu, H, np.empty((3, 3, 3)), np.empty(3))


@njit
def h_heading_w(x, prm, z, nu, H, S3):
    R, S = S3[0], S3[1]
    quat_to_rot(x[6:10], R)
    r = prm[PRM_RB:PRM_RB + 3]
    bx = R[0, 0] * r[0] + R[0, 1] * r[1] + R[0, 2] * r[2]
    by = R[1, 0] * r[0] + R[1, 1] * r[1] + R[1, 2] * r[2]
    n2 = bx * bx + by * by
    if n2 < 1e-6:
        return False
    d = z[0] - (math.atan2(by, bx) - math.atan2(r[1], r[0]))
    nu[0] = math.atan2(math.sin(d), math.cos(d))
    skew_mul(R, r, S)
    for c in range(15):
        H[0, c] = 0.0
    for j in range(3):
        H[0, 6 + j] = (by * S[0, j] - bx * S[1, j]) / n2
    return True


@njit
def h_heading(x, prm, z, nu, H):
    """Yaw from the baseline b = R r_b: ψ̂ = atan2(b_y, b_x) − atan2(r_b,y, r_b,x) (the body
    yaw when level), ν = wrap(z − ψ̂), H_θ as the module docstring.  False when the baseline
    is (nearly) vertical."""
    return h_heading_w(x, prm, z, nu, H, np.empty((2, 3, 3)))


@njit
def h_radar_w(x, prm, z, nu, H, S3):
    R, S = S3[0], S3[1]
    quat_to_rot(x[6:10], R)
    r = prm[PRM_RRAD:PRM_RRAD + 3]
    c = R[2, 2]
    if c < prm[PRM_COSMAX]:
        return False
    h = x[2] + R[2, 0] * r[0] + R[2, 1] * r[1] + R[2, 2] * r[2] - prm[PRM_ZG]
    if h <= 0.0 or h / c > prm[PRM_RMAX] or z[0] > prm[PRM_RMAX]:
        return False
    nu[0] = z[0] - h / c
    skew_mul(R, r, S)
    for k in range(15):
        H[0, k] = 0.0
    H[0, 2] = 1.0 / c
    # (R [e_z]×)_2j = (R_21, −R_20, 0)
    hc = h / (c * c)
    H[0, 6] = -S[2, 0] / c + hc * R[2, 1]
    H[0, 7] = -S[2, 1] / c + hc * -R[2, 0]
    H[0, 8] = -S[2, 2] / c + hc * 0.0
    return True


@njit
def h_radar(x, prm, z, nu, H):
    """Slant range along body −z to the plane z = z_g (docstring); False = not usable (tilt
    above the beam limit, sensor below the ground, or beyond the maximum range)."""
    return h_radar_w(x, prm, z, nu, H, np.empty((2, 3, 3)))


# ------------------------------------------------------------------------ the innovation gate
@njit
def innov_var(P, H, Rm, i):
    """S_ii = h_i P h_iᵀ + R_ii, over H's non-zero columns only (at most 7 of 15 for the GNSS
    rows)."""
    s = Rm[i, i]
    for a in range(15):
        ha = H[i, a]
        if ha == 0.0:
            continue
        acc = 0.0
        for b in range(15):
            if H[i, b] != 0.0:
                acc += P[a, b] * H[i, b]
        s += ha * acc
    return s


@njit
def gate_ratio(P, H, Rm, nu, gate):
    """The innovation test of PX4 EKF2 (docs.px4.io, *Using the ECL EKF*: "test ratio =
    innovation² / (gate² · innovation variance)", ``EKF2_GPS_GATE`` = 5 σ): the largest over
    the measurement's rows of ν_i² / (γ² S_ii), S_ii from :func:`innov_var`.  A ratio above 1
    fails the gate; a row whose S_ii is not positive (a singular covariance) fails it too
    (ratio ∞)."""
    worst = 0.0
    for i in range(H.shape[0]):
        s = innov_var(P, H, Rm, i)
        if not s > 0.0:
            return np.inf
        r = nu[i] * nu[i] / (gate * gate * s)
        if r > worst:
            worst = r
    return worst


@njit
def step_llr(P, H, Rm, nu, b):
    """The log-likelihood ratio of a receiver without a step against one stepped by ``b``, for
    the innovation ν (S's diagonal): ½ [Σ_i (ν_i − b_i)² / S_ii − Σ_i ν_i² / S_ii]; positive
    when the fix fits no step better."""
    d0 = 0.0
    d1 = 0.0
    for i in range(H.shape[0]):
        s = innov_var(P, H, Rm, i)
        d0 += nu[i] * nu[i] / s
        d1 += (nu[i] - b[i]) * (nu[i] - b[i]) / s
    return 0.5 * (d1 - d0)
