"""Each estimators layout holds what its kernels index there.

The layouts (:mod:`estimators.ins.layout`, the MCKF's options, state and work buffer in
:mod:`estimators.mckf`, the KF's work in :mod:`estimators.kf`) generate every offset the
kernels read; these tests tie them to what the code allocates and to what the kernels compute:
the sizes sum to the arrays the bank allocates, each named field holds the quantity of its name
after a step (the quaternion stays a unit quaternion, the position moves by v Δt, Q lands on
the error state's δv, δθ, δb_a, δb_g blocks in the order of the parameters), and the work
views of the MCKF update lie at the layout's offsets with its shapes.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators import MCKF
from estimators.ins import RULES, BatchINS, INSConfig, layout, quat_to_rot
from estimators.ins.layout import DGA, GI, GZ, PM, PR, RC, E, S, U, W
from estimators.kf import AXIS_BLOCK, KFWork, kf_work_in, kf_work_layout, kf_work_size
from estimators.mckf import (
    AP,
    FP,
    IP,
    MCKF_I,
    MCKF_ST,
    RECOVERY,
    ST,
    MCKFWork,
    mckf_work_in,
    mckf_work_layout,
    mckf_work_size,
)
from estimators.models import CVB, state_labels
from estimators.route import SG, singer_model


@pytest.fixture(scope="module")
def bank():
    cfg = INSConfig(lever_arm=(0.1, -0.2, 0.3), radar_offset=(0.0, 0.05, -0.1), eps=1e-5,
                    max_iter=7, lockout_n=4, recovery="inflate", adapt_lambda=0.9)
    return BatchINS(2, cfg, RULES)


def test_the_bank_allocates_what_its_layouts_declare(bank):
    N = bank.N
    assert bank.x_core.shape == bank.x_out.shape == (N, layout.STATE.size) == (N, 16)
    assert bank.P.shape == (N, layout.ERR.size, layout.ERR.size) == (N, 15, 15)
    assert bank._ints.shape == (N, layout.INTS.size)
    assert bank._dg.shape == (N, layout.DG.size)
    assert bank._mq.shape[2] == layout.REC.size
    assert bank._mpar.shape == (N, layout.MPAR.size)
    assert bank._ipar.shape == (N, MCKF_I.size)
    assert bank.prm.shape == (layout.PRM.size,)
    assert bank._popt.shape == (layout.POPT.size,)
    assert bank._fb.shape == (layout.SCRATCH.size,)
    assert bank._ib.shape[2] == layout.IMU.size == 6
    assert BatchINS.gnss_row().shape == (layout.GIN.size,)
    # the record's measurement and variances are the GNSS row's p, v, yaw and their variances
    assert RC.Z_END - RC.Z == GZ.SIZE == GI.VAR_P - GI.P == GI.VAR_YAW_END - GI.VAR_P
    assert (GZ.P, GZ.V, GZ.YAW) == (GI.P - GI.P, GI.V - GI.P, GI.YAW - GI.P)
    # the MCKF row state and the position fix's diagnostics
    assert layout.INTS.width["mst"] == MCKF_ST.size
    assert DGA.WY_END - DGA.WY == W.NU3_END - W.NU3 == layout.NZ == 3
    # the MCKF work at the scratch's tail, for 15 states and a 3-row fix
    assert layout.SCRATCH.size - W.KF == mckf_work_size(layout.ERR.size, layout.NZ)
    # F P: the δp, δv, δθ rows; the prediction's matrices
    assert layout.SCRATCH.shape["M"] == (E.BA, E.SIZE) and layout.SCRATCH.shape["S3P"][0] == PM.SIZE


def test_the_parameters_sit_where_the_config_writes_them(bank):
    cfg, prm = bank.cfg, bank.prm
    assert prm[PR.DT] == cfg.dt and prm[PR.G] == cfg.gravity
    assert np.array_equal(prm[PR.R_ANT:PR.R_ANT_END], cfg.lever_arm)
    assert np.array_equal(prm[PR.R_RAD:PR.R_RAD_END], cfg.radar_offset)
    assert prm[PR.DELAY] == cfg.delay_ticks() and prm[PR.RING] == cfg.delay_ticks() + 2
    assert prm[PR.QV] == pytest.approx((cfg.accel_sigma * cfg.dt) ** 2, rel=1e-15)
    mpar, ipar = bank._mpar[0], bank._ipar[0]
    f, a = mpar[layout.MP.F:layout.MP.F_END], mpar[layout.MP.A:layout.MP.A_END]
    assert f[FP.EPS2] == cfg.eps**2 and f[FP.REJECT] == cfg.reject_weight
    assert f[FP.INFLATE] == cfg.inflate and a[AP.LAM] == cfg.adapt_lambda
    assert a[AP.ADAPTIVE] == 0.0 and a[AP.CLIP] == cfg.adapt_clip
    assert ipar[IP.MAX_ITER] == 7 and ipar[IP.LOCKOUT] == 4
    assert ipar[IP.RECOVERY] == RECOVERY["inflate"]
    assert np.array_equal(mpar[layout.MP.SIG:layout.MP.SIG_END], cfg.kernel_widths())


def test_a_step_keeps_each_field_what_its_name_says():
    """One vehicle hovering level at 1 m/s east: after the steps the QUAT block holds a unit
    quaternion (the reset's non-unit one normalised), the position moved by v t, the biases are
    the reset's, and one step from P = 0 puts Q's impulses on δv, δθ, δb_a, δb_g in that order."""
    cfg = INSConfig(delayed=False)
    b = BatchINS(1, cfg, ("kf",))
    q0 = np.array([2.0, 0.0, 0.0, 0.2])
    ba, bg = np.array([0.01, -0.02, 0.03]), np.array([1e-4, 2e-4, -3e-4])
    b.reset([1.0, 2.0, 3.0], [1.0, 0.0, 0.0], q0, ba, bg, P0=np.zeros(15))
    u = np.zeros((1, layout.IMU.size))
    x = b.x_core[0]
    R = np.empty((3, 3))
    quat_to_rot(x[S.QUAT:S.QUAT_END], R)
    u[0, U.F:U.F_END] = R.T @ np.array([0.0, 0.0, cfg.gravity]) + ba   # level: f = Rᵀ g e_z
    u[0, U.W:U.W_END] = bg
    b.step(u)
    P = b.P[0]
    for fld, q in (("vel", PR.QV), ("theta", PR.QT), ("ba", PR.QBA), ("bg", PR.QBG)):
        sl = layout.ERR.slice(fld)
        assert np.allclose(np.diag(P)[sl], b.prm[q], rtol=0, atol=1e-20), fld
    assert np.all(np.diag(P)[layout.ERR.slice("pos")] < 1e-12)
    for _ in range(99):
        b.step(u)
    x = b.x_out[0]
    t = 100 * cfg.dt
    assert np.linalg.norm(x[S.QUAT:S.QUAT_END]) == pytest.approx(1.0, abs=1e-14)
    assert np.allclose(x[S.QUAT:S.QUAT_END], q0 / np.linalg.norm(q0), atol=1e-9)
    assert np.allclose(x[S.POS:S.POS_END], [1.0 + t, 2.0, 3.0], atol=1e-6)
    assert np.allclose(x[S.VEL:S.VEL_END], [1.0, 0.0, 0.0], atol=1e-6)
    assert np.array_equal(x[S.BA:S.BA_END], ba) and np.array_equal(x[S.BG:S.BG_END], bg)


def test_a_gnss_fix_lands_in_the_named_fields():
    """A fix fed through :meth:`BatchINS.gnss_row` is fused: the velocity's and the heading's
    NIS are finite (their parts of the record), and the position moves towards the fix."""
    b = BatchINS(1, INSConfig(delayed=False), ("kf",))
    b.reset([0.0, 0.0, 10.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], P0=np.full(15, 0.1))
    g = BatchINS.gnss_row(pos=[0.3, 0.0, 10.0], vel=[0.0, 0.0, 0.0], yaw=0.0)[None, :]
    b.step(None, g, None)
    assert np.isfinite(b._dg[0, DGA.NISP]) and np.isfinite(b._dg[0, DGA.NISV])
    assert np.isfinite(b._dg[0, DGA.NISY])
    assert b.counters["gnss_fused"][0] == 1
    assert 0.0 < b.x_out[0, S.POS] < 0.3


@pytest.mark.parametrize("n, m", [(15, 3), (4, 2), (6, 1)])
def test_the_mckf_work_views_lie_at_the_layouts_offsets(n, m):
    L = mckf_work_layout(n, m)
    assert L.size == mckf_work_size(n, m)
    assert tuple(L.offset) == MCKFWork._fields
    assert kf_work_layout(n, m).size == kf_work_size(n, m)
    assert tuple(kf_work_layout(n, m).offset) == KFWork._fields == MCKFWork._fields[:9]
    buf = np.zeros(L.size)
    w = mckf_work_in(buf, n, m)
    base = buf.__array_interface__["data"][0]
    for name, view in zip(MCKFWork._fields, w, strict=True):
        assert np.shares_memory(view, buf), name
        assert (view.__array_interface__["data"][0] - base) // 8 == L.offset[name], name
        assert view.shape == L.shape[name] or (view.shape == (1,) and L.shape[name] == (1,)), name
    kw = kf_work_in(buf, n, m)
    for name in KFWork._fields:
        assert getattr(kw, name).__array_interface__["data"][0] == \
            getattr(w, name).__array_interface__["data"][0], name


def test_the_mckf_options_and_state_by_name():
    F, H = np.eye(2), np.eye(2)
    f = MCKF(F, H, 0.1 * np.eye(2), np.eye(2), eps=1e-4, max_iter=3, lockout_n=5,
             reject_weight=0.1, recovery="inflate", inflate=8.0)
    fpar, ipar = f.params()
    assert fpar[FP.FLOOR] == f.kernel_floor and fpar[FP.EPS2] == 1e-8
    assert fpar[FP.REJECT] == 0.1 and fpar[FP.INFLATE] == 8.0 and fpar[FP.GATE] == f.inflate_gate
    assert ipar[IP.MAX_ITER] == 3 and ipar[IP.LOCKOUT] == 5
    assert ipar[IP.RECOVERY] == RECOVERY["inflate"] and ipar[IP.JMAX] >= 1
    for z in ([0.1, 0.0], [50.0, 50.0]):
        f.predict()
        f.update(np.array(z))
    assert f.n_iter == f._ist[ST.N_ITER] >= 1
    assert f.rejected == bool(f._ist[ST.REJECTED]) and f.n_rejected == f._ist[ST.N_REJECTED]


def test_the_axis_blocks_name_the_models_states():
    B = AXIS_BLOCK.at
    ca, cvb = state_labels("ca", 1), state_labels("cvb", 1)
    assert (ca[B.P], ca[B.V], ca[B.D]) == ("px", "vx", "ax") and len(ca) == B.SIZE
    assert (cvb[CVB.P], cvb[CVB.V], cvb[CVB.B]) == ("px", "vx", "bx") and len(cvb) == CVB.SIZE
    F, Q = singer_model(0.1, 0.5, 1.0, dim=1)
    assert F[SG.P, SG.V] == pytest.approx(0.1)                  # ṗ = v
    assert F[SG.A, SG.A] == pytest.approx(np.exp(-0.05))        # ȧ = −λ a
    assert F[SG.A, SG.P] == 0.0 and Q[SG.A, SG.A] > Q[SG.P, SG.P] > 0.0
