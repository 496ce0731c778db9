"""Error-state INS/GNSS filter with delayed fusion; the bank's four laws as its GNSS update.

Frames and conventions (those of the simulator: ``ag_uav/vehicle/imu.py``): world ENU (z up),
gravity ``g_w = (0, 0, −g)``; the IMU reports the body-frame **specific force**
``f̃ = Rᵀ(a − g_w) + b_a + n_a`` (+g along body z at rest) and the body rate
``ω̃ = ω + b_g + n_g``; ``q = (w, x, y, z)`` is the Hamilton body-to-world quaternion
(MuJoCo's), ``R = R(q)``.

Nominal state (16) and error state (15), after Solà, *Quaternion kinematics for the error-state
Kalman filter* (2017, arXiv:1711.02508), §5 with the local (body) angular error
``q_true = q ⊗ Exp(δθ)``::

    x = [p, v, q, b_a, b_g]                δx = [δp, δv, δθ, δb_a, δb_g]

Prediction, one IMU sample (Solà eqs 5.3.3 / 260 without the gravity state; a = f̃ − b_a,
ω = ω̃ − b_g, R at the start of the step)::

    p ← p + v Δt + ½ (R a + g_w) Δt²,   v ← v + (R a + g_w) Δt,   q ← q ⊗ Exp(ω Δt)
    P ← F P Fᵀ + Q,   F = I + blocks:  F_pv = I Δt,  F_vθ = −R [a]× Δt,  F_vba = −R Δt,
                                       F_θθ = Exp(ω Δt)ᵀ (replaces I),  F_θbg = −I Δt
    Q = diag(σ_a² Δt² I, σ_g² Δt² I, σ_ba² Δt I, σ_bg² Δt I)   on (δv, δθ, δb_a, δb_g)

(Solà eqs 5.4.3 / 269-270: the impulses V_i = σ_ãn² Δt², Θ_i = σ_ω̃n² Δt², A_i = σ_aw² Δt,
Ω_i = σ_ωw² Δt).  ``σ_a``, ``σ_g`` are the per-sample white-noise standard deviations of the
IMU (density over the Nyquist band of the sample rate, plus vibration, as the simulator's IMU
draws them: :meth:`INSConfig.from_imu`), ``σ_ba``, ``σ_bg`` the bias random walks.
``F P Fᵀ`` is written out on F's blocks (``M = F P`` on its first 9 rows, then the upper
triangle of ``M Fᵀ``, mirrored; the bias block, where F = I, is P's own), each entry summed in
F's column order.

Measurements (h, and H = ∂h/∂δx; R [r]× from ∂(R Exp(δθ) r)/∂δθ = −R [r]×):

* GNSS position at the antenna (lever arm ``r_ant`` in body axes)::

      h = p + R r_ant,               H = [I, 0, −R [r_ant]×, 0, 0]

* GNSS velocity at the antenna (ω from the gyro sample of that step)::

      h = v + R (ω × r_ant),         H = [0, I, −R [ω × r_ant]×, 0, R [r_ant]×]

* Dual-antenna heading: azimuth of the antenna baseline ``r_b`` (body) in the world,
  ``b = R r_b``, less the baseline's body azimuth (PX4's ``heading_offset``), so that the
  measurement is the vehicle yaw: ``ψ = atan2(b_y, b_x) − atan2(r_b,y, r_b,x)``::

      H_θ = [−b_y, b_x, 0] / (b_x² + b_y²) · (−R [r_b]×),   ν wrapped to (−π, π]

  This is the default yaw source (the DJI Matrice 350 RTK class carries two GNSS antennas;
  PX4 supports dual-antenna RTK heading "as an alternative to compass-based heading
  estimation", docs.px4.io, *RTK GPS Heading with Dual u-blox F9P*): a magnetometer on a spray
  drone sits among motor and pump currents and steel, whose disturbance is neither white nor
  known, while the baseline heading's error is σ_ψ ≈ σ_b / L (relative-position error over the
  baseline length).  Default σ_ψ = 0.5° is that ratio for σ_b ≈ 5 mm and L ≈ 0.6 m
  (engineering judgement; no DJI datasheet figure was found); receivers report it per fix
  (PX4 ``VehicleGnssHeading.heading_accuracy``), which the caller can pass as the variance.
* Radar altimeter, a narrow beam along body −z from ``r_rad`` to flat ground at ``z_g``
  (slant range over a tilted vehicle: ρ = h / cos(tilt))::

      s = p + R r_rad,   c = (R e_z)_z = cos(tilt),   h = s_z − z_g,   ρ = h / c
      ∂ρ/∂δp_z = 1/c,    ∂ρ/∂δθ = (1/c) (−R [r_rad]×)_z − (h/c²) (−R [e_z]×)_z

  Not fused (a dropout, counted) for a NaN range, c < cos(max tilt) or ρ above the maximum
  range.  (A wide-beam radar returns the nearest echo, ≈ h not h/c: not modelled.)

Update rules of the GNSS **position** (``rule``): ``"kf"`` the Joseph update; ``"mckf"`` the
correntropy fixed point on the position innovation (Chen, Liu, Zhao, Principe, Automatica 80,
2017; σ → ∞ is the KF; lock-out recovery as :class:`estimators.MCKF`); ``"pca-kf"``,
``"pca-mckf"`` the same after the PCA block (Candan & Li §III.C) on the window of antenna
fixes, run once per vehicle when a fix arrives.  The MCKF kernel (``INSConfig.mckf_kernel``):
``"fixed"`` σ per row as given, ``"adaptive"`` the adaptive bandwidth of :class:`estimators.MCKF`
(one row function for both, :func:`estimators.mckf.mckf_adaptive_update_row`; state ŝ per
row), ``"multi"`` σ on the fix's rows, ∞ on the prior's.  Velocity, heading and radar use the
KF update.  **The gate** in front of every rule (PX4 EKF2's innovation test, ``EKF2_GPS_GATE``
= 5 σ; :func:`gate_ratio`): a fix's position, velocity or heading whose innovation exceeds
``gate_sigma`` standard deviations on any axis is not fused; after ``gate_reset_s`` with
neither position nor velocity fused, a rejected fix resets the position to it.  Each
measurement is fused sequentially (R block-diagonal), then injected and reset
(Solà §6.2-6.3, eqs 282-287)::

      p += δp, v += δv, q ← q ⊗ Exp(δθ), b += δb;   P ← G P Gᵀ, G_θθ = I − [½ δθ]×

The laws live in :mod:`estimators._ins_laws` (the bank's own row functions).

**Delayed fusion** (PX4 EKF2: "The EKF runs on a delayed 'fusion time horizon' … an output
predictor … uses buffered IMU data to propagate the states forward to the current time",
docs.px4.io *Using the ECL EKF*; ``EKF2_GPS_DELAY`` default 110 ms, ekf2_params.c): the core
filter (nominal + P) runs ``D = round(delay / Δt)`` IMU samples behind now, from a ring of the
last D+1 samples.  Every measurement carries its time tag (``now − age``) into a queue and is
fused when the core reaches it (at once if it is already late, counted in ``n_late``).  The
output for the controller is the core nominal propagated through the buffered samples (the
same nominal step, so with no new correction it advances one sample per tick).  With
``delayed = False`` (fuse at receipt) D = 0 and every fix is fused as if it were current.

Everything is one compiled kernel per tick over the rows (vehicles × filters): the
single-vehicle :class:`INS` is a :class:`BatchINS` of one vehicle, so a row's arithmetic is the
same whatever the batch (bit-identical rows).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ._ins_laws import kf_fuse_b, mckf_fuse_b, pca_row
from ._jit import njit

__all__ = ["KERNELS", "RULES", "BatchINS", "INS", "INSConfig", "quat_to_rot", "quat_exp",
           "quat_mul", "quat_log_err"]

RULES = ("kf", "mckf", "pca-kf", "pca-mckf")
_RULE_CODE = {r: i for i, r in enumerate(RULES)}
_PCA_MODE = {"channels": 0, "hankel": 1}
_RECOVERY = {None: 0, "none": 0, "kf": 1, "inflate": 2}
G_STD = 9.81
DEG = math.pi / 180.0

# prm (shared parameters) layout
_P_DT, _P_G, _P_QV, _P_QT, _P_QBA, _P_QBG = 0, 1, 2, 3, 4, 5
_P_RANT, _P_RB, _P_RRAD = 6, 9, 12
_P_ZG, _P_COSMAX, _P_RMAX, _P_D, _P_DELAYED, _P_B, _P_QC = 15, 16, 17, 18, 19, 20, 21
_P_GATE, _P_GRESET = 22, 23  # the innovation gate (σ; inf = off), its reset time (ticks)
_NPRM = 24
# ints (per row) layout
_I_NOW, _I_CORE, _I_QN, _I_DIRTY, _I_LATE, _I_QDROP = 0, 1, 2, 3, 4, 5
_I_MST = 6  # 6..9: MCKF (n_rejected, n_iter, rejected, recovered)
_I_NGNSS, _I_NRAD, _I_RDROP = 10, 11, 12
# the gate: position / velocity / heading fixes rejected, position resets to the receiver,
# the core ticks of the last fused (or reset) position and of the last fused velocity
_I_GREJP, _I_GREJV, _I_GREJY, _I_GRESET, _I_GLAST, _I_GLASTV = 13, 14, 15, 16, 17, 18
_NINT = 19
# dg (per row diagnostics and the adaptive kernel's state)
_D_NISP, _D_NISV, _D_NISY, _D_NISR, _D_WY = 0, 1, 2, 3, 4  # 4..6 diag C_y
_D_S2 = 7  # ŝ of the adaptive bandwidth rule (1 after a reset)
_D_GATE = 8  # the last fix's position: 0 fused, 1 rejected by the gate, 2 reset (NaN: none)
_D_RSUM, _D_RN = 9, 10  # the radar NIS summed over the fused ranges, and their number
_NDG = 11
# mpar (per row MCKF parameters) layout: kx(15), ky(3), fpar(5), apar(3), σ(18)
_M_KX, _M_KY, _M_F, _M_A, _M_SIG, _NMPAR = 0, 15, 18, 23, 26, 44
KERNELS = ("fixed", "adaptive", "multi")
# queue record: tick, kind, z(7), zpca(3), var(7)
_Q_T, _Q_K, _Q_Z, _Q_ZP, _Q_V = 0, 1, 2, 9, 12
_QW = 19
# GNSS input row: age, p(3), v(3), yaw, var p(3), var v(3), var yaw
_GIN = 15



# the tick's scratch, one flat buffer per bank shared by its rows (the per-tick path allocates
# nothing): H, ν, R for m = 3 and m = 1, δx, the models' (3, 3, 3) and vector, the adaptive
# MCKF kernels kx, ky; F P (9, 15), the prediction's (5, 3, 3) and vector, the PCA'd fix, three
# NaNs; the KF / MCKF work of one update (estimators.mckf.mckf_work_size(15, 3) floats, whose
# head is the KF work: the two updates never run at once)
_W_H3, _W_NU3, _W_R3, _W_H1, _W_NU1, _W_R1, _W_DX, _W_S3, _W_V = 0, 45, 48, 57, 72, 73, 74, 89, 116
_W_KX, _W_KY, _W_M, _W_S3P, _W_W, _W_ZP, _W_NAN, _W_KF = 124, 139, 142, 277, 322, 338, 341, 344
_NW = _W_KF + 621 + 777  # mckf_work_size(15, 3): kf_work_size(15, 3) = 621, then the MCKF part


@njit
def _w2(fb, o, r, c):
    """The (r, c) view of the scratch at offset o."""
    return fb[o:o + r * c].reshape((r, c))


@njit
def _w3(fb, o, n):
    """The (n, 3, 3) view of the scratch at offset o."""
    return fb[o:o + 9 * n].reshape((n, 3, 3))


# ------------------------------------------------------------------------ quaternion algebra
@njit
def quat_mul(a, b, out):
    """out = a ⊗ b (Hamilton, (w, x, y, z)); out may not alias a or b."""
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]


@njit
def quat_exp(phi, out):
    """out = Exp(φ) = (cos(θ/2), sin(θ/2) φ/θ), θ = ‖φ‖ (Solà eq 101)."""
    th = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    if th < 1e-12:
        out[0] = 1.0
        for k in range(3):
            out[k + 1] = 0.5 * phi[k]
        return
    s = math.sin(0.5 * th) / th
    out[0] = math.cos(0.5 * th)
    for k in range(3):
        out[k + 1] = s * phi[k]


@njit
def quat_to_rot(q, R):
    """R = R(q), body to world (Solà eq 115)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    R[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[0, 1] = 2.0 * (x * y - w * z)
    R[0, 2] = 2.0 * (x * z + w * y)
    R[1, 0] = 2.0 * (x * y + w * z)
    R[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[1, 2] = 2.0 * (y * z - w * x)
    R[2, 0] = 2.0 * (x * z - w * y)
    R[2, 1] = 2.0 * (y * z + w * x)
    R[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit
def quat_log_err(q_est, q_true, out):
    """out = Log(q_est* ⊗ q_true): the local attitude error δθ with q_true = q_est ⊗ Exp(δθ)."""
    c = np.empty(4)
    c[0] = q_est[0]
    for k in range(3):
        c[k + 1] = -q_est[k + 1]
    d = np.empty(4)
    quat_mul(c, q_true, d)
    if d[0] < 0.0:
        for k in range(4):
            d[k] = -d[k]
    n = math.sqrt(d[1] * d[1] + d[2] * d[2] + d[3] * d[3])
    th = 2.0 * math.atan2(n, d[0])
    s = th / n if n > 1e-15 else 2.0
    for k in range(3):
        out[k] = s * d[k + 1]


@njit
def _skew_mul(M, r, out):
    """out = M [r]× (3×3)."""
    for i in range(3):
        out[i, 0] = M[i, 1] * r[2] - M[i, 2] * r[1]
        out[i, 1] = M[i, 2] * r[0] - M[i, 0] * r[2]
        out[i, 2] = M[i, 0] * r[1] - M[i, 1] * r[0]


# ------------------------------------------------------------------------ prediction
@njit
def _nominal_R(x, u, dt, g, R, w):
    """:func:`nominal_step` given R = R(q) of the current x; ``w`` (≥ 14): scratch."""
    a = w[0:3]
    for k in range(3):
        a[k] = u[k] - x[10 + k]
    for i in range(3):
        acc = R[i, 0] * a[0] + R[i, 1] * a[1] + R[i, 2] * a[2]
        if i == 2:
            acc -= g
        x[i] += x[3 + i] * dt + 0.5 * acc * dt * dt
        x[3 + i] += acc * dt
    phi = w[3:6]
    for k in range(3):
        phi[k] = (u[3 + k] - x[13 + k]) * dt
    dq = w[6:10]
    quat_exp(phi, dq)
    qn = w[10:14]
    quat_mul(x[6:10], dq, qn)
    nrm = math.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    for k in range(4):
        x[6 + k] = qn[k] / nrm


@njit
def nominal_step(x, u, dt, g, S3, w):
    """One IMU sample u = (f̃, ω̃) on the nominal x = [p, v, q, b_a, b_g] (module docstring).
    ``S3`` (≥ 1, 3, 3), ``w`` (≥ 14): scratch (the per-tick path allocates nothing)."""
    quat_to_rot(x[6:10], S3[0])
    _nominal_R(x, u, dt, g, S3[0], w)


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
    _skew_mul(R, a, Ra)
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
    dt = prm[_P_DT]
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
        q = prm[_P_QV + b]
        for k in range(3):
            d = 3 + 3 * b + k
            P[d, d] += q


# ------------------------------------------------------------------------ error injection
@njit
def _inject_reset(x, P, dx, w):
    """:func:`inject_reset` with ``w`` (≥ 8) as scratch."""
    for k in range(6):
        x[k] += dx[k]
    for k in range(6):
        x[10 + k] += dx[9 + k]
    dq = w[0:4]
    quat_exp(dx[6:9], dq)
    qn = w[4:8]
    quat_mul(x[6:10], dq, qn)
    nrm = math.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    for k in range(4):
        x[6 + k] = qn[k] / nrm
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
    _inject_reset(x, P, dx, np.empty(8))


# ------------------------------------------------------------------------ measurement models
# Each model h_* has a twin _h_* taking its scratch (S3 (≥ 2, 3, 3), a vector w): the tick's
# path allocates nothing; the public h_* allocate it (tests, callers outside the kernel).
@njit
def _h_gnss_pos(x, prm, z, nu, H, S3):
    R, S = S3[0], S3[1]
    quat_to_rot(x[6:10], R)
    r = prm[_P_RANT:_P_RANT + 3]
    _skew_mul(R, r, S)
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
    _h_gnss_pos(x, prm, z, nu, H, np.empty((2, 3, 3)))


@njit
def _h_gnss_vel(x, w, prm, z, nu, H, S3, wr):
    R, S1, S2 = S3[0], S3[1], S3[2]
    quat_to_rot(x[6:10], R)
    r = prm[_P_RANT:_P_RANT + 3]
    o0, o1, o2 = w[0] - x[13], w[1] - x[14], w[2] - x[15]
    wr[0] = o1 * r[2] - o2 * r[1]
    wr[1] = o2 * r[0] - o0 * r[2]
    wr[2] = o0 * r[1] - o1 * r[0]
    _skew_mul(R, wr, S1)
    _skew_mul(R, r, S2)
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
    _h_gnss_vel(x, w, prm, z, nu, H, np.empty((3, 3, 3)), np.empty(3))


@njit
def _h_heading(x, prm, z, nu, H, S3):
    R, S = S3[0], S3[1]
    quat_to_rot(x[6:10], R)
    r = prm[_P_RB:_P_RB + 3]
    bx = R[0, 0] * r[0] + R[0, 1] * r[1] + R[0, 2] * r[2]
    by = R[1, 0] * r[0] + R[1, 1] * r[1] + R[1, 2] * r[2]
    n2 = bx * bx + by * by
    if n2 < 1e-6:
        return False
    d = z[0] - (math.atan2(by, bx) - math.atan2(r[1], r[0]))
    nu[0] = math.atan2(math.sin(d), math.cos(d))
    _skew_mul(R, r, S)
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
    return _h_heading(x, prm, z, nu, H, np.empty((2, 3, 3)))


@njit
def _h_radar(x, prm, z, nu, H, S3):
    R, S = S3[0], S3[1]
    quat_to_rot(x[6:10], R)
    r = prm[_P_RRAD:_P_RRAD + 3]
    c = R[2, 2]
    if c < prm[_P_COSMAX]:
        return False
    h = x[2] + R[2, 0] * r[0] + R[2, 1] * r[1] + R[2, 2] * r[2] - prm[_P_ZG]
    if h <= 0.0 or h / c > prm[_P_RMAX] or z[0] > prm[_P_RMAX]:
        return False
    nu[0] = z[0] - h / c
    _skew_mul(R, r, S)
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
    return _h_radar(x, prm, z, nu, H, np.empty((2, 3, 3)))


# ------------------------------------------------------------------------ one measurement
@njit
def _fuse_kf(x, P, H, nu, Rm, fb):
    """δx = 0, the KF update of (H, R, ν), inject and reset; the NIS (not finite: not fused)."""
    dx = fb[_W_DX:_W_DX + 15]
    dx[:] = 0.0
    v = kf_fuse_b(dx, P, Rm, H, nu, fb[_W_KF:])
    if np.isfinite(v):
        _inject_reset(x, P, dx, fb[_W_V:_W_V + 8])
    return v


@njit(inline="always")
def _fuse_one(x, P, H, nu, Rm, use_mckf, mpar, ipar, mst, dg, fb):
    """:func:`_fuse_kf` or the MCKF update of (H, R, ν) from δx = 0, inject and reset.  The MCKF
    kernels are fixed (mpar's kx, ky) or adaptive (apar[0] = 1: from the base widths σ and the
    row's ŝ, dg[_D_S2]); diag C_y goes to dg[_D_WY:]."""
    if not use_mckf:
        return _fuse_kf(x, P, H, nu, Rm, fb)
    dx = fb[_W_DX:_W_DX + 15]
    dx[:] = 0.0
    v = mckf_fuse_b(dx, P, Rm, H, nu, (mpar[_M_KX:_M_KY], mpar[_M_KY:_M_F], mpar[_M_F:_M_A], ipar),
                    (mst, dg[_D_WY:_D_WY + 3]), (mpar[_M_A:_M_SIG], mpar[_M_SIG:_NMPAR],
                    dg[_D_S2:_D_S2 + 1], fb[_W_KX:_W_KX + 15], fb[_W_KY:_W_KY + nu.shape[0]]),
                    fb[_W_KF:])  # fb[_W_KF:]: mckf_work_in's work
    if np.isfinite(v):
        _inject_reset(x, P, dx, fb[_W_V:_W_V + 8])
    return v


@njit
def _diag_R(var, Rm):
    """Rm = diag(var[0], …) (m × m, off-diagonal zero)."""
    m = Rm.shape[0]
    for a in range(m):
        for b in range(m):
            Rm[a, b] = 0.0
        Rm[a, a] = var[a]
    return Rm


@njit
def gate_ratio(P, H, Rm, nu, gate):
    """The innovation test of PX4 EKF2 (docs.px4.io, *Using the ECL EKF*: "test ratio =
    innovation² / (gate² · innovation variance)", ``EKF2_GPS_GATE`` = 5 σ): the largest over
    the measurement's rows of ν_i² / (γ² S_ii), S_ii = h_i P h_iᵀ + R_ii.  Only H's non-zero
    columns enter (at most 7 of 15 for the GNSS rows).  A ratio above 1 fails the gate; a row
    whose S_ii is not positive (a singular covariance) fails it too (ratio ∞)."""
    worst = 0.0
    for i in range(H.shape[0]):
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
        if not s > 0.0:
            return np.inf
        r = nu[i] * nu[i] / (gate * gate * s)
        if r > worst:
            worst = r
    return worst


@njit
def _reset_pos(x, P, z, Rm, prm, S3):
    """The position reset to the receiver after a run of rejected fixes (PX4 EKF2 resets to
    GNSS after its fusion timeout): p = z − R r_ant, the position's cross-covariances zeroed
    and its variance the fix's."""
    R = S3[0]
    quat_to_rot(x[6:10], R)
    r = prm[_P_RANT:_P_RANT + 3]
    for i in range(3):
        x[i] = z[i] - (R[i, 0] * r[0] + R[i, 1] * r[1] + R[i, 2] * r[2])
        for c in range(15):
            P[i, c] = 0.0
            P[c, i] = 0.0
    for i in range(3):
        P[i, i] = Rm[i, i]


@njit(inline="always")
def _fuse_pos(x, P, rec, rule, prm, mpar, ipar, ints, dg, fb):
    """The fix's position through the gate (:func:`gate_ratio`; every rule's fix, the PCA'd
    one for rules 2-3), then the rule's law.  Once neither a position nor a velocity has been
    fused for ``_P_GRESET`` ticks (no horizontal aiding: the filter has drifted), a rejected
    fix resets the position (:func:`_reset_pos`); while velocities are fused the position's
    variance grows and the gate itself re-admits the fixes that fit it."""
    H3, nu3, R3 = _w2(fb, _W_H3, 3, 15), fb[_W_NU3:_W_NU3 + 3], _w2(fb, _W_R3, 3, 3)
    S3 = _w3(fb, _W_S3, 3)
    z = rec[_Q_ZP:_Q_ZP + 3] if rule >= 2 else rec[_Q_Z:_Q_Z + 3]
    if not np.isfinite(z[0] + z[1] + z[2]):
        return
    _h_gnss_pos(x, prm, z, nu3, H3, S3)
    Rm = _diag_R(rec[_Q_V:_Q_V + 3], R3)
    core = ints[_I_CORE]
    if gate_ratio(P, H3, Rm, nu3, prm[_P_GATE]) > 1.0:
        ints[_I_GREJP] += 1
        dg[_D_GATE] = 1.0
        if (core - ints[_I_GLAST] >= prm[_P_GRESET]
                and core - ints[_I_GLASTV] >= prm[_P_GRESET]):
            _reset_pos(x, P, z, Rm, prm, S3)
            ints[_I_GRESET] += 1
            ints[_I_GLAST] = core
            dg[_D_GATE] = 2.0
        return
    use_mckf = rule == 1 or rule == 3
    v = _fuse_one(x, P, H3, nu3, Rm, use_mckf, mpar, ipar, ints[_I_MST:_I_MST + 4], dg, fb)
    dg[_D_NISP] = v
    dg[_D_GATE] = 0.0
    ints[_I_GLAST] = core
    ints[_I_NGNSS] += 1


@njit(inline="always")
def _fuse_gnss(x, P, rec, w, rule, prm, mpar, ipar, ints, dg, fb):
    """A GNSS record: position (:func:`_fuse_pos`), then velocity and heading (KF, through the
    same gate), each present when finite; ``fb``: the scratch (``_W_*``).  The record's NIS
    (``dg``) are NaN for a part absent or rejected."""
    H3, nu3, R3 = _w2(fb, _W_H3, 3, 15), fb[_W_NU3:_W_NU3 + 3], _w2(fb, _W_R3, 3, 3)
    H1, nu1, R1 = _w2(fb, _W_H1, 1, 15), fb[_W_NU1:_W_NU1 + 1], _w2(fb, _W_R1, 1, 1)
    S3, wv = _w3(fb, _W_S3, 3), fb[_W_V:_W_V + 8]
    for k in range(3):
        dg[_D_NISP + k] = np.nan
    dg[_D_GATE] = np.nan
    _fuse_pos(x, P, rec, rule, prm, mpar, ipar, ints, dg, fb)
    gate = prm[_P_GATE]
    zv = rec[_Q_Z + 3:_Q_Z + 6]
    if np.isfinite(zv[0] + zv[1] + zv[2]):
        _h_gnss_vel(x, w, prm, zv, nu3, H3, S3, wv)
        Rv = _diag_R(rec[_Q_V + 3:_Q_V + 6], R3)
        if gate_ratio(P, H3, Rv, nu3, gate) > 1.0:
            ints[_I_GREJV] += 1
        else:
            dg[_D_NISV] = _fuse_kf(x, P, H3, nu3, Rv, fb)
            ints[_I_GLASTV] = ints[_I_CORE]
    zy = rec[_Q_Z + 6:_Q_Z + 7]
    if np.isfinite(zy[0]):
        if _h_heading(x, prm, zy, nu1, H1, S3):
            Ry = _diag_R(rec[_Q_V + 6:_Q_V + 7], R1)
            if gate_ratio(P, H1, Ry, nu1, gate) > 1.0:
                ints[_I_GREJY] += 1
            else:
                dg[_D_NISY] = _fuse_kf(x, P, H1, nu1, Ry, fb)


@njit(inline="always")
def _fuse_radar(x, P, rec, prm, mpar, ipar, ints, dg, fb):
    H1, nu1, R1 = _w2(fb, _W_H1, 1, 15), fb[_W_NU1:_W_NU1 + 1], _w2(fb, _W_R1, 1, 1)
    S3 = _w3(fb, _W_S3, 3)
    if np.isfinite(rec[_Q_Z]) and _h_radar(x, prm, rec[_Q_Z:_Q_Z + 1], nu1, H1, S3):
        v = _fuse_kf(x, P, H1, nu1, _diag_R(rec[_Q_V:_Q_V + 1], R1), fb)
        dg[_D_NISR] = v
        if np.isfinite(v):
            dg[_D_RSUM] += v
            dg[_D_RN] += 1.0
        ints[_I_NRAD] += 1
    else:
        ints[_I_RDROP] += 1


@njit
def _any_due(ints, mq):
    """Whether a queued record's tick ≤ the core tick (the scratch is passed only then)."""
    core = ints[_I_CORE]
    for j in range(ints[_I_QN]):
        if mq[j, _Q_T] <= core:
            return True
    return False


@njit(inline="always")
def _fuse_due(x, P, ib, ints, mq, dg, mpar, ipar, rule, prm, fb):
    """Fuse every queued record whose tick ≤ the core tick (in arrival order); compact."""
    core = ints[_I_CORE]
    B = int(prm[_P_B])
    keep = 0
    for j in range(ints[_I_QN]):
        rec = mq[j]
        t = int(rec[_Q_T])
        if t > core:
            if keep != j:
                for k in range(_QW):
                    mq[keep, k] = rec[k]
            keep += 1
            continue
        if t < core:
            ints[_I_LATE] += 1
        if rec[_Q_K] == 0.0:
            _fuse_gnss(x, P, rec, ib[core % B, 3:6], rule, prm, mpar, ipar, ints, dg, fb)
        else:
            _fuse_radar(x, P, rec, prm, mpar, ipar, ints, dg, fb)
        ints[_I_DIRTY] = 1
    ints[_I_QN] = keep


@njit
def _enqueue(ints, mq, prm, kind, age_ticks, z, zp, var):
    """Append a record (tick = now − age in delayed mode, now at receipt)."""
    n = ints[_I_QN]
    if n >= mq.shape[0]:
        ints[_I_QDROP] += 1
        return
    rec = mq[n]
    for k in range(_QW):
        rec[k] = np.nan
    rec[_Q_T] = ints[_I_NOW] - (age_ticks if prm[_P_DELAYED] > 0.0 else 0)
    rec[_Q_K] = kind
    for k in range(z.shape[0]):
        rec[_Q_Z + k] = z[k]
        rec[_Q_V + k] = var[k]
    for k in range(3):
        rec[_Q_ZP + k] = zp[k]
    ints[_I_QN] = n + 1


# ------------------------------------------------------------------------ one row, one tick
@njit
def _advance(xc, P, ib, ints, u, prm, M, S3, w):
    """now += 1, store u; the core takes the sample D ticks back once the ring holds it."""
    B = int(prm[_P_B])
    D = int(prm[_P_D])
    now = ints[_I_NOW] + 1
    ints[_I_NOW] = now
    for k in range(6):
        ib[now % B, k] = u[k]
    if now - D > ints[_I_CORE]:
        uc = ib[(now - D) % B]
        R = S3[0]
        quat_to_rot(xc[6:10], R)   # one R(q) for F and the nominal step
        cov_step(P, xc, uc, prm, R, M, S3, w)
        _nominal_R(xc, uc, prm[_P_DT], prm[_P_G], R, w)
        ints[_I_CORE] = now - D


@njit
def _refresh_output(xc, xo, ib, ints, prm, predicted, S3, w):
    """xo = the core nominal propagated through the buffered samples core+1 … now (or one
    step on the previous output when nothing was fused since)."""
    B = int(prm[_P_B])
    dt, g = prm[_P_DT], prm[_P_G]
    now, core = ints[_I_NOW], ints[_I_CORE]
    if ints[_I_DIRTY] or now == core:
        for k in range(16):
            xo[k] = xc[k]
        for t in range(core + 1, now + 1):
            nominal_step(xo, ib[t % B], dt, g, S3, w)
        ints[_I_DIRTY] = 0
    elif predicted:
        nominal_step(xo, ib[now % B], dt, g, S3, w)


@njit
def _step_kernel(xc, P, xo, ib, ints, mq, dg, mpar, ipar, pbuf, pcs, rules, prm, popt,
                 imu, predict, gin, rin, fb):
    """One tick of every row (row i belongs to vehicle i // n_rules): predict with imu[v] (if
    ``predict``), queue the vehicle's GNSS fix gin[v] (a NaN age: none) and radar range rin[v]
    (NaN: none), fuse what is due, refresh the output; ``fb``: the scratch (``_W_*``)."""
    N = xc.shape[0]
    NV = imu.shape[0]
    nr = N // NV
    M, S3, w = _w2(fb, _W_M, 9, 15), _w3(fb, _W_S3P, 5), fb[_W_W:_W_W + 16]
    zp, nan3 = fb[_W_ZP:_W_ZP + 3], fb[_W_NAN:_W_NAN + 3]
    dt = prm[_P_DT]
    Nw, L, r, mode, any_pca = popt[0], popt[1], popt[2], popt[3], popt[4]
    for v in range(NV):
        g = gin[v]
        has_g = np.isfinite(g[0])
        if has_g and any_pca and np.isfinite(g[1] + g[2] + g[3]):
            pca_row(pbuf[v], pcs[v], g[1:4], Nw, L, r, mode, zp)
        else:
            for k in range(3):  # a loop: numba's slice assignment compiles slowly
                zp[k] = nan3[k]
        has_r = np.isfinite(rin[v, 0])
        for i in range(v * nr, (v + 1) * nr):
            if predict:
                _advance(xc[i], P[i], ib[i], ints[i], imu[v], prm, M, S3, w)
            if has_g:
                age = int(round(g[0] / dt))
                _enqueue(ints[i], mq[i], prm, 0.0, age, g[1:8], zp, g[8:15])
            if has_r:
                _enqueue(ints[i], mq[i], prm, 1.0, int(round(rin[v, 2] / dt)), rin[v, 0:1],
                         nan3, rin[v, 1:2])
            if _any_due(ints[i], mq[i]):
                _fuse_due(xc[i], P[i], ib[i], ints[i], mq[i], dg[i], mpar[i], ipar[i],
                          rules[i], prm, fb)
            _refresh_output(xc[i], xo[i], ib[i], ints[i], prm, predict, S3, w)


# ------------------------------------------------------------------------ configuration
@dataclass
class INSConfig:
    """Parameters of the INS (defaults: the simulator's ICM-42688-P-class IMU at 100 Hz, an
    M350-RTK-class receiver, PX4's GNSS delay).

    IMU noise: ``accel_sigma`` / ``gyro_sigma`` per-sample white std (m/s², rad/s),
    ``accel_bias_rw`` ((m/s²)/√s), ``gyro_bias_rw`` ((rad/s)/√s); :meth:`from_imu` derives
    them from datasheet densities as ``ag_uav.vehicle.imu`` draws them.  Geometry (body axes,
    m): ``lever_arm`` IMU → GNSS antenna, ``heading_baseline`` the dual-antenna baseline
    direction, ``radar_offset`` IMU → radar; ``ground_z`` the flat ground height;
    ``radar_max_tilt_deg``, ``radar_max_range`` the radar's usable cone and range.  Fusion:
    ``delay_s`` (PX4 ``EKF2_GPS_DELAY`` default 110 ms), ``delayed`` (False: fuse at receipt),
    ``queue`` records per row.  GNSS position rule options: ``sigma`` the MCKF kernel
    bandwidth (scalar or 18 values, one per row of the whitened regression: 15 error states,
    then the 3 position channels; ``inf`` = KF), ``mckf_kernel`` (``"fixed"``: those widths;
    ``"adaptive"``: σ_k = σ max(1, √ŝ_k), ŝ the clipped exponentially weighted NIS/3 with
    factor ``adapt_lambda`` and clip ``adapt_clip``, the rule of :class:`estimators.MCKF`
    ``adaptive_sigma``; ``"multi"``: a scalar σ on the 3 position rows and ∞ on the 15 state
    rows, so only the fix is down-weighted, never the INS prior), ``max_iter``, ``eps``,
    ``recovery`` (``"kf"``, ``"inflate"`` or ``None``),
    ``lockout_n``, ``reject_weight``, ``inflate``; PCA block ``pca_window``, ``pca_mode``,
    ``pca_embed``, ``pca_components`` (as :class:`estimators.PCABlock`).  The innovation
    gate, common to the four rules and applied to the GNSS position, velocity and heading
    before any update (:func:`gate_ratio`): ``gate_sigma`` γ (PX4 ``EKF2_GPS_GATE``, default
    5; ``inf`` = no gate) and ``gate_reset_s``: a rejected position fix that comes that long
    after the last fused position and the last fused velocity resets the position to the
    receiver (``inf`` = never).
    """

    dt: float = 0.01
    gravity: float = G_STD
    accel_sigma: float = 0.1004
    gyro_sigma: float = 3.46e-4
    accel_bias_rw: float = 3e-4
    gyro_bias_rw: float = 1e-3 * DEG
    lever_arm: Sequence[float] = (0.0, 0.0, 0.3)
    heading_baseline: Sequence[float] = (0.0, 1.0, 0.0)
    radar_offset: Sequence[float] = (0.0, 0.0, -0.1)
    ground_z: float = 0.0
    radar_max_tilt_deg: float = 30.0
    radar_max_range: float = 50.0
    delay_s: float = 0.11
    delayed: bool = True
    queue: int = 64
    sigma: float | Sequence[float] = 2.0
    mckf_kernel: str = "fixed"
    adapt_lambda: float = 0.98
    adapt_clip: float = 3.0
    max_iter: int = 10
    eps: float = 1e-6
    recovery: str | None = "kf"
    lockout_n: int = 10
    reject_weight: float = 0.05
    inflate: float = 4.0
    pca_window: int = 10
    pca_mode: str = "hankel"
    pca_embed: int | None = None
    pca_components: int | None = None
    gate_sigma: float = 5.0
    gate_reset_s: float = 5.0
    extra: dict = field(default_factory=dict)

    @classmethod
    def from_imu(cls, rate_hz: float, accel_nd_ug: float = 70.0, gyro_nd_mdps: float = 2.8,
                 vibration: float = 0.1, accel_rw: float = 3e-4, gyro_rw_dps: float = 1e-3,
                 **kw) -> INSConfig:
        """σ per sample = density · √(f_s/2) (⊕ vibration for the accelerometer), as
        ``ag_uav.vehicle.imu.accel_sigma`` / ``gyro_sigma``; defaults ICM-42688-P (DS-000347
        Tables 1-2) and the simulator's ``[imu]`` defaults."""
        nyq = math.sqrt(rate_hz / 2.0)
        sa = math.hypot(accel_nd_ug * 1e-6 * G_STD * nyq, vibration)
        sg = gyro_nd_mdps * 1e-3 * DEG * nyq
        return cls(dt=1.0 / rate_hz, accel_sigma=sa, gyro_sigma=sg, accel_bias_rw=accel_rw,
                   gyro_bias_rw=gyro_rw_dps * DEG, **kw)

    def delay_ticks(self) -> int:
        return int(round(self.delay_s / self.dt)) if self.delayed else 0

    def prm(self) -> np.ndarray:
        p = np.zeros(_NPRM)
        dt = self.dt
        p[_P_DT], p[_P_G] = dt, self.gravity
        p[_P_QV] = (self.accel_sigma * dt) ** 2
        p[_P_QT] = (self.gyro_sigma * dt) ** 2
        p[_P_QBA] = self.accel_bias_rw**2 * dt
        p[_P_QBG] = self.gyro_bias_rw**2 * dt
        p[_P_RANT:_P_RANT + 3] = self.lever_arm
        b = np.asarray(self.heading_baseline, dtype=float)
        p[_P_RB:_P_RB + 3] = b / np.linalg.norm(b)
        p[_P_RRAD:_P_RRAD + 3] = self.radar_offset
        p[_P_ZG] = self.ground_z
        p[_P_COSMAX] = math.cos(self.radar_max_tilt_deg * DEG)
        p[_P_RMAX] = self.radar_max_range
        D = self.delay_ticks()
        p[_P_D], p[_P_DELAYED], p[_P_B], p[_P_QC] = D, float(self.delayed), D + 1, self.queue
        if not (self.gate_sigma > 0 and self.gate_reset_s > 0):
            raise ValueError(f"gate_sigma and gate_reset_s must be > 0 (inf = off), got "
                             f"{self.gate_sigma!r}, {self.gate_reset_s!r}")
        p[_P_GATE] = self.gate_sigma
        p[_P_GRESET] = self.gate_reset_s / dt
        return p

    def kernel_widths(self) -> np.ndarray:
        """The 18 base kernel widths (15 state rows, 3 position rows) of ``sigma`` and
        ``mckf_kernel``; ValueError for a bad combination."""
        if self.mckf_kernel not in KERNELS:
            raise ValueError(f"mckf_kernel must be one of {', '.join(KERNELS)}, got "
                             f"{self.mckf_kernel!r}")
        s = np.atleast_1d(np.asarray(self.sigma, dtype=float))
        if self.mckf_kernel == "multi":
            if s.size != 1:
                raise ValueError("mckf_kernel = 'multi' takes a scalar sigma (the position "
                                 "rows'; the 15 state rows get inf)")
            s = np.concatenate([np.full(15, np.inf), np.full(3, s[0])])
        s = np.full(18, s[0]) if s.size == 1 else s
        if s.shape != (18,) or np.any(~(s > 0)):
            raise ValueError("sigma must be a positive scalar or 18 values (15 states + 3)")
        if self.mckf_kernel == "adaptive" and not (0.0 <= self.adapt_lambda < 1.0
                                                   and self.adapt_clip > 0.0):
            raise ValueError("mckf_kernel = 'adaptive' needs 0 <= adapt_lambda < 1 and "
                             "adapt_clip > 0")
        return s

    def mckf_params(self) -> tuple[np.ndarray, np.ndarray]:
        """(mpar = [kx(15), ky(3), fpar(5), apar(3) = (adaptive, λ, clip), σ(18)], ipar(4))
        as :class:`estimators.MCKF` sets them."""
        from scipy.special import gammaincinv

        s = self.kernel_widths()
        c = -1.0 / (2.0 * s * s)
        if self.recovery not in _RECOVERY:
            raise ValueError(f"recovery must be 'kf', 'inflate' or None, got {self.recovery!r}")
        gate = 2.0 * float(gammaincinv(1.5, 0.999))
        jmax = max(1, int(12.0 / math.log10(self.inflate))) if self.inflate > 1 else 1
        mpar = np.concatenate([c[:15], 0.5 * c[15:], [1e-12, self.eps**2, self.reject_weight,
                                                       self.inflate, gate],
                               [float(self.mckf_kernel == "adaptive"), self.adapt_lambda,
                                self.adapt_clip], s])
        ipar = np.array([self.max_iter, self.lockout_n, _RECOVERY[self.recovery], jmax],
                        dtype=np.int64)
        return mpar, ipar


# ------------------------------------------------------------------------ classes
class BatchINS:
    """``n_vehicles`` × ``len(rules)`` INS filters advanced by one compiled call per tick.

    Row ``i`` is vehicle ``i // len(rules)`` with rule ``rules[i % len(rules)]`` (a vehicle's
    bank: one flown filter and its shadows, all fed the same IMU samples and fixes).  Arrays:
    ``x_out`` (N, 16) the output nominal now ``[p, v, q, b_a, b_g]``, ``x_core`` / ``P`` the
    core filter at the fusion horizon (tick ``core_tick``), ``nis`` (N, 4) the last NIS of
    position / velocity / heading / radar.
    """

    def __init__(self, n_vehicles: int, cfg: INSConfig | None = None,
                 rules: Sequence[str] = ("kf",)) -> None:
        self.cfg = cfg = cfg or INSConfig()
        bad = [r for r in rules if r not in _RULE_CODE]
        if bad or not rules:
            raise ValueError(f"rules must be among {RULES}, got {list(rules)}")
        if cfg.pca_mode not in _PCA_MODE:
            raise ValueError(f"pca_mode must be 'hankel' or 'channels', got {cfg.pca_mode!r}")
        self.NV, self.rules = int(n_vehicles), tuple(rules)
        N = self.N = self.NV * len(rules)
        self.prm = cfg.prm()
        B = int(self.prm[_P_B])
        self.x_core = np.zeros((N, 16))
        self.x_core[:, 6] = 1.0
        self.P = np.tile(np.eye(15), (N, 1, 1))
        self.x_out = self.x_core.copy()
        self._ib = np.zeros((N, B, 6))
        self._ints = np.zeros((N, _NINT), dtype=np.int64)
        self._mq = np.zeros((N, cfg.queue, _QW))
        self._dg = np.full((N, _NDG), np.nan)
        self._dg[:, _D_S2] = 1.0
        self._dg[:, _D_RSUM:_D_RN + 1] = 0.0
        mpar, ipar = cfg.mckf_params()
        self._mpar = np.tile(mpar, (N, 1))
        self._ipar = np.tile(ipar, (N, 1))
        self._rules = np.tile(np.array([_RULE_CODE[r] for r in rules], dtype=np.int64), self.NV)
        Nw = int(cfg.pca_window)
        mode = cfg.pca_mode
        L = (Nw // 2 if cfg.pca_embed is None else int(cfg.pca_embed)) if mode == "hankel" else 0
        r = cfg.pca_components or (2 if mode == "hankel" else 1)
        any_pca = any(x.startswith("pca") for x in rules)
        self._popt = np.array([Nw, L, r, _PCA_MODE[mode], int(any_pca)], dtype=np.int64)
        self._pbuf = np.zeros((self.NV, 3, 2 * Nw))
        self._pcs = np.zeros((self.NV, 2), dtype=np.int64)
        self._no_g = np.full((self.NV, _GIN), np.nan)
        self._no_r = np.full((self.NV, 3), np.nan)
        self._no_imu = np.zeros((self.NV, 6))
        self._fb = np.empty(_NW)
        self._fb[_W_NAN:_W_NAN + 3] = np.nan

    # -- state ------------------------------------------------------------------------------
    def reset(self, p, v, q, ba=None, bg=None, P0=None) -> None:
        """Initial nominal per vehicle ((NV, 3) / (NV, 4) or one row for all) and P0 (15
        standard deviations, or a 15×15 matrix); clears the buffers and queues."""
        NV, nr = self.NV, len(self.rules)
        x = np.zeros((NV, 16))
        x[:, 0:3], x[:, 3:6], x[:, 6:10] = p, v, q
        x[:, 10:13] = 0.0 if ba is None else ba
        x[:, 13:16] = 0.0 if bg is None else bg
        x[:, 6:10] /= np.linalg.norm(x[:, 6:10], axis=1, keepdims=True)
        self.x_core[:] = np.repeat(x, nr, axis=0)
        self.x_out[:] = self.x_core
        P0 = np.eye(15) if P0 is None else np.asarray(P0, dtype=float)
        self.P[:] = np.diag(P0**2) if P0.ndim == 1 else P0
        self._ib[:] = 0.0
        self._ints[:] = 0
        self._dg[:] = np.nan
        self._dg[:, _D_S2] = 1.0
        self._dg[:, _D_RSUM:_D_RN + 1] = 0.0
        self._pcs[:] = 0

    def reset_vehicle(self, iv: int, p, v, q, ba=None, bg=None, P0=None) -> None:
        """:meth:`reset` of vehicle ``iv``'s rows only (the others untouched): a vehicle of a
        batch initialised at its own first fix."""
        nr = len(self.rules)
        rows = slice(iv * nr, (iv + 1) * nr)
        x = np.zeros(16)
        x[0:3], x[3:6], x[6:10] = p, v, q
        x[10:13] = 0.0 if ba is None else ba
        x[13:16] = 0.0 if bg is None else bg
        x[6:10] /= np.linalg.norm(x[6:10])
        self.x_core[rows] = x
        self.x_out[rows] = x
        P0 = np.eye(15) if P0 is None else np.asarray(P0, dtype=float)
        self.P[rows] = np.diag(P0**2) if P0.ndim == 1 else P0
        self._ib[rows] = 0.0
        self._ints[rows] = 0
        self._dg[rows] = np.nan
        self._dg[rows, _D_S2] = 1.0
        self._dg[rows, _D_RSUM:_D_RN + 1] = 0.0
        self._pcs[iv] = 0

    # -- ticks ------------------------------------------------------------------------------
    def step(self, imu=None, gnss=None, radar=None) -> None:
        """One tick: predict with ``imu`` (NV, 6) = (f̃, ω̃) if given, then queue the fixes and
        fuse what is due.  ``gnss`` (NV, 15) rows ``[age_s, p(3), v(3), yaw, var_p(3),
        var_v(3), var_yaw]`` (NaN age: no fix; NaN components: absent); ``radar`` (NV, 3)
        rows ``[range, var, age_s]`` (NaN range: none / dropout)."""
        pred = imu is not None
        _step_kernel(self.x_core, self.P, self.x_out, self._ib, self._ints, self._mq,
                     self._dg, self._mpar, self._ipar, self._pbuf, self._pcs, self._rules,
                     self.prm, self._popt,
                     self._no_imu if imu is None else np.ascontiguousarray(imu, dtype=float),
                     pred, self._no_g if gnss is None else np.ascontiguousarray(gnss, dtype=float),
                     self._no_r if radar is None else np.ascontiguousarray(radar, dtype=float),
                     self._fb)

    def step_raw(self, imu, gnss, radar) -> None:
        """:meth:`step` with all three inputs given as C-contiguous float64 arrays (the
        caller's own buffers: no conversion), always predicting."""
        _step_kernel(self.x_core, self.P, self.x_out, self._ib, self._ints, self._mq,
                     self._dg, self._mpar, self._ipar, self._pbuf, self._pcs, self._rules,
                     self.prm, self._popt, imu, True, gnss, radar, self._fb)

    def predict(self, imu) -> None:
        self.step(imu)

    def update(self, gnss=None, radar=None) -> None:
        self.step(None, gnss, radar)

    @staticmethod
    def gnss_row(pos=None, vel=None, yaw=None, var_pos=(1e-4,) * 3, var_vel=(1e-4,) * 3,
                 var_yaw=(0.5 * DEG) ** 2, age_s: float = 0.0) -> np.ndarray:
        """One ``gnss`` input row (absent parts NaN)."""
        g = np.full(_GIN, np.nan)
        g[0] = age_s
        if pos is not None:
            g[1:4] = pos
        if vel is not None:
            g[4:7] = vel
        if yaw is not None:
            g[7] = yaw
        g[8:11], g[11:14], g[14] = var_pos, var_vel, var_yaw
        return g

    # -- views ------------------------------------------------------------------------------
    @property
    def now_tick(self) -> np.ndarray:
        return self._ints[:, _I_NOW]

    @property
    def core_tick(self) -> np.ndarray:
        return self._ints[:, _I_CORE]

    @property
    def nis(self) -> np.ndarray:
        return self._dg[:, :4]

    @property
    def counters(self) -> dict[str, np.ndarray]:
        i = self._ints
        return {"gnss_fused": i[:, _I_NGNSS], "radar_fused": i[:, _I_NRAD],
                "radar_dropped": i[:, _I_RDROP], "late": i[:, _I_LATE],
                "queue_full": i[:, _I_QDROP], "mckf_n_iter": i[:, _I_MST + 1],
                "mckf_rejected": i[:, _I_MST + 2], "mckf_recovered": i[:, _I_MST + 3],
                "gate_rejected_pos": i[:, _I_GREJP], "gate_rejected_vel": i[:, _I_GREJV],
                "gate_rejected_yaw": i[:, _I_GREJY], "gate_resets": i[:, _I_GRESET]}

    @property
    def gate_state(self) -> np.ndarray:
        """(N,) the last fix's position per row: 0 fused, 1 rejected by the gate, 2 rejected
        and reset to the receiver (NaN: no position in the last fix)."""
        return self._dg[:, _D_GATE]

    @property
    def radar_nis(self) -> np.ndarray:
        """(N, 2) the radar NIS summed over the fused ranges, and their number."""
        return self._dg[:, _D_RSUM:_D_RN + 1]


class INS:
    """One INS filter with one GNSS rule: a :class:`BatchINS` of one vehicle and one row (the
    same compiled kernel).  1-D views ``x``, ``P``, ``x_core``; ``p``, ``v``, ``q``, ``b_a``,
    ``b_g`` of the output (now)."""

    def __init__(self, cfg: INSConfig | None = None, rule: str = "kf") -> None:
        self.batch = BatchINS(1, cfg, (rule,))
        self.cfg, self.rule = self.batch.cfg, rule
        self._g = np.full((1, _GIN), np.nan)
        self._r = np.full((1, 3), np.nan)
        self._u = np.zeros((1, 6))

    def reset(self, p, v, q, ba=None, bg=None, P0=None) -> None:
        self.batch.reset(p, v, q, ba, bg, P0)

    def predict(self, f, w) -> None:
        """One IMU sample: specific force f̃ and body rate ω̃ (body axes)."""
        self._u[0, :3], self._u[0, 3:] = f, w
        self.batch.step(self._u)

    def update_gnss(self, pos=None, vel=None, yaw=None, var_pos=(1e-4,) * 3,
                    var_vel=(1e-4,) * 3, var_yaw=(0.5 * DEG) ** 2, age_s: float = 0.0) -> None:
        self._g[0] = BatchINS.gnss_row(pos, vel, yaw, var_pos, var_vel, var_yaw, age_s)
        self.batch.step(None, self._g, None)

    def update_radar(self, rng: float, var: float = 0.05**2, age_s: float = 0.0) -> None:
        self._r[0] = (rng, var, age_s)
        self.batch.step(None, None, self._r)

    @property
    def x(self) -> np.ndarray:
        return self.batch.x_out[0]

    @property
    def x_core(self) -> np.ndarray:
        return self.batch.x_core[0]

    @property
    def P(self) -> np.ndarray:
        return self.batch.P[0]

    p = property(lambda self: self.x[0:3])
    v = property(lambda self: self.x[3:6])
    q = property(lambda self: self.x[6:10])
    b_a = property(lambda self: self.x[10:13])
    b_g = property(lambda self: self.x[13:16])
