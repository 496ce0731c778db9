"""Run log writer: schemas, hand-encoded messages, rates, metadata, crash safety."""

from __future__ import annotations

import math
import mmap
import os
import signal
import struct
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, message_factory
from mcap.reader import NonSeekingReader, make_reader

from ag_uav.record.runlog import FlatSchema, LogIO, RunLog, Tick
from ag_uav.record.synthetic import synthetic_run
from ag_uav.record.wire import enc_pose_in_frame, enc_transform, str_field, ts_pb
from numkit.geometry import quat_to_euler

ROOT = Path(__file__).resolve().parents[1]


def _cls(schema_data: bytes, name: str):
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema_data)
    return message_factory.GetMessages(list(fds.file))[name]


def test_flat_schema_roundtrip_nested_and_vectors():
    fields = [("t", 0), ("a.x", 0), ("a.y", 0), ("v", 3), ("b.c.d", 0), ("b.e", 0),
              ("w", 2), ("z", 0)]
    fs = FlatSchema("ag_uav.Test", fields)
    vals = [1.5, -2.0, 3.25, 10.0, 20.0, 30.0, 7.0, 8.0, 0.0, -0.5, 9.0]
    raw = fs.encode(vals)
    assert len(raw) == fs.size
    msg = _cls(fs.schema_data, "ag_uav.Test").FromString(raw)
    assert msg.t == 1.5 and msg.a.x == -2.0 and msg.a.y == 3.25
    assert list(msg.v) == [10.0, 20.0, 30.0]
    assert msg.b.c.d == 7.0 and msg.b.e == 8.0
    assert list(msg.w) == [0.0, -0.5] and msg.z == 9.0
    nan = fs.encode([math.nan] * fs.n_values)
    assert math.isnan(_cls(fs.schema_data, "ag_uav.Test").FromString(nan).a.x)


def test_flat_schema_many_fields_two_byte_tags():
    fields = [(f"g.f{i}", 0) for i in range(40)]
    fs = FlatSchema("ag_uav.Big", fields)
    vals = [float(i) * 1.25 for i in range(40)]
    msg = _cls(fs.schema_data, "ag_uav.Big").FromString(fs.encode(vals))
    assert [getattr(msg.g, f"f{i}") for i in range(40)] == vals


def test_flat_schema_rejects_split_group():
    with pytest.raises(ValueError):
        FlatSchema("ag_uav.Bad", [("a.x", 0), ("b", 0), ("a.y", 0)])


def test_hand_encoded_foxglove_messages_decode_with_official_schema():
    from foxglove.messages import FrameTransforms, PoseInFrame

    tn = 12_345_678_901
    ts = ts_pb(tn)
    p, q = (1.5, -2.25, 3.0), (0.9, 0.1, -0.2, 0.3)
    pif = _cls(PoseInFrame.get_schema().data, "foxglove.PoseInFrame").FromString(
        enc_pose_in_frame(ts, p, q))
    assert (pif.timestamp.seconds, pif.timestamp.nanos) == (12, 345_678_901)
    assert pif.frame_id == "world"
    assert (pif.pose.position.x, pif.pose.position.y, pif.pose.position.z) == p
    o = pif.pose.orientation
    assert (o.w, o.x, o.y, o.z) == q
    raw = enc_transform(ts, str_field(3, "base_link"), p, q) + enc_transform(
        ts_pb(0), str_field(3, "cam_chase"), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0))
    ft = _cls(FrameTransforms.get_schema().data, "foxglove.FrameTransforms").FromString(raw)
    assert [t.child_frame_id for t in ft.transforms] == ["base_link", "cam_chase"]
    assert all(t.parent_frame_id == "world" for t in ft.transforms)
    assert ft.transforms[0].translation.y == -2.25 and ft.transforms[0].rotation.w == 0.9
    assert ft.transforms[1].translation.z == 1.0


def _tick_values(p, ctrl=None):
    return Tick(p_true=np.asarray(p, float), q_true_wxyz=(1.0, 0.0, 0.0, 0.0),
                v_true=(1.0, 0.0, 0.0), p_ref=(0.0, 0.0, 2.0), v_ref=(1.0, 0.0, 0.0),
                yaw_ref=0.0, p_est=(p[0] + 0.3, p[1] - 0.4, p[2]), v_est=(1.0, 0.0, 0.0),
                ctrl=ctrl if ctrl is not None else {"x.u": 0.1, "y.u": -0.2, "thrust": 0.5},
                motors=[0.4, 0.5, 0.6, 0.7], wind=(2.0, 0.0, 0.0), spray=True)


def _decoded(path):
    from mcap_protobuf.decoder import DecoderFactory

    with open(path, "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(c.topic, m.log_time, d) for _, c, m, d in r.iter_decoded_messages()]


def test_state_values_rates_and_errors(tmp_path):
    path = tmp_path / "r" / "run.mcap"
    with RunLog(path, channels="full", metadata={"seed": 7}, config_toml="a = 1\n") as log:
        for k in range(100):  # 1 s at 100 Hz
            log.tick(k * 0.01, _tick_values((k * 0.01, 1.0, 2.5)))
        log.tick(1.0, _tick_values((1.0, 1.0, 2.5), ctrl={"x.u": 0.7}))  # key missing: NaN
    msgs = _decoded(path)
    st = [(t, d) for topic, t, d in msgs if topic == "/drone/state"]
    assert len(st) == 21  # 20 Hz over [0, 1] inclusive
    t0, d0 = st[1]
    assert t0 == 50_000_000 and d0.t == pytest.approx(0.05)
    assert d0.pos.x == pytest.approx(0.05) and d0.pos.z == 2.5
    assert d0.err.z == pytest.approx(0.5) and d0.err.x == pytest.approx(0.05)
    assert d0.est_err.x == pytest.approx(0.3) and d0.est_err.horiz == pytest.approx(0.5)
    assert list(d0.motors) == [0.4, 0.5, 0.6, 0.7]
    assert d0.ctrl.x.u == pytest.approx(0.1) and d0.ctrl.y.u == pytest.approx(-0.2)
    assert d0.ctrl.thrust == 0.5 and d0.spray == 1.0 and d0.wind.x == 2.0
    last = st[-1][1]
    assert last.ctrl.x.u == 0.7 and math.isnan(last.ctrl.y.u)
    counts = {}
    for topic, _, _ in msgs:
        counts[topic] = counts.get(topic, 0) + 1
    assert counts["/drone/pose"] == counts["/drone/pose_ref"] == counts["/drone/pose_est"] == 11
    assert counts["/tf"] == 11
    with open(path, "rb") as f:
        r = make_reader(f)
        md = {m.name: m.metadata for m in r.iter_metadata()}
        att = {a.name: a.data for a in r.iter_attachments()}
    assert md["run"]["seed"] == "7" and "mujoco" in md["versions"]
    assert att["config.toml"] == b"a = 1\n"
    assert (path.parent / "layout.json").exists()


def test_light_set_rates_and_custom_rates(tmp_path):
    def run(**kw):
        p = tmp_path / f"{len(list(tmp_path.iterdir()))}.mcap"
        with RunLog(p, metadata={}, config_toml="", layout=False, **kw) as log:
            for k in range(200):  # 2 s
                t = k * 0.01
                log.tick(t, _tick_values((t, 0.0, 2.0)))
                if k % 5 == 0:  # 20 Hz GPS
                    log.gps(t, (t, 0.1, 2.0))
                    log.estimator(t, "kf", np.arange(6.0), np.ones(6), np.zeros(3))
        out = {}
        for topic, _, _ in _decoded(p):
            out[topic] = out.get(topic, 0) + 1
        return out

    light = run(channels="light")
    assert light["/drone/state"] == 10 and light["/gps"] == 2 and light["/estimator/kf"] == 2
    full = run(channels="full")
    assert full["/gps"] == 40 and full["/estimator/kf"] == 20 and full["/drone/state"] == 40
    custom = run(channels=["state", "gps"], rates={"state": 2.0, "gps": None})
    assert custom == {"/drone/state": 4, "/gps": 40}


def test_none_is_a_cheap_no_op(tmp_path):
    path = tmp_path / "x" / "run.mcap"
    log = RunLog(path, channels="none", metadata={}, config_toml="")
    log.scene(0.0, [[0, 0], [1, 0], [1, 1]], [], [], swath=1.0, altitude=1.0)
    log.tick(0.0, _tick_values((0.0, 0.0, 0.0)))
    log.gps(0.0, (0, 0, 0))
    log.estimator(0.0, "kf", [0.0], [1.0])
    log.frame(0.0, "chase", b"", 1, 1, 60.0)
    log.summary({"a": 1})
    log.close()
    assert not path.exists() and not log.want_frame(0.0)
    with pytest.raises(ValueError):
        RunLog(path, channels=["tf", "nope"], metadata={}, config_toml="")
    with pytest.raises(ValueError):
        RunLog(path, channels="medium", metadata={}, config_toml="")


def test_estimator_error_against_true_position(tmp_path):
    path = tmp_path / "run.mcap"
    with RunLog(path, metadata={}, config_toml="", layout=False) as log:
        log.tick(0.0, _tick_values((3.0, 4.0, 2.0)))
        log.estimator(0.0, "pca-kf", [0.0, 1.0, 0.0, 0.0], [1, 1, 1, 1], [0.5, 0.5],
                      {"nis": 2.0}, pos=(6.0, 8.0))
    est = [d for topic, _, d in _decoded(path) if topic == "/estimator/pca_kf"]
    assert len(est) == 1
    e = est[0]
    assert e.err.x == pytest.approx(3.0) and e.err.horiz == pytest.approx(5.0)
    assert e.pos.z == 2.0 and e.extra.nis == 2.0 and list(e.innovation) == [0.5, 0.5]


def test_estimator_error_against_the_truth_at_the_fix(tmp_path):
    """Between state ticks the bank sets the truth at the fix: err is not against a stale pose
    (a pose 50 ms old is 0.25 m behind at 5 m/s; the default mission's estimate is ~1 cm)."""
    path = tmp_path / "run.mcap"
    with RunLog(path, metadata={}, config_toml="", layout=False) as log:
        log.tick(0.0, _tick_values((3.0, 4.0, 2.0)))
        log.set_truth((3.25, 4.0, 2.0))      # the vehicle moved on since the last state tick
        log.estimator(0.03, "kf", [3.26, 5.0, 4.0, 0.0], [1, 1, 1, 1], None, pos=(3.26, 4.0))
    e = [d for topic, _, d in _decoded(path) if topic == "/estimator/kf"][0]
    assert e.err.x == pytest.approx(0.01) and e.err.horiz == pytest.approx(0.01)


_CHILD = textwrap.dedent("""
    import mmap, struct, sys, time
    sys.path.insert(0, {root!r})
    from ag_uav.record.runlog import RunLog
    from ag_uav.record.synthetic import synthetic_run
    f = open({shm!r}, "r+b"); mm = mmap.mmap(f.fileno(), 8)
    with RunLog({path!r}, channels="full", metadata={{"child": 1}}, config_toml="x = 1") as log:
        def on_tick(t, p, q):
            mm[:8] = struct.pack("<d", t)
            time.sleep({sleep})
        synthetic_run(log, {duration}, on_tick=on_tick)
    print("finished", flush=True)
""")


def _spawn(tmp_path, duration, sleep):
    shm = tmp_path / "t.bin"
    shm.write_bytes(b"\0" * 8)
    path = tmp_path / "run.mcap"
    code = _CHILD.format(root=str(ROOT), shm=str(shm), path=str(path), duration=duration,
                         sleep=sleep)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, start_new_session=True)
    return proc, path, shm


def _wait_for_t(shm, t_min, timeout=30.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        t = struct.unpack("<d", shm.read_bytes()[:8])[0]
        if t >= t_min:
            return t
        time.sleep(0.01)
    raise TimeoutError


def test_sigterm_finishes_the_file(tmp_path):
    proc, path, shm = _spawn(tmp_path, 600.0, 0.0005)
    _wait_for_t(shm, 2.0)
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=20)
    assert proc.returncode == 128 + signal.SIGTERM
    with open(path, "rb") as f:
        r = make_reader(f)
        assert r.get_summary().statistics.message_count > 0
        assert sum(1 for _ in r.iter_messages()) == r.get_summary().statistics.message_count


def test_sigkill_loses_at_most_one_sim_second_and_recovers(tmp_path):
    """SIGKILL of the flying process and its log writer (the process group) at a random
    moment: a streaming read keeps everything up to >= t_kill - 1 s."""
    from ag_uav.analysis.viewing import recover

    rng = np.random.default_rng(1234)
    t_kill_target = float(rng.uniform(2.0, 6.0))
    proc, path, shm = _spawn(tmp_path, 600.0, 0.0002)
    _wait_for_t(shm, t_kill_target)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    t_kill = struct.unpack("<d", shm.read_bytes()[:8])[0]
    times = []
    with open(path, "rb") as f:  # streaming read up to the cut (the tail raises)
        try:
            for _, _, m in NonSeekingReader(f).iter_messages(log_time_order=False):
                times.append(m.log_time * 1e-9)
        except Exception:  # noqa: BLE001 - the unfinished chunk at the cut
            pass
    assert times and max(times) >= t_kill - 1.0, (max(times, default=None), t_kill)
    out = tmp_path / "recovered.mcap"
    n = recover(path, out).messages
    assert n == len(times)
    with open(out, "rb") as f:
        r = make_reader(f)
        assert r.get_summary().statistics.message_count == n
        assert {m.name for m in r.iter_metadata()} >= {"run", "versions"}


def test_sigkill_of_the_flying_process_alone_leaves_a_finished_file(tmp_path):
    """The log's writer process outlives a SIGKILLed flight: it writes every row handed to it
    (all but the last 0.3 s of flight and one state tick) and finishes the file."""
    proc, path, shm = _spawn(tmp_path, 600.0, 0.0002)
    _wait_for_t(shm, 3.0)
    proc.kill()
    proc.wait(timeout=10)
    t_kill = struct.unpack("<d", shm.read_bytes()[:8])[0]
    deadline = time.monotonic() + 20
    while True:  # the writer finishes on its own, a moment later
        try:
            with open(path, "rb") as f:
                summary = make_reader(f).get_summary()
            if summary is not None:
                break
        except Exception:  # noqa: BLE001 - not finished yet
            pass
        assert time.monotonic() < deadline, "the writer did not finish the file"
        time.sleep(0.05)
    with open(path, "rb") as f:
        times = [m.log_time * 1e-9 for _, _, m in make_reader(f).iter_messages()]
    assert len(times) == summary.statistics.message_count
    assert max(times) >= t_kill - 0.4, (max(times), t_kill)  # 0.3 s, a state tick, the next


def test_the_writer_process_and_the_inline_writer_write_the_same_messages(tmp_path):
    logs = {}
    for writer in ("process", "inline"):
        p = tmp_path / f"{writer}.mcap"
        with RunLog(p, channels="full", metadata={}, config_toml="", layout=False,
                    writer=writer, io=LogIO(flush_sim_s=0.9)) as log:
            synthetic_run(log, 4.0, seed=3)
            logs[writer] = log.counts
        logs[writer + "_msgs"] = [(topic, t, m.SerializeToString()) for topic, t, m in _decoded(p)]
    assert logs["process"] == logs["inline"]
    assert logs["process_msgs"] == logs["inline_msgs"] and len(logs["inline_msgs"]) > 300
    assert sum(logs["inline"].values()) == len(logs["inline_msgs"])


def test_synthetic_run_is_deterministic(tmp_path):
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    for p in (a, b):
        with RunLog(p, channels="light", metadata={}, config_toml="", layout=False) as log:
            synthetic_run(log, 3.0, seed=5)
    da = [(t, m.SerializeToString()) for _, t, m in _decoded(a)]
    db = [(t, m.SerializeToString()) for _, t, m in _decoded(b)]
    assert da == db and len(da) > 10


def test_uses_mmap_module():  # keeps the child's imports honest on this platform
    assert hasattr(mmap, "mmap") and os.name == "posix"


def test_estimator_vectors_as_arrays_or_lists_encode_the_same(tmp_path):
    """float64 arrays go in as raw bytes, anything else through struct: same decoded values,
    including a strided covariance diagonal and NaN padding / truncation of odd lengths."""
    path = tmp_path / "run.mcap"
    P = np.arange(36.0).reshape(6, 6) * 0.5
    x = np.array([1.0, -2.0, 3.5, 0.25, -0.125, 9.0])
    y = np.array([0.5, -0.75, 1.25])
    with RunLog(path, metadata={}, config_toml="", layout=False) as log:
        log.tick(0.0, _tick_values((1.0, -1.0, 2.0)))
        log.estimator(0.0, "arr", x, np.diag(P), y, pos=(x[0], x[2], x[4]))
        log.estimator(0.0, "lst", x.tolist(), np.diag(P).tolist(), y.tolist(),
                      pos=(1.0, 3.5, -0.125))
        # later calls: a short float32 state, a long diagonal, no innovation
        log.estimator(0.2, "arr", x[:4].astype(np.float32), np.ones(8), None, pos=x[:3])
    est = {}
    for topic, _t, d in _decoded(path):
        if topic.startswith("/estimator/"):
            est.setdefault(topic, []).append(d)
    a0, l0 = est["/estimator/arr"][0], est["/estimator/lst"][0]
    assert a0.SerializeToString() == l0.SerializeToString()
    assert list(a0.p_diag) == [0.0, 3.5, 7.0, 10.5, 14.0, 17.5]
    assert list(a0.innovation) == [0.5, -0.75, 1.25]
    assert a0.err.x == pytest.approx(0.0) and a0.err.y == pytest.approx(4.5)
    assert a0.err.z == pytest.approx(-2.125) and a0.err.horiz == pytest.approx(4.5)
    a1 = est["/estimator/arr"][1]
    assert list(a1.x)[:4] == [1.0, -2.0, 3.5, 0.25] and all(math.isnan(v) for v in a1.x[4:])
    assert list(a1.p_diag) == [1.0] * 6 and all(math.isnan(v) for v in a1.innovation)
    assert a1.pos.y == -2.0


def test_want_estimator_follows_each_estimators_clock(tmp_path):
    with RunLog(tmp_path / "a.mcap", metadata={}, config_toml="", layout=False) as log:
        assert log.want_estimator("kf", 0.0)  # unseen: would be logged
        log.estimator(0.0, "kf", np.zeros(6), np.ones(6), np.zeros(3))
        assert not log.want_estimator("kf", 0.05)  # full set: estimators at 10 Hz
        assert log.want_estimator("kf", 0.1) and log.want_estimator("mckf", 0.05)
        log.estimator(0.05, "kf", np.zeros(6), np.ones(6), np.zeros(3))  # skipped
        assert log.counts["/estimator/kf"] == 1
    assert not log.want_estimator("kf", 10.0) and not log.want_estimator("mckf", 10.0)
    with RunLog(tmp_path / "b.mcap", channels=["state"], metadata={}, config_toml="",
                layout=False) as log:
        assert not log.want_estimator("kf", 0.0)


def test_buffered_messages_precede_a_frame_and_counts_match_the_file(tmp_path):
    """Hot-channel messages are handed to the writer in bursts: in order, before any frame or
    scene message, and all of them on close."""
    from mcap.reader import make_reader as mr

    path = tmp_path / "run.mcap"
    with RunLog(path, metadata={}, config_toml="", layout=False,
                io=LogIO(flush_sim_s=100.0, flush_wall_s=100.0)) as log:
        for k in range(30):
            log.tick(k * 0.01, _tick_values((k * 0.01, 0.0, 2.0)))
            log.gps(k * 0.01, (k * 0.01, 0.0, 2.0))
        log.frame(0.3, "chase", b"\xff\xd8jpeg", 32, 24, 60.0)
        log.tick(0.3, _tick_values((0.3, 0.0, 2.0)))
        counts = log.counts
    with open(path, "rb") as f:
        order = [(c.topic, m.log_time) for _, c, m in
                 mr(f).iter_messages(log_time_order=False)]
    file_counts = {}
    for topic, _ in order:
        file_counts[topic] = file_counts.get(topic, 0) + 1
    assert counts == file_counts and counts["/gps"] == 30 and counts["/drone/state"] == 7
    cam = order.index(("/camera/chase", 300_000_000))
    assert all(tn <= 300_000_000 for _, tn in order[:cam])
    assert [tn for topic, tn in order if topic == "/drone/state"] == [
        k * 50_000_000 for k in range(7)]
    assert order[-1][1] == 300_000_000 and order[cam - 1][1] == 290_000_000


def test_state_attitude_and_numpy_inputs(tmp_path):
    """Roll/pitch/yaw of a tilted, yawed body, from numpy inputs and from the loop's tuples."""
    path = tmp_path / "run.mcap"
    q = np.array([0.9, 0.1, -0.2, 0.3])
    q /= np.linalg.norm(q)
    with RunLog(path, channels=["state"], metadata={}, config_toml="", layout=False) as log:
        kw = _tick_values((1.0, 2.0, 3.0))
        log.tick(0.0, kw._replace(q_true_wxyz=q, p_true=np.array([1.0, 2.0, 3.0])))
        log.tick(0.05, kw._replace(q_true_wxyz=tuple(q.tolist()), p_true=(1.0, 2.0, 3.0)))
    st = [d for topic, _, d in _decoded(path) if topic == "/drone/state"]
    expect = [math.degrees(a) for a in quat_to_euler(*q.tolist())]
    assert min(abs(a) for a in expect) > 3.0  # all three angles non-trivial
    for d in st:
        assert (d.rpy.roll, d.rpy.pitch, d.rpy.yaw) == pytest.approx(expect, abs=1e-12)
        assert (d.pos.x, d.pos.y, d.pos.z) == (1.0, 2.0, 3.0)
    assert len(st) == 2


def test_a_writer_process_killed_on_its_own_is_not_silent(tmp_path):
    """The flight notices a dead writer within about a second of wall time: the log records
    the loss (:attr:`RunLog.lost`, an OSError naming the log, and the sim time it stops at),
    logs nothing more, and the flight goes on for its summary (which ``fly`` marks)."""
    path = tmp_path / "run.mcap"
    log = RunLog(path, channels="full", metadata={}, config_toml="", layout=False)
    log.tick(0.0, _tick_values((0.0, 0.0, 1.0)))
    log.flush()
    time.sleep(0.1)  # the writer polls its ring every millisecond
    os.kill(log.channels.sink.pid, signal.SIGKILL)
    time.sleep(1.1)
    for k in range(1, 200):
        log.tick(k * 0.01, _tick_values((k * 0.01, 0.0, 1.0)))
    e = log.lost
    assert isinstance(e, OSError) and "writer process exited" in str(e)
    assert e.filename == str(path) and not isinstance(e, BrokenPipeError)
    assert 0.0 < log.lost_at <= 0.05 and log.closed  # noticed at the first hand-over after
    log.close()  # quietly: the loss is recorded
    with open(path, "rb") as f:  # what it wrote before it died is there
        times = []
        try:
            for _, _, m in NonSeekingReader(f).iter_messages(log_time_order=False):
                times.append(m.log_time)
        except Exception:  # noqa: BLE001 - no footer
            pass
    assert times and min(times) == 0


def test_a_log_past_the_spare_cores_writes_in_process_and_says_so(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 2)  # one spare core: one writer process
    a = RunLog(tmp_path / "a.mcap", metadata={}, config_toml="", layout=False)
    with pytest.warns(UserWarning, match=r"b\.mcap: written in this process \(1 writer"):
        b = RunLog(tmp_path / "b.mcap", metadata={}, config_toml="", layout=False)
    assert a.channels.sink.process and not b.channels.sink.process
    for log in (a, b):
        log.tick(0.0, _tick_values((1.0, 2.0, 3.0)))
        log.close()
    c = RunLog(tmp_path / "c.mcap", metadata={}, config_toml="", layout=False)
    assert c.channels.sink.process  # a's writer is gone: the core is spare again
    c.close()
    assert [len(_decoded(tmp_path / f"{x}.mcap")) for x in "ab"] == [5, 5]


def test_dose_maps_period_doubles_after_each_quota_of_bytes(tmp_path: Path, monkeypatch) -> None:
    """A long flight over a big field logs its dose maps at a period that doubles after each
    DOSE_QUOTA_B of them (the log grows with the log of the duration, not with it); the final
    map is always logged."""
    import ag_uav.record.log_scene as rl

    grid = np.ones((100, 100))          # 40 kB of float32 a map
    monkeypatch.setattr(rl, "DOSE_QUOTA_B", 400_000)   # ~10 maps a quota
    times = []
    with RunLog(tmp_path / "d.mcap", channels="full", metadata={}) as log:
        for k in range(20_000):
            t = 0.5 * k
            if log.want_dose(t):
                log.dose(t, 0.0, 0.0, 1.0, grid)
                times.append(t)
        log.dose(10_000.0, 0.0, 0.0, 1.0, grid, final=True)
    gaps = np.diff(times)
    assert gaps[0] == 5.0 and gaps.max() >= 5.0 * 2 ** 4
    assert np.all(np.diff(gaps) >= 0)                    # the period never shrinks
    assert len(times) < 80                               # 2,000 maps at a fixed 5 s
    summ = make_reader(open(tmp_path / "d.mcap", "rb")).get_summary()
    counts = {summ.channels[c].topic: n for c, n in summ.statistics.channel_message_counts.items()}
    assert counts["/dose"] == len(times) + 1
