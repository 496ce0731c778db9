"""The INS's fusion and its tick: one measurement through the gate and the rule's law (the
bank's own row functions, :mod:`estimators._ins_laws`), the delayed-fusion queue (PX4 EKF2's
fusion time horizon), and :func:`step_kernel`, one tick of every row of a bank; see
:mod:`estimators.ins`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._ins_laws import kf_fuse_b, mckf_fuse_b, pca_row
from .._jit import njit
from .layout import (
    DG_GATE,
    DG_GB,
    DG_GC,
    DG_GR,
    DG_GS,
    DG_NISP,
    DG_NISR,
    DG_NISV,
    DG_NISY,
    DG_RN,
    DG_RSUM,
    DG_S2,
    DG_WY,
    GIN_AGE,
    GIN_N,
    GIN_P,
    GIN_VARP,
    INTS_CORE,
    INTS_DIRTY,
    INTS_GLAST,
    INTS_GLASTV,
    INTS_GLAT0,
    INTS_GLATCH,
    INTS_GNREL,
    INTS_GRAW,
    INTS_GREJP,
    INTS_GREJV,
    INTS_GREJY,
    INTS_GREL,
    INTS_GRESET,
    INTS_GRST,
    INTS_LATE,
    INTS_MST,
    INTS_NGNSS,
    INTS_NOW,
    INTS_NRAD,
    INTS_QDROP,
    INTS_QN,
    INTS_RDROP,
    MPAR_A,
    MPAR_F,
    MPAR_KX,
    MPAR_KY,
    MPAR_N,
    MPAR_SIG,
    PRM_B,
    PRM_D,
    PRM_DELAYED,
    PRM_DT,
    PRM_GATE,
    PRM_GLATCH,
    PRM_GRESET,
    PRM_PCAW,
    PRM_RANT,
    REC_K,
    REC_N,
    REC_T,
    REC_V,
    REC_Z,
    REC_ZP,
    RIN_AGE,
    RIN_RANGE,
    RIN_VAR,
    W_DX,
    W_H1,
    W_H3,
    W_KF,
    W_KX,
    W_KY,
    W_M,
    W_NAN,
    W_NU1,
    W_NU3,
    W_NUR,
    W_R1,
    W_R3,
    W_S3,
    W_S3P,
    W_V,
    W_W,
    W_ZP,
    view2,
    view3,
)
from .model import (
    cov_step,
    gate_ratio,
    h_gnss_pos_w,
    h_gnss_vel_w,
    h_heading_w,
    h_radar_w,
    inject_reset_w,
    innov_var,
    nominal_step,
    nominal_step_R,
    quat_to_rot,
    step_llr,
)


class BankRows(NamedTuple):
    """The rows of a :class:`~estimators.ins.bank.BatchINS`, declared once (layouts in
    :mod:`.layout`): per filter row the core state ``xc`` and covariance ``P``, the output
    state ``xo``, the IMU ring ``ib``, the integer state ``ints``, the measurement queue ``mq``,
    the diagnostics ``dg``, the float and integer parameters ``mpar``, ``ipar`` and the rule
    codes ``rules``; per vehicle the PCA ring ``pbuf`` and its counters ``pcs``."""

    xc: np.ndarray
    P: np.ndarray
    xo: np.ndarray
    ib: np.ndarray
    ints: np.ndarray
    mq: np.ndarray
    dg: np.ndarray
    mpar: np.ndarray
    ipar: np.ndarray
    pbuf: np.ndarray
    pcs: np.ndarray
    rules: np.ndarray

__all__ = ["step_kernel"]


# ------------------------------------------------------------------------ one measurement
@njit
def _fuse_kf(x, P, H, nu, Rm, fb):
    """δx = 0, the KF update of (H, R, ν), inject and reset; the NIS (not finite: not fused)."""
    dx = fb[W_DX:W_DX + 15]
    dx[:] = 0.0
    v = kf_fuse_b(dx, P, Rm, H, nu, fb[W_KF:])
    if np.isfinite(v):
        inject_reset_w(x, P, dx, fb[W_V:W_V + 8])
    return v


@njit(inline="always")
def _fuse_one(x, P, meas, use_mckf, par, mst, dg, fb):
    """:func:`_fuse_kf` or the MCKF update of ``meas`` = (H, ν, R) from δx = 0, inject and
    reset.  ``par`` = the row's (rule, prm, mpar, ipar).  The MCKF kernels are fixed (mpar's
    kx, ky) or adaptive (apar[0] = 1: from the base widths σ and the row's ŝ, dg[DG_S2]);
    diag C_y goes to dg[DG_WY:]."""
    H, nu, Rm = meas
    if not use_mckf:
        return _fuse_kf(x, P, H, nu, Rm, fb)
    _, _, mpar, ipar = par
    dx = fb[W_DX:W_DX + 15]
    dx[:] = 0.0
    mp = (mpar[MPAR_KX:MPAR_KY], mpar[MPAR_KY:MPAR_F], mpar[MPAR_F:MPAR_A], ipar)
    ad = (mpar[MPAR_A:MPAR_SIG], mpar[MPAR_SIG:MPAR_N], dg[DG_S2:DG_S2 + 1],
          fb[W_KX:W_KX + 15], fb[W_KY:W_KY + nu.shape[0]])
    # fb[W_KF:]: mckf_work_in's work
    v = mckf_fuse_b(dx, P, Rm, H, nu, mp, (mst, dg[DG_WY:DG_WY + 3]), ad, fb[W_KF:])
    if np.isfinite(v):
        inject_reset_w(x, P, dx, fb[W_V:W_V + 8])
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
def _reset_pos(x, P, z, Rm, prm, S3):
    """The position reset to the receiver after a run of rejected fixes (PX4 EKF2 resets to
    GNSS after its fusion timeout): p = z − R r_ant, the position's cross-covariances zeroed
    and its variance the fix's."""
    R = S3[0]
    quat_to_rot(x[6:10], R)
    r = prm[PRM_RANT:PRM_RANT + 3]
    for i in range(3):
        x[i] = z[i] - (R[i, 0] * r[0] + R[i, 1] * r[1] + R[i, 2] * r[2])
        for c in range(15):
            P[i, c] = 0.0
            P[c, i] = 0.0
    for i in range(3):
        P[i, i] = Rm[i, i]


#: the step latch's states (``INTS_GLATCH``): none, a candidate step (one fix rejected), a
#: confirmed step (the next fix rejected too, and nearer the step than the filter)
LATCH_NONE, LATCH_CANDIDATE, LATCH_ON = 0, 1, 2


@njit
def _latch_holds(P, H3, Rm, nu3, prm, ints, dg):
    """Whether the confirmed latch still holds after this fix.  Page's CUSUM of the evidence
    for the unstepped receiver, C ← max(0, C + clip(λ, ±γ²/2)), λ = :func:`step_llr` (one fix
    weighs at most what a γ-σ event does, so a lone outlier cannot release it); C ≥ γ²
    releases it, and so does a fix whose reported variance is not within a factor 2 of the
    latched fix's (the receiver has a new solution, a new fix type: the step was the old
    one's)."""
    r0 = dg[DG_GR]
    c = 0.0
    if 0.5 * r0 <= Rm[0, 0] <= 2.0 * r0:
        h = 0.5 * prm[PRM_GATE] * prm[PRM_GATE]
        lam = min(max(step_llr(P, H3, Rm, nu3, dg[DG_GB:DG_GB + 3]), -h), h)
        c = max(0.0, dg[DG_GC] + lam)
        dg[DG_GC] = c
        if c < 2.0 * h:
            return True
    ints[INTS_GLATCH] = LATCH_NONE
    ints[INTS_GREL] += 1
    return False


@njit
def _open_latch(P, H3, Rm, nu3, ints, dg):
    """A fix the gate rejected opens a candidate step: b = its innovation, b's variance = its
    innovation variance per axis."""
    ints[INTS_GLATCH] = LATCH_CANDIDATE
    ints[INTS_GLAT0] = ints[INTS_CORE]
    dg[DG_GC] = 0.0
    dg[DG_GR] = Rm[0, 0]
    for i in range(3):
        dg[DG_GB + i] = nu3[i]
        dg[DG_GS + i] = innov_var(P, H3, Rm, i)


@njit
def _filter_as_sure(P, H3, Rm):
    """Whether the filter knows the antenna's horizontal position at least as well as the fix
    does (S_ii ≤ 2 R_ii, east and north): only then is a rejected fix evidence that the
    receiver stepped.  A filter less sure than its fixes (out of a float or DGPS period, into
    RTK fixed) disagreeing with them is more likely wrong itself, and is not latched."""
    for i in range(2):
        if innov_var(P, H3, Rm, i) > 2.0 * Rm[i, i]:
            return False
    return True


@njit
def _hold_fix(nu3, nur, Rm, ints, dg):
    """A fix the confirmed latch holds: its position is not taken; it is fused relative to
    the step (ν ← ν_raw − b, R ← R + diag(var b)) through the gate again."""
    ints[INTS_GREJP] += 1
    dg[DG_GATE] = 3.0
    for i in range(3):
        nu3[i] = nur[i] - dg[DG_GB + i]
        Rm[i, i] += dg[DG_GS + i]


@njit
def _reject_fix(x, P, z, meas, prm, ints, dg, S3, force_reset):
    """A fix the gate rejects: counted; a reset to the receiver when forced (the latch's hold
    limit), once neither a position nor a velocity has been fused for ``PRM_GRESET`` ticks
    (no horizontal aiding: the filter has drifted), or once no position has been fused for
    twice that (PX4 EKF2's ``shouldResetGpsFusion``: the aiding timeout, or the position's
    alone for twice ``reset_timeout_max``); else, when the raw fix (``meas``'s ν) fails the
    gate too, the latch's confirmation when the candidate's step fits it, or a candidate
    step: only once the filter has fused fixes for ``PRM_GRESET`` ticks since it was set on
    one (its start, a reset), and is as sure as the fix (:func:`_filter_as_sure`)."""
    H3, nu3, Rm = meas
    core = ints[INTS_CORE]
    ints[INTS_GREJP] += 1
    dg[DG_GATE] = 1.0
    since = core - ints[INTS_GLAST]
    if force_reset or since >= 2.0 * prm[PRM_GRESET] or (
            since >= prm[PRM_GRESET] and core - ints[INTS_GLASTV] >= prm[PRM_GRESET]):
        _reset_pos(x, P, z, Rm, prm, S3)
        ints[INTS_GRESET] += 1
        ints[INTS_GLAST] = core
        ints[INTS_GRST] = core
        ints[INTS_GLATCH] = LATCH_NONE
        dg[DG_GATE] = 2.0
    elif prm[PRM_GLATCH] > 0.0 and gate_ratio(P, H3, Rm, nu3, prm[PRM_GATE]) > 1.0:
        if (ints[INTS_GLATCH] == LATCH_CANDIDATE
                and step_llr(P, H3, Rm, nu3, dg[DG_GB:DG_GB + 3]) < 0.0):
            ints[INTS_GLATCH] = LATCH_ON
        elif core - ints[INTS_GRST] >= prm[PRM_GRESET] and _filter_as_sure(P, H3, Rm):
            _open_latch(P, H3, Rm, nu3, ints, dg)


@njit(inline="always")
def _fuse_pos(x, P, rec, par, ints, dg, fb):
    """The fix's position through the gate (:func:`gate_ratio`; every rule's fix, the PCA'd
    one for rules 2-3) and the step latch (module docstring of :mod:`estimators.ins`), then
    the rule's law.  A rejected fix opens a candidate step; the next fix, rejected too and
    nearer the step than the filter, confirms it; while the confirmed latch holds
    (:func:`_latch_holds`) the fixes are held (:func:`_hold_fix`); held for ``PRM_GLATCH``
    ticks, the position resets to the receiver (:func:`_reject_fix`).  The latch works on the
    raw fix for every rule: a false fix is the receiver's step, which the PCA block's window
    spreads over its fixes (a PCA'd fix the gate rejects opens nothing unless the raw fix
    fails the gate too, and a held fix is fused raw, relative to the raw step).  A PCA rule
    fuses the raw fix while its PCA window spans a fix whose raw position the gate rejected
    or the latch held (that fix and the ``PRM_PCAW`` − 1 after it): a fix the gate keeps out
    does not come in through the window, whose reconstruction rings after an outlier or a
    step's end by centimetres (as the window's restart after it would)."""
    rule, prm, _, _ = par
    H3, nu3, R3 = view2(fb, W_H3, 3, 15), fb[W_NU3:W_NU3 + 3], view2(fb, W_R3, 3, 3)
    S3, nur = view3(fb, W_S3, 3), fb[W_NUR:W_NUR + 3]
    zr = rec[REC_Z:REC_Z + 3]
    z = rec[REC_ZP:REC_ZP + 3] if rule >= 2 else zr
    if not np.isfinite(z[0] + z[1] + z[2] + zr[0] + zr[1] + zr[2]):
        return
    h_gnss_pos_w(x, prm, zr, nur, H3, S3)   # the raw fix's ν: the latch's
    Rm = _diag_R(rec[REC_V:REC_V + 3], R3)
    if rule >= 2 and gate_ratio(P, H3, Rm, nur, prm[PRM_GATE]) > 1.0:
        ints[INTS_GRAW] = int(prm[PRM_PCAW])
    pca = rule >= 2 and ints[INTS_GRAW] <= 0
    if ints[INTS_GRAW] > 0:
        ints[INTS_GRAW] -= 1
    if pca:
        h_gnss_pos_w(x, prm, z, nu3, H3, S3)
    else:
        z = zr
        for i in range(3):
            nu3[i] = nur[i]
    core = ints[INTS_CORE]
    held = reject = force = False
    if ints[INTS_GLATCH] == LATCH_ON and _latch_holds(P, H3, Rm, nur, prm, ints, dg):
        if core - ints[INTS_GLAT0] < prm[PRM_GLATCH]:
            held = True
            ints[INTS_GRAW] = int(prm[PRM_PCAW]) - 1
            _hold_fix(nu3, nur, Rm, ints, dg)
            if gate_ratio(P, H3, Rm, nu3, prm[PRM_GATE]) > 1.0:
                return
        else:
            reject = force = True
    elif gate_ratio(P, H3, Rm, nu3, prm[PRM_GATE]) > 1.0:
        reject = True
    if reject:   # one call site each: an inlined callee is compiled once per site
        _reject_fix(x, P, z, (H3, nur, Rm), prm, ints, dg, S3, force)
        return
    if not held:
        ints[INTS_GLATCH] = LATCH_NONE
    v = _fuse_one(x, P, (H3, nu3, Rm), rule == 1 or rule == 3, par, ints[INTS_MST:INTS_MST + 4],
                  dg, fb)
    dg[DG_NISP] = v
    ints[INTS_GLAST] = core
    if held:
        ints[INTS_GNREL] += 1
    else:
        dg[DG_GATE] = 0.0
        ints[INTS_NGNSS] += 1


@njit(inline="always")
def _fuse_gnss(x, P, rec, w, par, ints, dg, fb):
    """A GNSS record: position (:func:`_fuse_pos`), then velocity and heading (KF, through the
    same gate), each present when finite; ``w`` the gyro sample of the record's tick, ``par``
    the row's (rule, prm, mpar, ipar), ``fb`` the scratch (:data:`layout.SCRATCH`).  The
    record's NIS (``dg``) are NaN for a part absent or rejected."""
    prm = par[1]
    H3, nu3, R3 = view2(fb, W_H3, 3, 15), fb[W_NU3:W_NU3 + 3], view2(fb, W_R3, 3, 3)
    H1, nu1, R1 = view2(fb, W_H1, 1, 15), fb[W_NU1:W_NU1 + 1], view2(fb, W_R1, 1, 1)
    S3, wv = view3(fb, W_S3, 3), fb[W_V:W_V + 8]
    for k in range(3):
        dg[DG_NISP + k] = np.nan
    dg[DG_GATE] = np.nan
    _fuse_pos(x, P, rec, par, ints, dg, fb)
    gate = prm[PRM_GATE]
    zv = rec[REC_Z + 3:REC_Z + 6]
    if np.isfinite(zv[0] + zv[1] + zv[2]):
        h_gnss_vel_w(x, w, prm, zv, nu3, H3, S3, wv)
        Rv = _diag_R(rec[REC_V + 3:REC_V + 6], R3)
        if gate_ratio(P, H3, Rv, nu3, gate) > 1.0:
            ints[INTS_GREJV] += 1
        else:
            dg[DG_NISV] = _fuse_kf(x, P, H3, nu3, Rv, fb)
            ints[INTS_GLASTV] = ints[INTS_CORE]
    zy = rec[REC_Z + 6:REC_Z + 7]
    if np.isfinite(zy[0]):
        if h_heading_w(x, prm, zy, nu1, H1, S3):
            Ry = _diag_R(rec[REC_V + 6:REC_V + 7], R1)
            if gate_ratio(P, H1, Ry, nu1, gate) > 1.0:
                ints[INTS_GREJY] += 1
            else:
                dg[DG_NISY] = _fuse_kf(x, P, H1, nu1, Ry, fb)


@njit(inline="always")
def _fuse_radar(x, P, rec, prm, ints, dg, fb):
    """A radar record (KF; :func:`h_radar_w` says whether the range is usable)."""
    H1, nu1, R1 = view2(fb, W_H1, 1, 15), fb[W_NU1:W_NU1 + 1], view2(fb, W_R1, 1, 1)
    S3 = view3(fb, W_S3, 3)
    if np.isfinite(rec[REC_Z]) and h_radar_w(x, prm, rec[REC_Z:REC_Z + 1], nu1, H1, S3):
        v = _fuse_kf(x, P, H1, nu1, _diag_R(rec[REC_V:REC_V + 1], R1), fb)
        dg[DG_NISR] = v
        if np.isfinite(v):
            dg[DG_RSUM] += v
            dg[DG_RN] += 1.0
        ints[INTS_NRAD] += 1
    else:
        ints[INTS_RDROP] += 1


@njit
def _any_due(ints, mq):
    """Whether a queued record's tick ≤ the core tick (the scratch is passed only then)."""
    core = ints[INTS_CORE]
    for j in range(ints[INTS_QN]):
        if mq[j, REC_T] <= core:
            return True
    return False


@njit(inline="always")
def _fuse_due(x, P, ib, ints, mq, dg, par, fb):
    """Fuse every queued record whose tick ≤ the core tick (in arrival order); compact.
    ``par`` = the row's (rule, prm, mpar, ipar)."""
    prm = par[1]
    core = ints[INTS_CORE]
    B = int(prm[PRM_B])
    keep = 0
    for j in range(ints[INTS_QN]):
        rec = mq[j]
        t = int(rec[REC_T])
        if t > core:
            if keep != j:
                for k in range(REC_N):
                    mq[keep, k] = rec[k]
            keep += 1
            continue
        if t < core:
            ints[INTS_LATE] += 1
        if rec[REC_K] == 0.0:
            _fuse_gnss(x, P, rec, ib[core % B, 3:6], par, ints, dg, fb)
        else:
            _fuse_radar(x, P, rec, prm, ints, dg, fb)
        ints[INTS_DIRTY] = 1
    ints[INTS_QN] = keep


@njit
def _enqueue(ints, mq, prm, kind, age_ticks, z, zp, var):
    """Append a record (tick = now − age in delayed mode, now at receipt)."""
    n = ints[INTS_QN]
    if n >= mq.shape[0]:
        ints[INTS_QDROP] += 1
        return
    rec = mq[n]
    for k in range(REC_N):
        rec[k] = np.nan
    rec[REC_T] = ints[INTS_NOW] - (age_ticks if prm[PRM_DELAYED] > 0.0 else 0)
    rec[REC_K] = kind
    for k in range(z.shape[0]):
        rec[REC_Z + k] = z[k]
        rec[REC_V + k] = var[k]
    for k in range(3):
        rec[REC_ZP + k] = zp[k]
    ints[INTS_QN] = n + 1


# ------------------------------------------------------------------------ one row, one tick
@njit
def _advance(xc, P, ib, ints, u, prm, M, S3, w):
    """now += 1, store u; the core takes the sample D ticks back once the ring holds it (and
    the one before it, for the coning and sculling corrections: the ring holds D + 2)."""
    B = int(prm[PRM_B])
    D = int(prm[PRM_D])
    now = ints[INTS_NOW] + 1
    ints[INTS_NOW] = now
    for k in range(6):
        ib[now % B, k] = u[k]
    if now - D > ints[INTS_CORE]:
        uc = ib[(now - D) % B]
        R = S3[0]
        quat_to_rot(xc[6:10], R)   # one R(q) for F and the nominal step
        cov_step(P, xc, uc, prm, R, M, S3, w)
        nominal_step_R(xc, uc, ib[(now - D - 1) % B], prm, R, w)
        ints[INTS_CORE] = now - D


@njit
def _refresh_output(xc, xo, ib, ints, prm, predicted, S3, w):
    """xo = the core nominal propagated through the buffered samples core+1 … now (or one
    step on the previous output when nothing was fused since)."""
    B = int(prm[PRM_B])
    now, core = ints[INTS_NOW], ints[INTS_CORE]
    if ints[INTS_DIRTY] or now == core:
        for k in range(16):
            xo[k] = xc[k]
        for t in range(core + 1, now + 1):
            nominal_step(xo, ib[t % B], ib[(t - 1) % B], prm, S3, w)
        ints[INTS_DIRTY] = 0
    elif predicted:
        nominal_step(xo, ib[now % B], ib[(now - 1) % B], prm, S3, w)


@njit
def step_kernel(rows, prm, popt, imu, predict, gin, rin, fb):
    """One tick of every row (row i belongs to vehicle i // n_rules): predict with imu[v] (if
    ``predict``), queue the vehicle's GNSS fix gin[v] (a NaN age: none) and radar range rin[v]
    (NaN: none), fuse what is due, refresh the output; ``fb``: the scratch
    (:data:`layout.SCRATCH`).  ``rows``: the bank's :class:`BankRows` (a plain tuple in field
    order, named again here); shared ``prm`` and ``popt`` = (window, embed, components, mode,
    any PCA rule)."""
    r = BankRows(*rows)
    xc, P, xo, ib, ints, mq, dg = r.xc, r.P, r.xo, r.ib, r.ints, r.mq, r.dg
    mpar, ipar, pbuf, pcs, rules = r.mpar, r.ipar, r.pbuf, r.pcs, r.rules
    N = xc.shape[0]
    NV = imu.shape[0]
    nr = N // NV
    M, S3, w = view2(fb, W_M, 9, 15), view3(fb, W_S3P, 5), fb[W_W:W_W + 18]
    zp, nan3 = fb[W_ZP:W_ZP + 3], fb[W_NAN:W_NAN + 3]
    dt = prm[PRM_DT]
    Nw, L, r, mode, any_pca = popt[0], popt[1], popt[2], popt[3], popt[4]
    for v in range(NV):
        g = gin[v]
        has_g = np.isfinite(g[GIN_AGE])
        if has_g and any_pca and np.isfinite(g[GIN_P] + g[GIN_P + 1] + g[GIN_P + 2]):
            pca_row(pbuf[v], pcs[v], g[GIN_P:GIN_P + 3], Nw, L, r, mode, zp)
        else:
            for k in range(3):  # a loop: numba's slice assignment compiles slowly
                zp[k] = nan3[k]
        has_r = np.isfinite(rin[v, RIN_RANGE])
        for i in range(v * nr, (v + 1) * nr):
            if predict:
                _advance(xc[i], P[i], ib[i], ints[i], imu[v], prm, M, S3, w)
            if has_g:
                age = int(round(g[GIN_AGE] / dt))  # p, v, yaw and their variances
                _enqueue(ints[i], mq[i], prm, 0.0, age, g[GIN_P:GIN_VARP], zp, g[GIN_VARP:GIN_N])
            if has_r:
                _enqueue(ints[i], mq[i], prm, 1.0, int(round(rin[v, RIN_AGE] / dt)),
                         rin[v, RIN_RANGE:RIN_RANGE + 1], nan3, rin[v, RIN_VAR:RIN_VAR + 1])
            if _any_due(ints[i], mq[i]):
                _fuse_due(xc[i], P[i], ib[i], ints[i], mq[i], dg[i],
                          (rules[i], prm, mpar[i], ipar[i]), fb)
            _refresh_output(xc[i], xo[i], ib[i], ints[i], prm, predict, S3, w)

