"""The INS's model: the nominal and covariance prediction (its quaternion algebra from
:mod:`numkit.geometry`), the error injection and reset, and the measurement models (h, H)
with the innovation gate; formulas and sources in :mod:`estimators.ins`.  Each model ``h_*``
has a twin ``h_*_w`` taking its scratch (the tick's path allocates nothing; the public ``h_*``
allocate it, for tests and callers outside the kernel)."""

from __future__ import annotations

import math

import numpy as np

from numkit import X, Y, Z
from numkit.geometry import quat_exp, quat_log_err, quat_mul, quat_normalize, quat_to_rot

from .._jit import njit
from .layout import HM, PM, PR, RS, WS, E, S, U

HMAT_SIZE, RESET_SIZE = HM.SIZE, RS.SIZE

__all__ = ["cov_step", "gate_ratio", "h_gnss_pos", "h_gnss_pos_w", "h_gnss_vel", "h_gnss_vel_w",
           "h_heading", "h_heading_w", "h_radar", "h_radar_w", "inject_reset", "inject_reset_w",
           "increments", "innov_var", "nominal_step", "nominal_step_R", "quat_exp", "quat_log_err",
           "quat_mul", "quat_to_rot", "skew_mul", "step_llr"]


@njit
def skew_mul(M, r, out):
    """out = M [r]× (3×3): row i of M times the cross-product matrix of r."""
    for i in range(3):
        out[i, X] = M[i, Y] * r[Z] - M[i, Z] * r[Y]
        out[i, Y] = M[i, Z] * r[X] - M[i, X] * r[Z]
        out[i, Z] = M[i, X] * r[Y] - M[i, Y] * r[X]


# ------------------------------------------------------------------------ prediction
@njit
def increments(x, u, up, dt, coning, w):
    """The bias-corrected body-frame rotation vector ``w[WS.DTH:WS.DTH_END]`` and velocity
    increment ``w[WS.DV:WS.DV_END]`` of one IMU sample ``u = (f̃, ω̃)`` (the means of the
    sample's delta-velocity and delta-angle over Δt), with ``up`` the previous sample; ``w``
    (≥ ``STEP.size``, layout ``STEP``): scratch.

    α = (ω̃ − b_g)Δt, ν = (f̃ − b_a)Δt (and α', ν' of ``up``, with the same bias estimate); with
    ``coning`` the two-sample (previous-sample) corrections of Savage, *Strapdown inertial
    navigation integration algorithm design, part 1: attitude algorithms*, JGCD 21(1) 1998
    (coning) and *part 2: velocity and position algorithms*, JGCD 21(2) 1998 (sculling); also
    Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems* (2nd
    ed., 2013), ch. 5::

        φ  = α + (1/12) α' × α                                        (coning)
        Δv = ν + ½ α × ν + (1/12) (α' × ν + ν' × α)      (rotation + sculling)

    without ``coning``: φ = α, Δv = ν (rates held over the step)."""
    a = w[WS.DV:WS.DV_END]
    phi = w[WS.DTH:WS.DTH_END]
    ap = w[WS.DTH_P:WS.DTH_P_END]
    vp = w[WS.DV_P:WS.DV_P_END]
    for k in range(3):
        a[k] = (u[U.F + k] - x[S.BA + k]) * dt        # ν = (f̃ − b_a) Δt
        phi[k] = (u[U.W + k] - x[S.BG + k]) * dt      # α = (ω̃ − b_g) Δt
        vp[k] = (up[U.F + k] - x[S.BA + k]) * dt      # ν'
        ap[k] = (up[U.W + k] - x[S.BG + k]) * dt      # α'
    if not coning:
        return
    c0 = ap[Y] * phi[Z] - ap[Z] * phi[Y]              # α' × α
    c1 = ap[Z] * phi[X] - ap[X] * phi[Z]
    c2 = ap[X] * phi[Y] - ap[Y] * phi[X]
    r0 = 0.5 * (phi[Y] * a[Z] - phi[Z] * a[Y])        # ½ α × ν
    r1 = 0.5 * (phi[Z] * a[X] - phi[X] * a[Z])
    r2 = 0.5 * (phi[X] * a[Y] - phi[Y] * a[X])
    # (α' × ν + ν' × α) / 12
    s0 = (ap[Y] * a[Z] - ap[Z] * a[Y] + vp[Y] * phi[Z] - vp[Z] * phi[Y]) / 12.0
    s1 = (ap[Z] * a[X] - ap[X] * a[Z] + vp[Z] * phi[X] - vp[X] * phi[Z]) / 12.0
    s2 = (ap[X] * a[Y] - ap[Y] * a[X] + vp[X] * phi[Y] - vp[Y] * phi[X]) / 12.0
    a[X] += r0 + s0                                   # Δv = ν + ½ α × ν + sculling
    a[Y] += r1 + s1
    a[Z] += r2 + s2
    phi[X] += c0 / 12.0                               # φ = α + (1/12) α' × α
    phi[Y] += c1 / 12.0
    phi[Z] += c2 / 12.0


@njit
def nominal_step_R(x, u, up, prm, R, w):
    """:func:`nominal_step` given R = R(q) of the current x; ``w`` (layout ``STEP``): scratch."""
    dt, g = prm[PR.DT], prm[PR.G]
    increments(x, u, up, dt, prm[PR.CONING] > 0.0, w)
    dv = w[WS.DV:WS.DV_END]
    for i in range(3):
        acc = (R[i, X] * dv[X] + R[i, Y] * dv[Y] + R[i, Z] * dv[Z]) / dt  # a = R Δv / Δt − g e_z
        if i == Z:
            acc -= g
        x[S.POS + i] += x[S.VEL + i] * dt + 0.5 * acc * dt * dt  # p ← p + v Δt + ½ a Δt²
        x[S.VEL + i] += acc * dt                                  # v ← v + a Δt
    dq = w[WS.DQ:WS.DQ_END]
    quat_exp(w[WS.DTH:WS.DTH_END], dq)                            # Exp(φ)
    qn = w[WS.QN:WS.QN_END]
    quat_mul(x[S.QUAT:S.QUAT_END], dq, qn)                       # q ← q ⊗ Exp(φ)
    quat_normalize(qn, x[S.QUAT:S.QUAT_END])                     # q ← q / |q|


@njit
def nominal_step(x, u, up, prm, S3, w):
    """One IMU sample u = (f̃, ω̃) after the sample ``up`` on the nominal x = [p, v, q, b_a,
    b_g] (module docstring; :func:`increments`).  ``S3`` (≥ 1, 3, 3), ``w`` (layout ``STEP``):
    scratch (the per-tick path allocates nothing)."""
    quat_to_rot(x[S.QUAT:S.QUAT_END], S3[PM.R])
    nominal_step_R(x, u, up, prm, S3[PM.R], w)


@njit
def _fill_F(x, u, dt, R, S3, w):
    """F's non-identity blocks from R = R(q) (layout ``PMAT`` of ``S3``): F_vθ = −R [a]× Δt,
    F_vba = −R Δt, F_θθ = Exp(−ω Δt) as a rotation matrix (F_pv = I Δt, F_θbg = −I Δt are
    scalars); ``S3`` (≥ ``PMAT.size``, 3, 3), ``w`` (layout ``STEP``): scratch."""
    a = w[WS.DV:WS.DV_END]
    phi = w[WS.DTH:WS.DTH_END]
    for k in range(3):
        a[k] = u[U.F + k] - x[S.BA + k]                # a = f̃ − b_a
        phi[k] = -(u[U.W + k] - x[S.BG + k]) * dt      # −ω Δt, ω = ω̃ − b_g
    Ra = S3[PM.RA]
    skew_mul(R, a, Ra)                                 # R [a]×
    dq = w[WS.DQ:WS.DQ_END]
    quat_exp(phi, dq)  # Exp(ω Δt)ᵀ = Exp(−ω Δt)
    quat_to_rot(dq, S3[PM.FTH])
    Fv, Fa = S3[PM.FV], S3[PM.FBA]
    for i in range(3):
        for j in range(3):
            Fv[i, j] = -Ra[i, j] * dt                  # F_vθ = −R [a]× Δt
            Fa[i, j] = -R[i, j] * dt                   # F_vba = −R Δt


@njit
def _fp_rows(P, dt, Fv, Fa, Ft, M):
    """M[0:9] = the δp, δv, δθ rows of F P (its bias rows are P's), each entry summed in F's
    column order; M's δv rows at the δp columns and its δθ rows at the δp, δv columns are not
    needed by :func:`cov_step` and not formed (Ft = F_θθ)."""
    mdt = -dt
    th, ba, bg = E.THETA, E.BA, E.BG
    for i in range(3):
        for c in range(E.SIZE):
            M[E.POS + i, c] = P[E.POS + i, c] + dt * P[E.VEL + i, c]  # δp' = δp + Δt δv
        for c in range(E.VEL, E.SIZE):
            # δv' = δv + F_vθ δθ + F_vba δb_a
            M[E.VEL + i, c] = (P[E.VEL + i, c] + Fv[i, X] * P[th + X, c] + Fv[i, Y] * P[th + Y, c]
                               + Fv[i, Z] * P[th + Z, c] + Fa[i, X] * P[ba + X, c]
                               + Fa[i, Y] * P[ba + Y, c] + Fa[i, Z] * P[ba + Z, c])
        for c in range(E.THETA, E.SIZE):
            # δθ' = F_θθ δθ − Δt δb_g
            M[th + i, c] = (Ft[i, X] * P[th + X, c] + Ft[i, Y] * P[th + Y, c]
                            + Ft[i, Z] * P[th + Z, c] + mdt * P[bg + i, c])


@njit
def cov_step(P, x, u, prm, R, M, S3, w):
    """P ← F P Fᵀ + Q with F's blocks written out (module docstring), R = R(q) of x; M (≥ 9,
    15), S3 (≥ ``PMAT.size``, 3, 3), w (layout ``STEP``): scratch.  M = F P (the δp, δv, δθ
    rows), then the upper triangle of M Fᵀ, mirrored: the block of the bias rows (F = I there)
    is P's own."""
    dt = prm[PR.DT]
    _fill_F(x, u, dt, R, S3, w)
    Fv, Fa, Ft = S3[PM.FV], S3[PM.FBA], S3[PM.FTH]
    _fp_rows(P, dt, Fv, Fa, Ft, M)
    mdt = -dt
    th, ba, bg = E.THETA, E.BA, E.BG
    for r in range(E.BA):
        for c in range(r, E.POS_END):        # (M Fᵀ)_rc, c in δp: M_rc + Δt M_r,v
            s = M[r, c] + M[r, E.VEL + c] * dt
            P[r, c] = s
            P[c, r] = s
        for c in range(max(r, E.VEL), E.VEL_END):   # c in δv: M_rc + M_rθ F_vθᵀ + M_r,ba F_vbaᵀ
            i = c - E.VEL
            s = (M[r, c] + M[r, th + X] * Fv[i, X] + M[r, th + Y] * Fv[i, Y]
                 + M[r, th + Z] * Fv[i, Z] + M[r, ba + X] * Fa[i, X] + M[r, ba + Y] * Fa[i, Y]
                 + M[r, ba + Z] * Fa[i, Z])
            P[r, c] = s
            P[c, r] = s
        for c in range(max(r, E.THETA), E.THETA_END):  # c in δθ: M_rθ F_θθᵀ − Δt M_r,bg
            i = c - E.THETA
            s = (M[r, th + X] * Ft[i, X] + M[r, th + Y] * Ft[i, Y] + M[r, th + Z] * Ft[i, Z]
                 + M[r, bg + i] * mdt)
            P[r, c] = s
            P[c, r] = s
        for c in range(E.BA, E.SIZE):
            s = M[r, c]
            P[r, c] = s
            P[c, r] = s
    for r in range(E.BA, E.SIZE):
        for c in range(r + 1, E.SIZE):
            P[c, r] = P[r, c]
    for b in range(4):   # + Q: the impulses of δv, δθ, δb_a, δb_g on their diagonals
        q = prm[PR.QV + b]
        for k in range(3):
            d = E.VEL + 3 * b + k
            P[d, d] += q


# ------------------------------------------------------------------------ error injection
@njit
def inject_reset_w(x, P, dx, w):
    """:func:`inject_reset` with ``w`` (layout ``RESET``) as scratch."""
    for k in range(6):
        x[S.POS + k] += dx[E.POS + k]      # p ← p + δp, v ← v + δv
    for k in range(6):
        x[S.BA + k] += dx[E.BA + k]        # b ← b + δb
    dq = w[RS.DQ:RS.DQ_END]
    quat_exp(dx[E.THETA:E.THETA_END], dq)
    qn = w[RS.QN:RS.QN_END]
    quat_mul(x[S.QUAT:S.QUAT_END], dq, qn)  # q ← q ⊗ Exp(δθ)
    quat_normalize(qn, x[S.QUAT:S.QUAT_END])  # q ← q / |q|
    th = E.THETA
    h0, h1, h2 = 0.5 * dx[th + X], 0.5 * dx[th + Y], 0.5 * dx[th + Z]
    # G = [[1, h2, −h1], [−h2, 1, h0], [h1, −h0, 1]]: the δθ rows ← G P_θ·, then cols ← · Gᵀ
    g01, g02, g10, g12, g20, g21 = h2, -h1, -h2, h0, h1, -h0
    for c in range(E.SIZE):
        p6, p7, p8 = P[th + X, c], P[th + Y, c], P[th + Z, c]
        P[th + X, c] = 1.0 * p6 + g01 * p7 + g02 * p8
        P[th + Y, c] = g10 * p6 + 1.0 * p7 + g12 * p8
        P[th + Z, c] = g20 * p6 + g21 * p7 + 1.0 * p8
    for r in range(E.SIZE):
        p6, p7, p8 = P[r, th + X], P[r, th + Y], P[r, th + Z]
        P[r, th + X] = p6 * 1.0 + p7 * g01 + p8 * g02
        P[r, th + Y] = p6 * g10 + p7 * 1.0 + p8 * g12
        P[r, th + Z] = p6 * g20 + p7 * g21 + p8 * 1.0
    for r in range(E.SIZE):  # keep P exactly symmetric
        for c in range(r + 1, E.SIZE):
            s = 0.5 * (P[r, c] + P[c, r])
            P[r, c] = s
            P[c, r] = s


@njit
def inject_reset(x, P, dx):
    """x ← x ⊕ δx, then P ← G P Gᵀ with G_θθ = I − [½ δθ]× (Solà eqs 282-287)."""
    inject_reset_w(x, P, dx, np.empty(RESET_SIZE))


# ------------------------------------------------------------------------ measurement models
@njit
def h_gnss_pos_w(x, prm, z, nu, H, S3):
    R, Sr = S3[HM.R], S3[HM.S1]
    quat_to_rot(x[S.QUAT:S.QUAT_END], R)
    r = prm[PR.R_ANT:PR.R_ANT_END]
    skew_mul(R, r, Sr)                                  # R [r_ant]×
    for i in range(3):
        # ν = z − (p + R r_ant)
        nu[i] = z[i] - (x[S.POS + i] + R[i, X] * r[X] + R[i, Y] * r[Y] + R[i, Z] * r[Z])
        for c in range(E.SIZE):
            H[i, c] = 0.0
        H[i, E.POS + i] = 1.0                           # H_p = I
        for j in range(3):
            H[i, E.THETA + j] = -Sr[i, j]               # H_θ = −R [r_ant]×


@njit
def h_gnss_pos(x, prm, z, nu, H):
    """ν = z − (p + R r_ant), H = [I, 0, −R [r_ant]×, 0, 0]."""
    h_gnss_pos_w(x, prm, z, nu, H, np.empty((HMAT_SIZE, 3, 3)))


@njit
def h_gnss_vel_w(x, w, prm, z, nu, H, S3, wr):
    R, S1, S2 = S3[HM.R], S3[HM.S1], S3[HM.S2]
    quat_to_rot(x[S.QUAT:S.QUAT_END], R)
    r = prm[PR.R_ANT:PR.R_ANT_END]
    bg = S.BG
    o0, o1, o2 = w[X] - x[bg + X], w[Y] - x[bg + Y], w[Z] - x[bg + Z]  # ω = ω̃ − b_g
    wr[X] = o1 * r[Z] - o2 * r[Y]                       # ω × r_ant
    wr[Y] = o2 * r[X] - o0 * r[Z]
    wr[Z] = o0 * r[Y] - o1 * r[X]
    skew_mul(R, wr, S1)                                 # R [ω × r_ant]×
    skew_mul(R, r, S2)                                  # R [r_ant]×
    for i in range(3):
        # ν = z − (v + R (ω × r_ant))
        nu[i] = z[i] - (x[S.VEL + i] + R[i, X] * wr[X] + R[i, Y] * wr[Y] + R[i, Z] * wr[Z])
        for c in range(E.SIZE):
            H[i, c] = 0.0
        H[i, E.VEL + i] = 1.0                           # H_v = I
        for j in range(3):
            H[i, E.THETA + j] = -S1[i, j]               # H_θ = −R [ω × r_ant]×
            H[i, E.BG + j] = S2[i, j]                   # H_bg = R [r_ant]×


@njit
def h_gnss_vel(x, w, prm, z, nu, H):
    """ν = z − (v + R (ω × r_ant)), H = [0, I, −R [ω × r_ant]×, 0, R [r_ant]×]; w = ω̃."""
    h_gnss_vel_w(x, w, prm, z, nu, H, np.empty((HMAT_SIZE, 3, 3)), np.empty(3))


@njit
def h_heading_w(x, prm, z, nu, H, S3):
    R, Sr = S3[HM.R], S3[HM.S1]
    quat_to_rot(x[S.QUAT:S.QUAT_END], R)
    r = prm[PR.R_B:PR.R_B_END]
    bx = R[X, X] * r[X] + R[X, Y] * r[Y] + R[X, Z] * r[Z]  # b = R r_b
    by = R[Y, X] * r[X] + R[Y, Y] * r[Y] + R[Y, Z] * r[Z]
    n2 = bx * bx + by * by
    if n2 < 1e-6:
        return False
    d = z[0] - (math.atan2(by, bx) - math.atan2(r[Y], r[X]))  # z − ψ̂
    nu[0] = math.atan2(math.sin(d), math.cos(d))              # ν = wrap(z − ψ̂)
    skew_mul(R, r, Sr)                                       # R [r_b]×
    for c in range(E.SIZE):
        H[0, c] = 0.0
    for j in range(3):
        # H_θ = ∂ψ̂/∂b · (−R [r_b]×) = (b_y (R [r_b]×)_0j − b_x (R [r_b]×)_1j) / (b_x² + b_y²)
        H[0, E.THETA + j] = (by * Sr[X, j] - bx * Sr[Y, j]) / n2
    return True


@njit
def h_heading(x, prm, z, nu, H):
    """Yaw from the baseline b = R r_b: ψ̂ = atan2(b_y, b_x) − atan2(r_b,y, r_b,x) (the body
    yaw when level), ν = wrap(z − ψ̂), H_θ as the module docstring.  False when the baseline
    is (nearly) vertical."""
    return h_heading_w(x, prm, z, nu, H, np.empty((HMAT_SIZE, 3, 3)))


@njit
def h_radar_w(x, prm, z, nu, H, S3):
    R, Sr = S3[HM.R], S3[HM.S1]
    quat_to_rot(x[S.QUAT:S.QUAT_END], R)
    r = prm[PR.R_RAD:PR.R_RAD_END]
    c = R[Z, Z]                                          # cos tilt = (R e_z)_z
    if c < prm[PR.COS_MAX]:
        return False
    # height of the sensor: h = p_z + (R r_rad)_z − z_g
    h = x[S.POS + Z] + R[Z, X] * r[X] + R[Z, Y] * r[Y] + R[Z, Z] * r[Z] - prm[PR.Z_G]
    if h <= 0.0 or h / c > prm[PR.R_MAX] or z[0] > prm[PR.R_MAX]:
        return False
    nu[0] = z[0] - h / c                                 # ν = z − h / cos tilt
    skew_mul(R, r, Sr)                                   # R [r_rad]×
    for k in range(E.SIZE):
        H[0, k] = 0.0
    H[0, E.POS + Z] = 1.0 / c
    # (R [e_z]×)_2j = (R_21, −R_20, 0)
    hc = h / (c * c)
    th = E.THETA
    H[0, th + X] = -Sr[Z, X] / c + hc * R[Z, Y]
    H[0, th + Y] = -Sr[Z, Y] / c + hc * -R[Z, X]
    H[0, th + Z] = -Sr[Z, Z] / c + hc * 0.0
    return True


@njit
def h_radar(x, prm, z, nu, H):
    """Slant range along body −z to the plane z = z_g (docstring); False = not usable (tilt
    above the beam limit, sensor below the ground, or beyond the maximum range)."""
    return h_radar_w(x, prm, z, nu, H, np.empty((HMAT_SIZE, 3, 3)))


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
