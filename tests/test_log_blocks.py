"""The run log's block encoding (ag_uav.record.encode) against one-message-at-a-time references:
the poses and transforms of ``enc_pose_in_frame`` / ``enc_transform``, the state message of
``FlatSchema.encode`` with the derived values computed here by hand; and what a signal arriving
mid-tick leaves in the file."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ag_uav.record import wire as R
from ag_uav.record.encode import EST, POSE, REF, STATE, TF, TickFormat, encode_flat, encode_ticks
from ag_uav.record.runlog import RunLog
from numkit.geometry import quat_to_euler


def _rows(rng, n, nm, extra):
    r = rng.normal(size=(n, R.TICK_HEAD + nm + extra)) * 10
    # times across the varint sizes: 0, sub-second, seconds, a long mission; sec or nsec zero
    r[:, 0] = np.resize([0.0, 0.05, 1.0, 3.25, 127.5, 128.0, 20000.123456789], n)
    q = rng.normal(size=(n, 4))
    r[:, R.TICK_Q:R.TICK_V] = q / np.linalg.norm(q, axis=1, keepdims=True)
    r[:, 1] = rng.integers(0, 16, size=n)
    return r


def _state_ref(row, nm, ctrl_cols):
    """DroneState's values of one row, written out as the per-call encoder used to."""
    t, px, py, pz = row[0], *row[R.TICK_P:R.TICK_Q]
    w, x, y, z = row[R.TICK_Q:R.TICK_V]
    vx, vy, vz = row[R.TICK_V:R.TICK_PREF]
    rx, ry, rz = row[R.TICK_PREF:R.TICK_VREF]
    roll, pitch, yaw = (math.degrees(a) for a in quat_to_euler(w, x, y, z))
    has = int(row[1]) & 8
    est = list(row[R.TICK_PEST:R.TICK_WIND]) if has else [math.nan] * 6
    ex, ey, ez = px - rx, py - ry, pz - rz
    eh = math.sqrt(ex * ex + ey * ey)
    dx, dy, dz = est[0] - px, est[1] - py, est[2] - pz
    return ([t, px, py, pz, vx, vy, vz, roll, pitch, yaw, rx, ry, rz,
             *row[R.TICK_VREF:R.TICK_PEST]] + est
            + [ex, ey, ez, eh, math.sqrt(eh * eh + ez * ez), dx, dy, dz,
               math.sqrt(dx * dx + dy * dy), math.sqrt(vx * vx + vy * vy + vz * vz),
               row[R.TICK_SPRAY], *row[R.TICK_WIND:R.TICK_SPRAY]]
            + list(row[R.TICK_HEAD:R.TICK_HEAD + nm]) + [row[c] for c in ctrl_cols])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_block_messages_equal_the_one_at_a_time_encoders(seed):
    rng = np.random.default_rng(seed)
    nm, extra = 4, 7
    rows = _rows(rng, 40, nm, extra)
    ctrl_cols = np.array([R.TICK_HEAD + nm + j for j in (3, 0, 6, 1)], dtype=np.intp)
    schema = R.FlatSchema("t.S", [(f, 0) for f in [f"v{j}" for j in range(37)]]
                          + [("motors", nm)] + [(f"c{j}", 0) for j in range(len(ctrl_cols))])
    st = R.template(schema.prefixes)
    mid = R.WORLD2 + R.str_field(3, "base_link")
    out = np.zeros(200_000, np.uint8)
    starts, kinds, tns = (np.zeros(400, np.int64) for _ in range(3))
    fmt = TickFormat(nm, ctrl_cols, st[0], st[1], R.POSE_TMPL, R.POSE_SLOTS, R.TF_TMPL,
                     np.frombuffer(mid, np.uint8).copy(),
                     np.frombuffer(R.POSE_MID, np.uint8).copy())
    m = encode_ticks(rows, fmt, out, starts, kinds, tns)
    want = []
    for row in rows:
        tn, mask = R.ns(float(row[0])), int(row[1])
        ts = R.ts_pb(tn)
        p, q = row[R.TICK_P:R.TICK_Q], row[R.TICK_Q:R.TICK_V]
        if mask & 1:
            want.append((TF, tn, R.enc_transform(ts, R.str_field(3, "base_link"), p, q)))
        if mask & 2:
            h = 0.5 * row[R.TICK_YAW]
            want.append((POSE, tn, R.enc_pose_in_frame(ts, p, q)))
            want.append((REF, tn, R.enc_pose_in_frame(
                ts, row[R.TICK_PREF:R.TICK_VREF], (math.cos(h), 0.0, 0.0, math.sin(h)))))
            if mask & 8:
                want.append((EST, tn, R.enc_pose_in_frame(ts, row[R.TICK_PEST:R.TICK_VEST], q)))
        if mask & 4:
            want.append((STATE, tn, schema.encode(_state_ref(row, nm, ctrl_cols))))
    assert m == len(want)
    got = [(int(kinds[j]), int(tns[j]), out[starts[j]:starts[j + 1]].tobytes()) for j in range(m)]
    for g, w in zip(got, want, strict=True):
        assert g[:2] == w[:2]
        if g[0] == STATE:  # derived values may differ in the last bit (libm vs numba)
            a = np.frombuffer(g[2], np.uint8)
            b = np.frombuffer(w[2], np.uint8)
            assert len(a) == len(b)
            va = np.array([np.frombuffer(g[2][s:s + 8], "<f8")[0] for s in st[1]])
            vb = np.array([np.frombuffer(w[2][s:s + 8], "<f8")[0] for s in st[1]])
            np.testing.assert_allclose(va, vb, rtol=1e-13, atol=1e-12, equal_nan=True)
            keep = np.ones(len(a), bool)
            for s in st[1]:
                keep[s:s + 8] = False
            assert np.array_equal(a[keep], b[keep])  # tags and headers
        else:
            assert g[2] == w[2]


def test_flat_rows_equal_flatschema_encode():
    rng = np.random.default_rng(5)
    schema = R.FlatSchema("t.E", [("t", 0), ("x", 16), ("p_diag", 16), ("pos.x", 0)])
    rows = rng.normal(size=(9, schema.n_values))
    tmpl, slots = R.template(schema.prefixes)
    out = np.zeros(len(tmpl) * 9, np.uint8)
    starts = np.zeros(10, np.int64)
    encode_flat(rows, tmpl, slots, out, starts)
    for j, row in enumerate(rows):
        assert out[starts[j]:starts[j + 1]].tobytes() == schema.encode(row.tolist())


def test_signal_mid_tick_drops_only_the_row_being_filled(tmp_path):
    """A tick row handed out but not filled when SIGTERM closes the log is not written; every
    row before it is."""
    from mcap.reader import make_reader

    log = RunLog(tmp_path / "a.mcap", metadata={}, config_toml="", layout=False)
    log.bind_ticks(4, ["x.u"], [0], 1)
    for k in range(10):
        row = log.tick_slot(k * 0.05)
        row[:] = k
    log.tick_slot(0.5)  # handed out, never filled: the signal came
    log.close(partial=True)
    with open(tmp_path / "a.mcap", "rb") as f:
        times = [m.log_time for _, c, m in make_reader(f).iter_messages()
                 if c.topic == "/drone/state"]
    assert times == [k * 50_000_000 for k in range(10)]


def test_grid_encoding_decodes_as_the_sdk_message():
    """``enc_grid`` against the SDK's own foxglove.Grid encoding, field by field."""
    import foxglove
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    M = foxglove.messages
    vals = np.arange(12, dtype=np.float64).reshape(3, 4) * 1.5
    tn = R.ns(12.345)
    ours = R.enc_grid(R.ts_pb(tn), -3.5, 7.25, 0.02, 0.8, vals)
    sdk = M.Grid(timestamp=M.Timestamp(sec=tn // 10**9, nsec=tn % 10**9), frame_id="world",
                 pose=M.Pose(position=M.Vector3(x=-3.5, y=7.25, z=0.02),
                             orientation=M.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
                 column_count=4, cell_size=M.Vector2(x=0.8, y=0.8), row_stride=16, cell_stride=4,
                 fields=[M.PackedElementField(name="l_per_ha", offset=0,
                                              type=M.PackedElementFieldNumericType.Float32)],
                 data=vals.astype("<f4").tobytes()).encode()
    fds = descriptor_pb2.FileDescriptorSet.FromString(M.Grid.get_schema().data)
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName("foxglove.Grid"))
    a, b = cls.FromString(ours), cls.FromString(sdk)
    assert a == b and a.column_count == 4 and len(a.data) == 48


def test_gps_block_equals_the_one_message_encoder():
    """``/gps`` fixes are kept as rows and encoded at the flush (``encode_poses``): each
    message is the PoseInFrame of :func:`enc_pose_in_frame` at the fix, identity rotation."""
    from ag_uav.record.encode import encode_poses

    rows = np.array([[0.0, 1.5, -2.25, 3.0], [0.05, 1e3, 2e-3, -7.0],
                     [128.0, -0.0, 5.0, 1.0], [20000.123456789, 4.0, 5.0, 6.0]])
    mid = np.frombuffer(R.POSE_MID, np.uint8).copy()
    out = np.zeros(4096, np.uint8)
    starts, tns = np.zeros(5, np.int64), np.zeros(4, np.int64)
    end = encode_poses(rows, R.POSE_TMPL, R.POSE_SLOTS, mid, out, starts, tns)
    assert starts[4] == end
    for j, (t, x, y, z) in enumerate(rows):
        tn = R.ns(t)
        assert tns[j] == tn
        ref = R.enc_pose_in_frame(R.ts_pb(tn), (x, y, z), (1.0, 0.0, 0.0, 0.0))
        assert out[starts[j]:starts[j + 1]].tobytes() == ref


def test_estimator_bank_writes_what_one_call_per_filter_writes(tmp_path):
    """``estimator_bank`` (the INS bank's way: one block per fix) and ``estimator`` called per
    filter give the same ``/estimator/<name>`` messages, byte for byte."""
    from mcap.reader import make_reader

    rng = np.random.default_rng(3)
    names = ["kf", "mckf", "pca-kf"]
    fixes = [(0.1 * k, rng.normal(size=(3, 16)), rng.random((3, 15)), rng.normal(size=3))
             for k in range(1, 30)]
    msgs = {}
    for way in ("bank", "calls"):
        with RunLog(tmp_path / f"{way}.mcap", channels=["estimator"], layout=False) as log:
            for t, x, pd, truth in fixes:
                if way == "bank":
                    log.estimator_bank(t, names, x, pd, truth)
                else:
                    log.set_truth(truth)
                    for j, nm in enumerate(names):
                        log.estimator(t, nm, x[j], pd[j], None)
            counts = log.counts
        with open(tmp_path / f"{way}.mcap", "rb") as f:
            msgs[way] = [(c.topic, m.log_time, m.data) for _, c, m in
                         make_reader(f).iter_messages(log_time_order=False)]
        assert counts == {f"/estimator/{R.sanitize_name(nm)}": len(fixes) for nm in names}
    assert len(msgs["bank"]) == 3 * len(fixes)
    assert sorted(msgs["bank"]) == sorted(msgs["calls"])
