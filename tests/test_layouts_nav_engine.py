"""The navigation's and the engine's packed rows are what their Layouts say: widths match the
arrays allocated, and the kernels write each field where the layout names it."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from ag_uav.engine import kernels as K
from ag_uav.engine import spray_batched as SB
from ag_uav.engine.physics import XFRC
from ag_uav.engine.reftable import COLUMNS, REF
from ag_uav.engine.stages import IMU_KEYS, REC_COLUMNS
from ag_uav.navigation import estimation
from ag_uav.navigation import ins_kernels as IK
from ag_uav.navigation.ins_feedback import ANTENNA, RADAR, BatchInsFeedback, InsFeedback
from ag_uav.record.runlog import RunLog
from ag_uav.seeds import seed_sequences
from estimators.ins import INS, BatchINS
from estimators.ins.layout import DG, ERR, GIN, IMU, RIN, STATE


def _columns(layout, names: dict[str, tuple[str, ...]]) -> list[str]:
    """A layout's columns, each field expanded to its components' names."""
    return [c for f in layout.offset for c in names.get(f, (f,))]


def test_the_nominal_state_is_the_filters():
    """The kernels' nominal state (the bank's STATE) is the order the INS resets and reads its
    state in."""
    ins = INS()
    p, v, ba, bg = (1.0, 2.0, 3.0), (4.0, 5.0, 6.0), (0.1, 0.2, 0.3), (0.4, 0.5, 0.6)
    q = np.array([math.cos(0.3), 0.0, 0.0, math.sin(0.3)])
    ins.reset(p, v, q, ba=ba, bg=bg)
    x = ins.x
    assert x.shape == (STATE.size,)
    for name, want in {"pos": p, "vel": v, "quat": q, "ba": ba, "bg": bg}.items():
        assert np.array_equal(x[STATE.slice(name)], want), name
    assert np.array_equal(ins.q, x[IK.XN.QUAT:IK.XN.QUAT_END])


def test_the_error_state_blocks_are_the_nees_blocks():
    """The 15-state error in the order of P, its 3-state blocks at 3·b (quad_inv_at) in the
    order of the score record's block columns."""
    E = ERR
    assert E.size == 15 == INS().P.shape[0]
    assert [E.offset[f] for f in ("pos", "vel", "theta", "ba", "bg")] == [3 * b for b in range(5)]
    assert IK.XE == ERR.at and IK.XN == STATE.at
    R = IK.NEES_REC.offset
    assert [R[b] - R["pos"] for b in IK.BLOCKS] == list(range(5))
    assert IK.NREC == IK.NEES_REC.size


def test_the_bank_rows_are_the_estimators():
    """The GNSS, radar and IMU input rows and the NIS head are the bank's own layouts."""
    assert IK.GN.SIZE == GIN.size and IK.RN.SIZE == RIN.size
    for name, o in GIN.offset.items():
        assert getattr(IK.GN, name.upper()) == o
    assert (IK.RN.RANGE, IK.RN.VAR, IK.RN.AGE) == tuple(RIN.offset.values())
    bank = BatchINS(1)
    assert bank.nis.shape[1] == 4 and list(DG.offset)[:4] == ["nisp", "nisv", "nisy", "nisr"]
    assert (IK.DN.NISP, IK.DN.NISV, IK.DN.NISY) == (0, 1, 2)
    assert IK.IM == IMU.at and IMU.size == 6


@pytest.fixture(scope="module")
def ins_feedback():
    from ag_uav.config import config_from_dict

    cfg = config_from_dict({"sim": {"max_time_s": 2.0}, "log": {"enabled": False}})
    return InsFeedback(cfg, seed_sequences(cfg.seed))


def test_a_gnss_row_round_trips_through_its_names(ins_feedback):
    """The receiver's row (InsFeedback.fix) read by GIN's names and rebuilt by the bank's own
    builder is the same row, bit for bit."""
    fb = ins_feedback
    p_ant, v_ant, yaw = [10.0, -5.0, 3.0], [1.0, 0.5, -0.2], 0.7
    row = None
    for k in range(200):
        row = fb.fix(k * fb.dt, p_ant, v_ant, yaw)
        if row is not None:
            break
    assert row is not None and len(row) == GIN.size
    G = IK.GN
    back = BatchINS.gnss_row(pos=row[G.P:G.P_END], vel=row[G.V:G.V_END], yaw=row[G.YAW],
                             var_pos=row[G.VAR_P:G.VAR_P_END],
                             var_vel=row[G.VAR_V:G.VAR_V_END], var_yaw=row[G.VAR_YAW],
                             age_s=row[G.AGE])
    assert np.array_equal(np.array(row), back)
    assert row[G.AGE] == fb.age_s and row[G.VAR_YAW] == fb.var_yaw
    assert row[G.VAR_V:G.VAR_V_END] == [fb.var_v] * 3
    assert np.allclose(row[G.P:G.P_END], p_ant, atol=5.0)
    assert np.allclose(row[G.V:G.V_END], v_ant, atol=1.0)
    assert abs(row[G.YAW] - yaw) < 0.2


def test_the_ring_holds_its_fields_where_the_layout_names_them(ins_feedback):
    """ring_write's row: each RING field by name, in a ring as wide as the layout."""
    bank = BatchInsFeedback([ins_feedback], 16)
    ring, prm = bank.ring, bank.prm
    assert ring.shape[2] == IK.RING.size == IK.RING_WIDTH
    assert prm.shape == (IK.SENSOR_PRM.size,)
    S = IK.SENSOR_PRM
    assert tuple(prm[S.slice("r_ant")]) == ANTENNA and tuple(prm[S.slice("r_rad")]) == RADAR
    c, s = math.cos(0.4), math.sin(0.4)
    R = np.array([[c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0]])
    p, v, w = np.array([[1.0, 2.0, 10.0]]), np.array([[0.3, -0.2, 0.1]]), np.zeros((1, 3))
    bt = np.arange(bank.blk * 6, dtype=float).reshape(1, bank.blk, 6)
    bank.btru[:] = bt
    act = np.ones(1, dtype=bool)
    IK.tick_in((p, v, R, w, act, np.zeros((1, 3)), np.zeros((1, 3))), bank.rows, 0, 0.0, 2)
    r, L = ring[0, 0], IK.RING
    assert np.array_equal(r[L.slice("p")], p[0]) and np.array_equal(r[L.slice("v")], v[0])
    assert np.array_equal(r[L.slice("R")], R[0])
    assert np.array_equal(r[L.slice("ba")], bt[0, 2, :3])
    assert np.array_equal(r[L.slice("bg")], bt[0, 2, 3:])
    assert np.allclose(r[L.slice("ant_p")], p[0] + R[0].reshape(3, 3) @ np.array(ANTENNA))
    assert np.allclose(r[L.slice("ant_v")], v[0])
    assert r[L.offset["range"]] == pytest.approx(p[0, 2] + RADAR[2])
    assert np.isfinite(r[L.offset["yaw"]])


def test_the_engine_record_rows_are_their_columns():
    xyz = ("x", "y", "z")
    rec = _columns(K.RECORD, {"p": tuple("p" + a for a in xyz), "v": tuple("v" + a for a in xyz),
                              "rp": tuple("r" + a for a in xyz),
                              "p_fb": tuple("f" + a for a in xyz),
                              "f": tuple(f"f{j}" for j in range(4)),
                              "wind": tuple("w" + a for a in xyz)})
    assert rec == list(REC_COLUMNS)
    ref = _columns(REF, {"p": tuple("p" + a for a in xyz), "v": tuple("v" + a for a in xyz),
                         "a": tuple("a" + a for a in xyz)})
    assert ref == list(COLUMNS)
    assert K.IMU_REC.size == len(IMU_KEYS)
    assert list(SB.LOG_ROW.offset) == list(RunLog.SPRAY_FIELDS)


def test_tick_out_writes_the_record_by_name():
    """tick_out's row: each RECORD field by name; rotors past the fourth after the wind."""
    n, rot = 1, 6
    p, v, rp, pfb, w = (np.full((n, 3), float(j)) + np.arange(3) for j in range(1, 6))
    f = np.arange(rot, dtype=float).reshape(n, rot) + 100.0
    ref_tab = np.zeros((1, 4, REF.size))
    ref_tab[0, 2, K.RF.SEG] = 7.0
    rec = np.zeros((4, n, K.RECORD.size + rot - K.NF))
    flown = np.zeros(n, dtype=np.int64)
    K.tick_out(rec, 2, np.ones(n, dtype=bool), flown,
               (p, v, rp, pfb, w, f, np.ones(n, dtype=bool), ref_tab, np.zeros(1, np.int64),
                np.zeros(n, np.int64)))
    r, L = rec[2, 0], K.RECORD
    for name, want in {"p": p, "v": v, "rp": rp, "p_fb": pfb, "wind": w}.items():
        assert np.array_equal(r[L.slice(name)], want[0]), name
    assert r[L.offset["seg"]] == 7.0 and r[L.offset["spray"]] == 1.0
    assert np.array_equal(r[L.slice("f")], f[0, :K.NF])
    assert np.array_equal(r[L.size:], f[0, K.NF:]) and flown[0] == 3


def test_the_free_joint_and_the_applied_force_are_mujocos():
    m = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='0.1'/></body></worldbody></mujoco>")
    assert (m.nq, m.nv) == (K.FREE_QPOS.size, K.FREE_QVEL.size)
    d = mujoco.MjData(m)
    d.qpos[K.FREE_QPOS.slice("pos")] = (1.0, 2.0, 3.0)
    d.qpos[K.FREE_QPOS.slice("quat")] = (math.cos(0.2), 0.0, 0.0, math.sin(0.2))
    d.qvel[K.FREE_QVEL.slice("vel")] = (0.5, 0.0, 0.0)
    mujoco.mj_forward(m, d)
    assert np.allclose(d.xpos[1], (1.0, 2.0, 3.0))
    assert np.allclose(d.xquat[1], (math.cos(0.2), 0.0, 0.0, math.sin(0.2)))
    assert d.xfrc_applied.shape[1] == XFRC.size


def test_the_closed_sortie_mirrors_the_current_one():
    """The sprayer's closed-sortie totals (c_*) lie in the current totals' order, contiguous
    (the batch clears them as one slice)."""
    s = SB.STATE.offset
    totals = ("lit", "ej", "minsoc", "randry", "tland")
    assert [s["c_" + t] for t in totals] == list(range(s["c_lit"], s["c_lit"] + 5))
    assert [s[t] for t in totals] == list(range(s["lit"], s["lit"] + 5))
    assert estimation.CONS.shape["P"] == (3, 3) and estimation.CONS.offset["P"] == 2
