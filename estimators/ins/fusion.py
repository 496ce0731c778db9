"""The INS's fusion and its tick: one measurement through the gate and the rule's law (the
bank's own row functions, :mod:`estimators._ins_laws`), the delayed-fusion queue (PX4 EKF2's
fusion time horizon), and :func:`step_kernel`, one tick of every row of a bank; see
:mod:`estimators.ins`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from numkit import X, Y, Z

from .._ins_laws import kf_fuse_b, mckf_fuse_b, pca_row
from .._jit import njit
from .layout import CT, DGA, GI, GZ, HM, MP, NZ, PM, PO, PR, RC, RI, E, S, U, W, view2, view3
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

HMAT_SIZE, PMAT_SIZE = HM.SIZE, PM.SIZE


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
    dx = fb[W.DX:W.DX_END]
    dx[:] = 0.0
    v = kf_fuse_b(dx, P, Rm, H, nu, fb[W.KF:])
    if np.isfinite(v):
        inject_reset_w(x, P, dx, fb[W.V:W.V_END])
    return v


@njit(inline="always")
def _fuse_one(x, P, meas, use_mckf, par, mst, dg, fb):
    """:func:`_fuse_kf` or the MCKF update of ``meas`` = (H, ν, R) from δx = 0, inject and
    reset.  ``par`` = the row's (rule, prm, mpar, ipar).  The MCKF kernels are fixed (mpar's
    kx, ky) or adaptive (apar[0] = 1: from the base widths σ and the row's ŝ, dg[DGA.S2]);
    diag C_y goes to dg[DGA.WY:]."""
    H, nu, Rm = meas
    if not use_mckf:
        return _fuse_kf(x, P, H, nu, Rm, fb)
    _, _, mpar, ipar = par
    dx = fb[W.DX:W.DX_END]
    dx[:] = 0.0
    mp = (mpar[MP.KX:MP.KX_END], mpar[MP.KY:MP.KY_END], mpar[MP.F:MP.F_END], ipar)
    ad = (mpar[MP.A:MP.A_END], mpar[MP.SIG:MP.SIG_END], dg[DGA.S2:DGA.S2_END],
          fb[W.KX:W.KX_END], fb[W.KY:W.KY + nu.shape[0]])
    # fb[W.KF:]: mckf_work_in's work
    v = mckf_fuse_b(dx, P, Rm, H, nu, mp, (mst, dg[DGA.WY:DGA.WY_END]), ad, fb[W.KF:])
    if np.isfinite(v):
        inject_reset_w(x, P, dx, fb[W.V:W.V_END])
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
    R = S3[HM.R]
    quat_to_rot(x[S.QUAT:S.QUAT_END], R)
    r = prm[PR.R_ANT:PR.R_ANT_END]
    for i in range(3):
        # p = z − R r_ant
        x[S.POS + i] = z[i] - (R[i, X] * r[X] + R[i, Y] * r[Y] + R[i, Z] * r[Z])
        for c in range(E.SIZE):
            P[E.POS + i, c] = 0.0
            P[c, E.POS + i] = 0.0
    for i in range(3):
        P[E.POS + i, E.POS + i] = Rm[i, i]


#: the step latch's states (``CT.GLATCH``): none, a candidate step (one fix rejected), a
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
    r0 = dg[DGA.GR]
    c = 0.0
    if 0.5 * r0 <= Rm[0, 0] <= 2.0 * r0:
        h = 0.5 * prm[PR.GATE] * prm[PR.GATE]
        lam = min(max(step_llr(P, H3, Rm, nu3, dg[DGA.GB:DGA.GB_END]), -h), h)
        c = max(0.0, dg[DGA.GC] + lam)
        dg[DGA.GC] = c
        if c < 2.0 * h:
            return True
    ints[CT.GLATCH] = LATCH_NONE
    ints[CT.GREL] += 1
    return False


@njit
def _open_latch(P, H3, Rm, nu3, ints, dg):
    """A fix the gate rejected opens a candidate step: b = its innovation, b's variance = its
    innovation variance per axis."""
    ints[CT.GLATCH] = LATCH_CANDIDATE
    ints[CT.GLAT0] = ints[CT.CORE]
    dg[DGA.GC] = 0.0
    dg[DGA.GR] = Rm[0, 0]
    for i in range(3):
        dg[DGA.GB + i] = nu3[i]
        dg[DGA.GS + i] = innov_var(P, H3, Rm, i)


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
    ints[CT.GREJP] += 1
    dg[DGA.GATE] = 3.0
    for i in range(3):
        nu3[i] = nur[i] - dg[DGA.GB + i]
        Rm[i, i] += dg[DGA.GS + i]


@njit
def _reject_fix(x, P, z, meas, prm, ints, dg, S3, force_reset):
    """A fix the gate rejects: counted; a reset to the receiver when forced (the latch's hold
    limit), once neither a position nor a velocity has been fused for ``PR.GATE_RESET`` ticks
    (no horizontal aiding: the filter has drifted), or once no position has been fused for
    twice that (PX4 EKF2's ``shouldResetGpsFusion``: the aiding timeout, or the position's
    alone for twice ``reset_timeout_max``); else, when the raw fix (``meas``'s ν) fails the
    gate too, the latch's confirmation when the candidate's step fits it, or a candidate
    step: only once the filter has fused fixes for ``PR.GATE_RESET`` ticks since it was set on
    one (its start, a reset), and is as sure as the fix (:func:`_filter_as_sure`)."""
    H3, nu3, Rm = meas
    core = ints[CT.CORE]
    ints[CT.GREJP] += 1
    dg[DGA.GATE] = 1.0
    since = core - ints[CT.GLAST]
    if force_reset or since >= 2.0 * prm[PR.GATE_RESET] or (
            since >= prm[PR.GATE_RESET] and core - ints[CT.GLASTV] >= prm[PR.GATE_RESET]):
        _reset_pos(x, P, z, Rm, prm, S3)
        ints[CT.GRESET] += 1
        ints[CT.GLAST] = core
        ints[CT.GRST] = core
        ints[CT.GLATCH] = LATCH_NONE
        dg[DGA.GATE] = 2.0
    elif prm[PR.GATE_LATCH] > 0.0 and gate_ratio(P, H3, Rm, nu3, prm[PR.GATE]) > 1.0:
        if (ints[CT.GLATCH] == LATCH_CANDIDATE
                and step_llr(P, H3, Rm, nu3, dg[DGA.GB:DGA.GB_END]) < 0.0):
            ints[CT.GLATCH] = LATCH_ON
        elif core - ints[CT.GRST] >= prm[PR.GATE_RESET] and _filter_as_sure(P, H3, Rm):
            _open_latch(P, H3, Rm, nu3, ints, dg)


@njit(inline="always")
def _fuse_pos(x, P, rec, par, ints, dg, fb):
    """The fix's position through the gate (:func:`gate_ratio`; every rule's fix, the PCA'd
    one for rules 2-3) and the step latch (module docstring of :mod:`estimators.ins`), then
    the rule's law.  A rejected fix opens a candidate step; the next fix, rejected too and
    nearer the step than the filter, confirms it; while the confirmed latch holds
    (:func:`_latch_holds`) the fixes are held (:func:`_hold_fix`); held for ``PR.GATE_LATCH``
    ticks, the position resets to the receiver (:func:`_reject_fix`).  The latch works on the
    raw fix for every rule: a false fix is the receiver's step, which the PCA block's window
    spreads over its fixes (a PCA'd fix the gate rejects opens nothing unless the raw fix
    fails the gate too, and a held fix is fused raw, relative to the raw step).  A PCA rule
    fuses the raw fix while its PCA window spans a fix whose raw position the gate rejected
    or the latch held (that fix and the ``PR.PCA_WINDOW`` − 1 after it): a fix the gate keeps out
    does not come in through the window, whose reconstruction rings after an outlier or a
    step's end by centimetres (as the window's restart after it would)."""
    rule, prm, _, _ = par
    H3, nu3, R3 = view2(fb, W.H3, NZ, E.SIZE), fb[W.NU3:W.NU3_END], view2(fb, W.R3, NZ, NZ)
    S3, nur = view3(fb, W.S3, HMAT_SIZE), fb[W.NUR:W.NUR_END]
    zr = rec[RC.Z + GZ.P:RC.Z + GZ.P_END]
    z = rec[RC.ZP:RC.ZP_END] if rule >= 2 else zr
    if not np.isfinite(z[X] + z[Y] + z[Z] + zr[X] + zr[Y] + zr[Z]):
        return
    h_gnss_pos_w(x, prm, zr, nur, H3, S3)   # the raw fix's ν: the latch's
    Rm = _diag_R(rec[RC.VAR + GZ.P:RC.VAR + GZ.P_END], R3)
    if rule >= 2 and gate_ratio(P, H3, Rm, nur, prm[PR.GATE]) > 1.0:
        ints[CT.GRAW] = int(prm[PR.PCA_WINDOW])
    pca = rule >= 2 and ints[CT.GRAW] <= 0
    if ints[CT.GRAW] > 0:
        ints[CT.GRAW] -= 1
    if pca:
        h_gnss_pos_w(x, prm, z, nu3, H3, S3)
    else:
        z = zr
        for i in range(3):
            nu3[i] = nur[i]
    core = ints[CT.CORE]
    held = reject = force = False
    if ints[CT.GLATCH] == LATCH_ON and _latch_holds(P, H3, Rm, nur, prm, ints, dg):
        if core - ints[CT.GLAT0] < prm[PR.GATE_LATCH]:
            held = True
            ints[CT.GRAW] = int(prm[PR.PCA_WINDOW]) - 1
            _hold_fix(nu3, nur, Rm, ints, dg)
            if gate_ratio(P, H3, Rm, nu3, prm[PR.GATE]) > 1.0:
                return
        else:
            reject = force = True
    elif gate_ratio(P, H3, Rm, nu3, prm[PR.GATE]) > 1.0:
        reject = True
    if reject:   # one call site each: an inlined callee is compiled once per site
        _reject_fix(x, P, z, (H3, nur, Rm), prm, ints, dg, S3, force)
        return
    if not held:
        ints[CT.GLATCH] = LATCH_NONE
    v = _fuse_one(x, P, (H3, nu3, Rm), rule == 1 or rule == 3, par, ints[CT.MST:CT.MST_END],
                  dg, fb)
    dg[DGA.NISP] = v
    ints[CT.GLAST] = core
    if held:
        ints[CT.GNREL] += 1
    else:
        dg[DGA.GATE] = 0.0
        ints[CT.NGNSS] += 1


@njit(inline="always")
def _fuse_gnss(x, P, rec, w, par, ints, dg, fb):
    """A GNSS record: position (:func:`_fuse_pos`), then velocity and heading (KF, through the
    same gate), each present when finite; ``w`` the gyro sample of the record's tick, ``par``
    the row's (rule, prm, mpar, ipar), ``fb`` the scratch (:data:`layout.SCRATCH`).  The
    record's NIS (``dg``) are NaN for a part absent or rejected."""
    prm = par[1]
    H3, nu3, R3 = view2(fb, W.H3, NZ, E.SIZE), fb[W.NU3:W.NU3_END], view2(fb, W.R3, NZ, NZ)
    H1, nu1, R1 = view2(fb, W.H1, 1, E.SIZE), fb[W.NU1:W.NU1_END], view2(fb, W.R1, 1, 1)
    S3, wv = view3(fb, W.S3, HMAT_SIZE), fb[W.V:W.V_END]
    for k in range(3):
        dg[DGA.NISP + k] = np.nan
    dg[DGA.GATE] = np.nan
    _fuse_pos(x, P, rec, par, ints, dg, fb)
    gate = prm[PR.GATE]
    zv = rec[RC.Z + GZ.V:RC.Z + GZ.V_END]
    if np.isfinite(zv[X] + zv[Y] + zv[Z]):
        h_gnss_vel_w(x, w, prm, zv, nu3, H3, S3, wv)
        Rv = _diag_R(rec[RC.VAR + GZ.V:RC.VAR + GZ.V_END], R3)
        if gate_ratio(P, H3, Rv, nu3, gate) > 1.0:
            ints[CT.GREJV] += 1
        else:
            dg[DGA.NISV] = _fuse_kf(x, P, H3, nu3, Rv, fb)
            ints[CT.GLASTV] = ints[CT.CORE]
    zy = rec[RC.Z + GZ.YAW:RC.Z + GZ.YAW_END]
    if np.isfinite(zy[0]):
        if h_heading_w(x, prm, zy, nu1, H1, S3):
            Ry = _diag_R(rec[RC.VAR + GZ.YAW:RC.VAR + GZ.YAW_END], R1)
            if gate_ratio(P, H1, Ry, nu1, gate) > 1.0:
                ints[CT.GREJY] += 1
            else:
                dg[DGA.NISY] = _fuse_kf(x, P, H1, nu1, Ry, fb)


@njit(inline="always")
def _fuse_radar(x, P, rec, prm, ints, dg, fb):
    """A radar record (KF; :func:`h_radar_w` says whether the range is usable)."""
    H1, nu1, R1 = view2(fb, W.H1, 1, E.SIZE), fb[W.NU1:W.NU1_END], view2(fb, W.R1, 1, 1)
    S3 = view3(fb, W.S3, HMAT_SIZE)
    if np.isfinite(rec[RC.Z]) and h_radar_w(x, prm, rec[RC.Z:RC.Z + 1], nu1, H1, S3):
        v = _fuse_kf(x, P, H1, nu1, _diag_R(rec[RC.VAR:RC.VAR + 1], R1), fb)
        dg[DGA.NISR] = v
        if np.isfinite(v):
            dg[DGA.RSUM] += v
            dg[DGA.RN] += 1.0
        ints[CT.NRAD] += 1
    else:
        ints[CT.RDROP] += 1


@njit
def _any_due(ints, mq):
    """Whether a queued record's tick ≤ the core tick (the scratch is passed only then)."""
    core = ints[CT.CORE]
    for j in range(ints[CT.QN]):
        if mq[j, RC.T] <= core:
            return True
    return False


@njit(inline="always")
def _fuse_due(x, P, ib, ints, mq, dg, par, fb):
    """Fuse every queued record whose tick ≤ the core tick (in arrival order); compact.
    ``par`` = the row's (rule, prm, mpar, ipar)."""
    prm = par[1]
    core = ints[CT.CORE]
    B = int(prm[PR.RING])
    keep = 0
    for j in range(ints[CT.QN]):
        rec = mq[j]
        t = int(rec[RC.T])
        if t > core:
            if keep != j:
                for k in range(RC.SIZE):
                    mq[keep, k] = rec[k]
            keep += 1
            continue
        if t < core:
            ints[CT.LATE] += 1
        if rec[RC.KIND] == 0.0:
            _fuse_gnss(x, P, rec, ib[core % B, U.W:U.W_END], par, ints, dg, fb)
        else:
            _fuse_radar(x, P, rec, prm, ints, dg, fb)
        ints[CT.DIRTY] = 1
    ints[CT.QN] = keep


@njit
def _enqueue(ints, mq, prm, kind, age_ticks, z, zp, var):
    """Append a record (tick = now − age in delayed mode, now at receipt)."""
    n = ints[CT.QN]
    if n >= mq.shape[0]:
        ints[CT.QDROP] += 1
        return
    rec = mq[n]
    for k in range(RC.SIZE):
        rec[k] = np.nan
    rec[RC.T] = ints[CT.NOW] - (age_ticks if prm[PR.DELAYED] > 0.0 else 0)
    rec[RC.KIND] = kind
    for k in range(z.shape[0]):
        rec[RC.Z + k] = z[k]
        rec[RC.VAR + k] = var[k]
    for k in range(3):
        rec[RC.ZP + k] = zp[k]
    ints[CT.QN] = n + 1


# ------------------------------------------------------------------------ one row, one tick
@njit
def _advance(xc, P, ib, ints, u, prm, M, S3, w):
    """now += 1, store u; the core takes the sample D ticks back once the ring holds it (and
    the one before it, for the coning and sculling corrections: the ring holds D + 2)."""
    B = int(prm[PR.RING])
    D = int(prm[PR.DELAY])
    now = ints[CT.NOW] + 1
    ints[CT.NOW] = now
    for k in range(U.SIZE):
        ib[now % B, k] = u[k]
    if now - D > ints[CT.CORE]:
        uc = ib[(now - D) % B]
        R = S3[PM.R]
        quat_to_rot(xc[S.QUAT:S.QUAT_END], R)   # one R(q) for F and the nominal step
        cov_step(P, xc, uc, prm, R, M, S3, w)
        nominal_step_R(xc, uc, ib[(now - D - 1) % B], prm, R, w)
        ints[CT.CORE] = now - D


@njit
def _refresh_output(xc, xo, ib, ints, prm, predicted, S3, w):
    """xo = the core nominal propagated through the buffered samples core+1 … now (or one
    step on the previous output when nothing was fused since)."""
    B = int(prm[PR.RING])
    now, core = ints[CT.NOW], ints[CT.CORE]
    if ints[CT.DIRTY] or now == core:
        for k in range(S.SIZE):
            xo[k] = xc[k]
        for t in range(core + 1, now + 1):
            nominal_step(xo, ib[t % B], ib[(t - 1) % B], prm, S3, w)
        ints[CT.DIRTY] = 0
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
    M, S3, w = view2(fb, W.M, E.BA, E.SIZE), view3(fb, W.S3P, PMAT_SIZE), fb[W.W:W.W_END]
    zp, nan3 = fb[W.ZP:W.ZP_END], fb[W.NAN:W.NAN_END]
    dt = prm[PR.DT]
    Nw, L, r, mode, any_pca = (popt[PO.WINDOW], popt[PO.EMBED], popt[PO.COMPONENTS],
                               popt[PO.MODE], popt[PO.ANY_PCA])
    for v in range(NV):
        g = gin[v]
        has_g = np.isfinite(g[GI.AGE])
        if has_g and any_pca and np.isfinite(g[GI.P + X] + g[GI.P + Y] + g[GI.P + Z]):
            pca_row(pbuf[v], pcs[v], g[GI.P:GI.P_END], Nw, L, r, mode, zp)
        else:
            for k in range(3):  # a loop: numba's slice assignment compiles slowly
                zp[k] = nan3[k]
        has_r = np.isfinite(rin[v, RI.RANGE])
        for i in range(v * nr, (v + 1) * nr):
            if predict:
                _advance(xc[i], P[i], ib[i], ints[i], imu[v], prm, M, S3, w)
            if has_g:
                age = int(round(g[GI.AGE] / dt))  # p, v, yaw and their variances
                _enqueue(ints[i], mq[i], prm, 0.0, age, g[GI.P:GI.VAR_P], zp, g[GI.VAR_P:GI.SIZE])
            if has_r:
                _enqueue(ints[i], mq[i], prm, 1.0, int(round(rin[v, RI.AGE] / dt)),
                         rin[v, RI.RANGE:RI.RANGE + 1], nan3, rin[v, RI.VAR:RI.VAR + 1])
            if _any_due(ints[i], mq[i]):
                _fuse_due(xc[i], P[i], ib[i], ints[i], mq[i], dg[i],
                          (rules[i], prm, mpar[i], ipar[i]), fb)
            _refresh_output(xc[i], xo[i], ib[i], ints[i], prm, predict, S3, w)

