"""Every log passes Foxglove's own TypeScript reader (@mcap/core + @mcap/nodejs + @mcap/support):
indexed read with CRC validation, every message decoded, then a streaming read.  Every message
of a Foxglove schema is decoded once more against Foxglove's published schema (@foxglove/schemas),
the geographic topics (LocationFix, GeoJSON) included.

Needs node + npm; packages are pinned by tests/node/package-lock.json and installed with
``npm ci`` when node_modules is missing (skipped, with the reason, where node is absent or
the install fails, e.g. offline)."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import shapely
from mcap.reader import make_reader
from PIL import Image

from ag_uav.analysis.viewing import recover
from ag_uav.record.runlog import RunLog
from ag_uav.record.synthetic import synthetic_run

NODE_DIR = Path(__file__).resolve().parent / "node"


@pytest.fixture(scope="module")
def node_checker():
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node/npm not installed: Foxglove TypeScript reader check not run")
    mods = NODE_DIR / "node_modules"
    if not all((mods / m).exists() for m in ("@mcap/support", "@foxglove/schemas",
                                              "protobufjs")):
        r = subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=NODE_DIR,
                           capture_output=True, text=True, timeout=300)
        if r.returncode != 0:
            pytest.skip(f"npm ci failed (offline?): {r.stderr.strip().splitlines()[-1:]}")

    def check(path: Path) -> dict:
        r = subprocess.run([node, str(NODE_DIR / "check_mcap.mjs"), str(path)],
                           capture_output=True, text=True, timeout=120)
        assert r.stdout, r.stderr
        out = json.loads(r.stdout.strip().splitlines()[-1])
        assert r.returncode == 0 and out["ok"], out.get("error")
        return out

    return check


#: the run's origin in the synthetic logs: the default farm (ag_uav.world.field.DEFAULT_ORIGIN)
ORIGIN = (46.725, -117.02, 760.0)


def _jpeg() -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.full((24, 32, 3), 90, np.uint8)).save(buf, format="JPEG")
    return buf.getvalue()


@pytest.fixture(scope="module")
def full_log(tmp_path_factory):
    d = tmp_path_factory.mktemp("node")
    jpg = _jpeg()
    with RunLog(d / "run.mcap", channels="full", metadata={"seed": 1},
                config_toml="x = 1\n") as log:
        def on_tick(t, p, q):
            if log.want_frame(t):
                log.frame(t, "down", jpg, 32, 24, 70.0, pose=(p, (0.0, 1.0, 0.0, 0.0)))
        synthetic_run(log, 5.0, on_tick=on_tick, estimators=("kf", "mckf", "pca_kf"),
                      origin=ORIGIN)
        log.sprayed(5.0, [shapely.box(0, 0, 10, 4).difference(shapely.box(4, 1, 5, 2))])
        dose = np.zeros((40, 60))  # a sprayed strip: on target, its edges under-dosed
        dose[10:20, 5:50], dose[9, 5:50], dose[20, 5:50] = 1.0, 0.5, 0.5
        log.dose(5.0, 0.0, 0.0, 1.0, dose, final=True)
        log.summary({"rmse_m": 0.3})
    return d / "run.mcap"


def _count(path: Path) -> dict[str, int]:
    with open(path, "rb") as f:
        r = make_reader(f)
        s = r.get_summary()
        return {s.channels[c].topic: n for c, n in s.statistics.channel_message_counts.items()}


def test_full_log_passes_typescript_reader(node_checker, full_log):
    out = node_checker(full_log)
    assert out["indexed"]["by_topic"] == _count(full_log)
    assert out["indexed"]["decoded"] == out["indexed"]["messages"] == out["stream"]["messages"]
    assert out["stream"]["footer"] is True
    assert set(out["indexed"]["metadata"]) >= {"run", "versions", "summary"}
    assert set(out["indexed"]["attachments"]) == {"config.toml", "summary.json"}
    # protobuf field names survive as written (Foxglove plot paths use them)
    assert set(out["indexed"]["field_names"]["/drone/state"]) >= {"pos", "err", "est_err",
                                                                   "ctrl", "motors"}
    # every message of a Foxglove schema agrees with Foxglove's own schema, the geographic
    # topics included (LocationFix: lat/lon in range; GeoJSON: it parses)
    geo = {"/geo/true", "/geo/est", "/geo/gnss", "/geo/field", "/geo/plan", "/geo/sprayed",
           "/geo/dose"}
    by_topic, canon = out["indexed"]["by_topic"], out["indexed"]["canonical"]
    assert geo <= set(by_topic)
    with open(full_log, "rb") as f:
        s = make_reader(f).get_summary()
        foxglove = {ch.topic for ch in s.channels.values()
                    if s.schemas[ch.schema_id].name.startswith("foxglove.")}
    assert geo <= foxglove
    assert canon == {t: by_topic[t] for t in foxglove}
    assert set(out["indexed"]["field_names"]["/geo/gnss"]) >= {
        "latitude", "longitude", "altitude", "position_covariance",
        "position_covariance_type", "color", "metadata"}


def test_a_schema_that_is_not_foxglove_s_fails_the_check(node_checker, tmp_path):
    """A LocationFix written with a schema that swaps latitude and longitude (as the log's own
    schema says) is caught by the second decode against Foxglove's schema."""
    from google.protobuf import descriptor_pb2
    from mcap.writer import Writer

    fdp = descriptor_pb2.FileDescriptorProto(name="foxglove/LocationFix.proto",
                                             package="foxglove", syntax="proto3")
    msg = fdp.message_type.add(name="LocationFix")
    F = descriptor_pb2.FieldDescriptorProto
    msg.field.add(name="latitude", number=2, type=F.TYPE_DOUBLE, label=F.LABEL_OPTIONAL)
    msg.field.add(name="longitude", number=1, type=F.TYPE_DOUBLE, label=F.LABEL_OPTIONAL)
    data = descriptor_pb2.FileDescriptorSet(file=[fdp]).SerializeToString()
    path = tmp_path / "swapped.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("foxglove.LocationFix", "protobuf", data)
        cid = w.register_channel("/geo/true", "protobuf", sid)
        body = b"\x09" + np.float64(46.7).tobytes() + b"\x11" + np.float64(-117.0).tobytes()
        w.add_message(cid, log_time=0, data=body, publish_time=0)
        w.finish()
    r = subprocess.run([shutil.which("node"), str(NODE_DIR / "check_mcap.mjs"), str(path)],
                       capture_output=True, text=True, timeout=120)
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert r.returncode == 1 and not out["ok"]
    assert "/geo/true: field longitude is 46.7 by the log's schema, -117 by Foxglove's" in \
        out["error"]


def test_light_and_recovered_logs_pass_typescript_reader(node_checker, full_log, tmp_path):
    light = tmp_path / "light.mcap"
    with RunLog(light, channels="light", metadata={}, config_toml="", layout=False) as log:
        synthetic_run(log, 3.0)
    assert node_checker(light)["indexed"]["messages"] > 0
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full_log.read_bytes()[: int(full_log.stat().st_size * 0.5)])
    fixed = tmp_path / "fixed.mcap"
    n = recover(cut, fixed).messages
    out = node_checker(fixed)
    assert out["indexed"]["messages"] == n > 0


def test_real_flight_log_passes_foxglove_reader(node_checker, tmp_path):
    """A real (short) MuJoCo flight with GPS, estimators in the loop and EGL camera renders."""
    import ag_uav
    from ag_uav.jobs.run import fly

    cfg = ag_uav.load_config(None, {"sim.max_time_s": 15.0, "gps.preset": "sbas",
                                    "estimator.name": "pca-mckf", "estimator.shadow": ["kf"],
                                    "log.render_hz": 2.0})
    res, run_dir = fly(cfg, out_root=tmp_path, run_id="real")
    out = node_checker(run_dir / "run.mcap")
    assert out["indexed"]["decoded"] == out["indexed"]["messages"] > 0
    with open(run_dir / "run.mcap", "rb") as f:
        topics = {ch.topic for ch in make_reader(f).get_summary().channels.values()}
    for t in ("/tf", "/drone/pose", "/drone/pose_est", "/drone/state", "/gps", "/field",
              "/estimator/pca_mckf", "/estimator/kf", "/geo/true", "/geo/est", "/geo/gnss",
              "/geo/field", "/geo/plan"):
        assert t in topics
    assert out["indexed"]["canonical"]["/geo/gnss"] == out["indexed"]["by_topic"]["/gps"] > 0
    if res.summary["frames"]:
        assert {"/camera/chase", "/camera/down"} <= topics
    else:  # EGL unavailable: the run goes on and says why
        assert any("no camera frames" in n for n in res.summary["notes"])
    assert (run_dir / "layout.json").exists()


_REAL_CHILD = """
import mmap, struct, sys
sys.path.insert(0, {root!r})
import ag_uav
from ag_uav.record.runlog import RunLog
from ag_uav.engine.missions import simulate
cfg = ag_uav.load_config(None, {{"log.render": False}})
f = open({shm!r}, "r+b")
mm = mmap.mmap(f.fileno(), 8)
pack = struct.Struct("<d").pack
def hook(t, data):
    mm[:8] = pack(t + 0.01)   # sim time reached after this tick
with RunLog({path!r}, channels="full", metadata={{}}, config_toml="") as log:
    simulate(cfg, log=log, tick_hook=hook)
"""


def test_sigkill_of_a_real_flight_loses_under_a_sim_second(node_checker, tmp_path):
    """A real MuJoCo mission logging the full channel set, SIGKILLed at a random moment with
    its log writer process (the worst case: the writer holds what it has not written yet)."""
    import os
    import signal
    import struct
    import sys
    import time

    from mcap.stream_reader import StreamReader

    root = Path(__file__).resolve().parent.parent
    shm = tmp_path / "t.bin"
    shm.write_bytes(b"\0" * 8)
    path = tmp_path / "run.mcap"
    t_target = float(np.random.default_rng(7).uniform(20.0, 200.0))
    proc = subprocess.Popen([sys.executable, "-c", _REAL_CHILD.format(
        root=str(root), shm=str(shm), path=str(path))], stderr=subprocess.PIPE,
        start_new_session=True)
    deadline = time.monotonic() + 120
    while struct.unpack("<d", shm.read_bytes()[:8])[0] < t_target:
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        assert time.monotonic() < deadline
        time.sleep(0.002)
    os.killpg(proc.pid, signal.SIGKILL)  # the flight and its log writer
    proc.wait(timeout=10)
    t_kill = struct.unpack("<d", shm.read_bytes()[:8])[0]
    times = []
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, skip_magic=False).records:
                if hasattr(rec, "log_time") and hasattr(rec, "channel_id"):
                    times.append(rec.log_time * 1e-9)
        except Exception:  # noqa: BLE001 - the unfinished chunk at the cut
            pass
    print(f"killed at sim t = {t_kill:.2f} s; last message kept at {max(times):.2f} s")
    assert times and max(times) >= t_kill - 1.0, (max(times, default=None), t_kill)
    out = tmp_path / "recovered.mcap"
    assert recover(path, out).messages == len(times)
    res = node_checker(out)
    assert res["indexed"]["decoded"] == res["indexed"]["messages"] == len(times)
