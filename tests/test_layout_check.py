"""The Foxglove layout (``layout.json``) read against the MCAP of a real logged run.

Every panel of the layout ``ag_uav.record.layout.write_foxglove_layout`` writes must name
topics the run's log holds, with the schema that panel renders, and every plotted message path
must resolve, field by field, to a number in a logged message. A layout whose panel names a
topic the log lacks (or a wrong schema, or a field the message has not) fails the check: the
second half of this file plants each fault and shows it is caught.

Foxglove's message-path syntax used by the layout: ``/topic.field.sub[index]``; the topic is the
longest logged topic the path starts with (Foxglove's own rule for unquoted topics).
"""

from __future__ import annotations

import copy
import json
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pytest
from google.protobuf import descriptor_pb2, message_factory
from google.protobuf.descriptor import FieldDescriptor
from mcap.reader import make_reader

# What each panel renders (Foxglove schema names).  3D: every topic it can draw; a topic set
# to draw as a pose (``type`` arrow / axis) must be a pose message.
POSES = {"foxglove.PoseInFrame", "foxglove.PosesInFrame"}
IMAGES = {"foxglove.CompressedImage", "foxglove.RawImage", "foxglove.CompressedVideo"}
SCENE_3D = POSES | IMAGES | {
    "foxglove.SceneUpdate", "foxglove.FrameTransform", "foxglove.FrameTransforms",
    "foxglove.CameraCalibration", "foxglove.PointCloud", "foxglove.LaserScan", "foxglove.Grid"}
CALIBRATION = {"foxglove.CameraCalibration"}
# the Map panel draws location fixes (a track it can follow) and GeoJSON
FIXES = {"foxglove.LocationFix", "sensor_msgs/NavSatFix"}
MAP = FIXES | {"foxglove.GeoJSON"}
_TOKEN = re.compile(r"\.([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]")


class LogIndex:
    """Topics, schema names and the first decoded message of each topic of one MCAP file."""

    def __init__(self, mcap_path: Path) -> None:
        with open(mcap_path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            self.schema: dict[str, str] = {}
            classes: dict[str, Any] = {}
            for ch in summary.channels.values():
                sc = summary.schemas[ch.schema_id]
                self.schema[ch.topic] = sc.name
                if ch.message_encoding == "protobuf":
                    fds = descriptor_pb2.FileDescriptorSet.FromString(sc.data)
                    classes[ch.topic] = message_factory.GetMessages(list(fds.file))[sc.name]
            self.first: dict[str, Any] = {}
            for _, ch, msg in reader.iter_messages():
                if ch.topic in classes and ch.topic not in self.first:
                    self.first[ch.topic] = classes[ch.topic].FromString(msg.data)
                    if len(self.first) == len(classes):
                        break
        self.frames = self._frames()

    def _frames(self) -> set[str]:
        """Frame ids the log's transforms and poses name (what a 3D panel can follow)."""
        out: set[str] = set()
        for topic, m in self.first.items():
            if self.schema[topic] == "foxglove.FrameTransforms":
                for tf in m.transforms:
                    out |= {tf.parent_frame_id, tf.child_frame_id}
            elif self.schema[topic] in POSES:
                out.add(m.frame_id)
        return out

    def topic_of(self, path: str) -> str | None:
        """The longest logged topic ``path`` starts with (followed by ``.``, ``[`` or nothing)."""
        hits = [t for t in self.schema if path == t or path.startswith((t + ".", t + "["))]
        return max(hits, key=len) if hits else None


def _repeated(fd: FieldDescriptor) -> bool:
    """A repeated field (``is_repeated`` in protobuf >= 6, ``label`` before)."""
    if hasattr(fd, "is_repeated"):
        return bool(fd.is_repeated)
    return fd.label == FieldDescriptor.LABEL_REPEATED


def _need(log: LogIndex, panel: str, topic: str, allowed: set[str]) -> list[str]:
    if topic not in log.schema:
        return [f"{panel}: topic {topic} is not in the log"]
    if log.schema[topic] not in allowed:
        return [f"{panel}: topic {topic} is {log.schema[topic]}, the panel needs one of "
                f"{sorted(allowed)}"]
    return []


def _resolve(log: LogIndex, panel: str, path: str) -> list[str]:
    """A plot path down to a numeric leaf of the topic's first logged message."""
    topic = log.topic_of(path)
    if topic is None:
        return [f"{panel}: {path}: no logged topic starts the path"]
    if topic not in log.first:
        return [f"{panel}: {path}: {topic} has no decodable (protobuf) message"]
    rest, value, leaf = path[len(topic):], log.first[topic], None
    tokens = list(_TOKEN.finditer(rest))
    if "".join(t.group(0) for t in tokens) != rest or not tokens:
        return [f"{panel}: {path}: not a plain field path (.field / [index])"]
    for tok in tokens:
        name, index = tok.group(1), tok.group(2)
        if name is not None:
            fd = getattr(value, "DESCRIPTOR", None)
            leaf = fd.fields_by_name.get(name) if fd is not None else None
            if leaf is None:
                return [f"{panel}: {path}: {log.schema[topic]} has no field {name!r} here"]
            value = getattr(value, name)
        else:
            if leaf is None or not _repeated(leaf):
                return [f"{panel}: {path}: [{index}] indexes a field that is not repeated"]
            if int(index) >= len(value):
                return [f"{panel}: {path}: [{index}] past the {len(value)} logged values"]
            value, leaf = value[int(index)], None
    if hasattr(value, "DESCRIPTOR") or not isinstance(value, int | float):
        return [f"{panel}: {path}: ends on a {type(value).__name__}, not a number"]
    return []


def check_layout(layout: dict[str, Any], log: LogIndex) -> list[str]:
    """Problems of ``layout`` (Foxglove app-export JSON) against ``log``; empty when it fits."""
    problems: list[str] = []
    for panel, cfg in layout["configById"].items():
        kind = panel.split("!", 1)[0]
        if kind == "3D":
            for topic, tcfg in cfg.get("topics", {}).items():
                pose = tcfg.get("type") in ("arrow", "axis")
                problems += _need(log, panel, topic, POSES if pose else SCENE_3D)
            for frame in [cfg.get("followTf")] + [ly.get("frameId") for ly in
                                                  cfg.get("layers", {}).values()]:
                if frame and frame not in log.frames:
                    problems.append(f"{panel}: frame {frame!r} is in no logged transform")
        elif kind == "Image":
            mode = cfg.get("imageMode", {})
            problems += _need(log, panel, mode.get("imageTopic", "<none>"), IMAGES)
            if mode.get("calibrationTopic"):
                problems += _need(log, panel, mode["calibrationTopic"], CALIBRATION)
        elif kind == "Plot":
            for p in cfg.get("paths", []):
                problems += _resolve(log, panel, p["value"])
        elif kind == "Map":
            named = [*cfg.get("topicColors", {}), *cfg.get("topicConfig", {}),
                     *cfg.get("disabledTopics", [])]
            for topic in dict.fromkeys(named):
                problems += _need(log, panel, topic, MAP)
            if cfg.get("followTopic"):
                problems += _need(log, panel, cfg["followTopic"], FIXES)
        else:
            problems.append(f"{panel}: panel kind {kind!r} is not checked (teach this test)")
    return problems


def _panels(node: Any) -> Iterable[str]:
    if isinstance(node, str):
        yield node
    else:
        yield from _panels(node["first"])
        yield from _panels(node["second"])


# --------------------------------------------------------------------------------------------
# a real logged run
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> tuple[dict[str, Any], LogIndex, dict[str, Any]]:
    """The two-part field flown whole (~150 s of flight), full log, the four-filter bank and,
    where renders work here, both cameras at 0.25 Hz; without renders it flies again without."""
    import ag_uav
    from ag_uav.jobs.run import fly

    out = tmp_path_factory.mktemp("layout")
    over = {"mission.field": "two-part", "log.render_hz": 0.25}
    res, d = fly(ag_uav.load_config(None, overrides=over), out_root=out, run_id="render")
    if not res.summary.get("frames"):
        over["log.render"] = False
        res, d = fly(ag_uav.load_config(None, overrides=over), out_root=out, run_id="plain")
    layout = json.loads((d / "layout.json").read_text())
    return layout, LogIndex(d / "run.mcap"), res.summary


def test_every_panel_fits_the_log(run):
    layout, log, summary = run
    assert summary["completed"]
    assert check_layout(layout, log) == []
    kinds = {p.split("!", 1)[0] for p in layout["configById"]}
    assert kinds >= {"3D", "Plot", "Map"}
    # the Map panel opens on the field, the plan, the flown track, the estimate and the fixes
    mp = layout["configById"]["Map!aguavmap"]
    assert mp["followTopic"] == "/geo/true"
    assert {"/geo/field", "/geo/plan", "/geo/true", "/geo/est", "/geo/gnss", "/geo/sprayed",
            "/geo/dose"} <= set(mp["topicConfig"])
    assert next(_panels(layout["layout"])) == "Map!aguavmap"  # the top-left panel
    if summary.get("frames"):  # the Image panels were checked against real frames
        assert {"Image!camchase", "Image!camdown"} <= set(layout["configById"])
    # what the check walked: the four filters' error plots and the spray-job plot
    paths = [p["value"] for p in layout["configById"]["Plot!errors"]["paths"]]
    assert {f"/estimator/{e}.err.horiz" for e in ("kf", "mckf", "pca_kf", "pca_mckf")} <= set(
        paths)
    assert "Plot!spray" in layout["configById"]
    # and the layout tree shows exactly the panels it configures
    assert sorted(_panels(layout["layout"])) == sorted(layout["configById"])


def _plant(layout: dict[str, Any], how: str) -> dict[str, Any]:
    lay = copy.deepcopy(layout)
    cfg = lay["configById"]
    if how == "3d-topic":
        cfg["3D!aguav3d"]["topics"]["/lidar/points"] = {"visible": True}
    elif how == "3d-pose-schema":
        cfg["3D!aguav3d"]["topics"]["/field"]["type"] = "arrow"
    elif how == "plot-topic":
        cfg["Plot!errors"]["paths"].append({"value": "/drone/wind.speed", "enabled": True})
    elif how == "plot-field":
        cfg["Plot!pos"]["paths"].append({"value": "/drone/state.pos.w", "enabled": True})
    elif how == "plot-index":
        cfg["Plot!motors"]["paths"].append({"value": "/drone/state.motors[4]", "enabled": True})
    elif how == "plot-not-a-number":
        cfg["Plot!pos"]["paths"].append({"value": "/drone/state.pos", "enabled": True})
    elif how == "image-topic":
        cfg["Image!camextra"] = {"imageMode": {"imageTopic": "/camera/extra"}}
    elif how == "image-schema":
        cfg["Image!camextra"] = {"imageMode": {"imageTopic": "/drone/pose"}}
    elif how == "follow-frame":
        cfg["3D!aguav3d"]["followTf"] = "base_link_missing"
    elif how == "map-topic":
        cfg["Map!aguavmap"]["topicConfig"]["/geo/lidar"] = {"historyMode": "all"}
    elif how == "map-schema":
        cfg["Map!aguavmap"]["topicColors"]["/gps"] = "#ff0000"
    elif how == "map-follow":
        cfg["Map!aguavmap"]["followTopic"] = "/geo/field"
    elif how == "unknown-panel":
        cfg["Gauge!speed"] = {"path": "/drone/state.speed"}
    return lay


PLANTS = {
    "3d-topic": "topic /lidar/points is not in the log",
    "3d-pose-schema": "topic /field is foxglove.SceneUpdate",
    "plot-topic": "/drone/wind.speed: no logged topic starts the path",
    "plot-field": "has no field 'w'",
    "plot-index": "[4] past the 4 logged values",
    "plot-not-a-number": "/drone/state.pos: ends on a",
    "image-topic": "topic /camera/extra is not in the log",
    "image-schema": "topic /drone/pose is foxglove.PoseInFrame, the panel needs",
    "follow-frame": "frame 'base_link_missing' is in no logged transform",
    "map-topic": "topic /geo/lidar is not in the log",
    "map-schema": "topic /gps is foxglove.PoseInFrame, the panel needs",
    "map-follow": "topic /geo/field is foxglove.GeoJSON, the panel needs",
    "unknown-panel": "panel kind 'Gauge' is not checked",
}


@pytest.mark.parametrize("how", sorted(PLANTS))
def test_a_planted_fault_fails_the_check(run, how):
    layout, log, _ = run
    problems = check_layout(_plant(layout, how), log)
    assert len(problems) == 1, problems
    assert PLANTS[how] in problems[0]


_NO_EGL_RUN = """
import json, sys
import ag_uav
from ag_uav.jobs.run import fly
res, d = fly(ag_uav.load_config(None, {"sim.max_time_s": 3.0, "log.render_hz": 1.0}),
             out_root=sys.argv[1], run_id="no-egl")
print(json.dumps({"frames": res.summary.get("frames"), "dir": str(d)}))
"""


def test_a_run_whose_renders_failed_gets_no_camera_panels(tmp_path):
    """EGL made to fail for real (no vendor library), so the run goes on without frames."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "__EGL_VENDOR_LIBRARY_FILENAMES": str(tmp_path / "none.json"),
           "MUJOCO_GL": "egl", "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    out = subprocess.run([sys.executable, "-c", _NO_EGL_RUN, str(tmp_path)], env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout.strip().splitlines()[-1])
    assert not info["frames"]
    d = Path(info["dir"])
    problems = check_layout(json.loads((d / "layout.json").read_text()), LogIndex(d / "run.mcap"))
    assert [p for p in problems if "/camera/" in p] == []
