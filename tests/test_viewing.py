"""show / plot / video / recover / layout from a synthetic run log (no GL needed)."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import shapely
from mcap.reader import make_reader
from PIL import Image

from ag_uav.analysis import viewing
from ag_uav.record.runlog import RunLog
from ag_uav.record.synthetic import synthetic_run


def _fake_jpeg(k: int) -> bytes:
    img = np.zeros((48, 64, 3), np.uint8)
    img[:, : (k * 3) % 64] = (200, 40, 40)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="JPEG", quality=80)
    return buf.getvalue()


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("run-0001")
    frames = [0]
    with RunLog(d / "run.mcap", channels="full", metadata={"seed": 3, "scenario": "demo"},
                config_toml='[mission]\nspeed = 4.0\n', rates={"camera": 5.0}) as log:
        def on_tick(t, p, q):
            if log.want_frame(t):
                frames[0] += 1
                log.frame(t, "chase", _fake_jpeg(frames[0]), 64, 48, 60.0,
                          pose=(p, (1.0, 0.0, 0.0, 0.0)))
        synthetic_run(log, 8.0, on_tick=on_tick)
        log.sprayed(8.0, [shapely.box(2, 2, 30, 6)])
        log.summary({"rmse_m": 0.5, "coverage": 0.25})
    return d


def test_show_reports_metadata_channels_and_config(run_dir):
    text = viewing.show(run_dir)
    assert "finished, indexed" in text
    assert "scenario" in text and "demo" in text and "speed = 4.0" in text
    assert "rmse_m" in text and "coverage" in text
    for topic in ("/drone/state", "/gps", "/estimator/kf", "/camera/chase", "/field", "/tf"):
        assert topic in text
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("/drone/state "))
    assert int(line.split()[2]) == 160  # 20 Hz over [0, 8) s
    assert float(line.split()[3]) == pytest.approx(20.0, rel=1e-3)


def test_read_run_series_match_the_source(run_dir):
    d = viewing.read_run(run_dir)
    st = d.series["/drone/state"]
    assert np.allclose(np.diff(st.t), 0.05)
    assert np.allclose(st["err.horiz"], np.hypot(st["err.x"], st["err.y"]))
    assert st["motors"].shape == (len(st.t), 4)
    assert len(d.images["/camera/chase"]) == 40
    assert d.scenes["/field"].entities[0].id == "field"


def test_plot_writes_four_pngs(run_dir, tmp_path):
    paths = viewing.plot(run_dir, tmp_path / "plots")
    assert [p.name for p in paths] == ["map.png", "errors.png", "controller.png",
                                       "estimators.png"]
    for p in paths:
        with Image.open(p) as im:
            assert im.size[0] > 400 and im.size[1] > 300


def test_video_from_logged_frames(run_dir, tmp_path):
    pytest.importorskip("imageio.v2")
    iff = pytest.importorskip("imageio_ffmpeg")
    out = viewing.video(run_dir, tmp_path / "chase.mp4")
    n_frames, secs = iff.count_frames_and_secs(str(out))
    assert n_frames == 40 and secs == pytest.approx(8.0, abs=0.3)  # 5 fps: real time
    gen = iff.read_frames(str(out))
    meta = next(gen)
    assert tuple(meta["size"]) == (64, 48)
    gen.close()
    with pytest.raises(viewing.LogError, match="cameras: chase"):
        viewing.video(run_dir, tmp_path / "x.mp4", camera="nope")


def test_recover_truncated_log(run_dir, tmp_path):
    src = (run_dir / "run.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src[: int(len(src) * 0.6)])
    with open(cut, "rb") as f, pytest.raises(Exception):  # noqa: B017 - no footer
        make_reader(f).get_summary()
    assert "NOT finished" in viewing.show(cut)
    out = tmp_path / "fixed.mcap"
    rep = viewing.recover(cut, out)
    n = rep.messages
    with open(run_dir / "run.mcap", "rb") as f:
        total = make_reader(f).get_summary().statistics.message_count
    assert 0 < n < total
    assert rep.cut_at is not None and rep.lost is None and "cut short" in rep.describe()
    with open(out, "rb") as f:
        r = make_reader(f)
        assert r.get_summary().statistics.message_count == n
        assert sum(1 for _ in r.iter_messages()) == n
        assert {a.name for a in r.iter_attachments()} >= {"config.toml"}
    assert "finished, indexed" in viewing.show(out)
    with pytest.raises(viewing.LogError, match="must differ"):
        viewing.recover(out, out)


def test_layout_is_app_export_json(run_dir):
    lay = json.loads((run_dir / "layout.json").read_text())
    assert set(lay) >= {"configById", "layout", "globalVariables", "userNodes"}
    ids = set()

    def walk(node):
        if isinstance(node, str):
            ids.add(node)
        else:
            walk(node["first"])
            walk(node["second"])

    walk(lay["layout"])
    assert ids == set(lay["configById"])
    assert lay["configById"]["Image!camchase"]["imageMode"]["imageTopic"] == "/camera/chase"
    paths = [p["value"] for p in lay["configById"]["Plot!errors"]["paths"]]
    assert "/estimator/kf.err.horiz" in paths and "/estimator/mckf.err.horiz" in paths
    ctrl = [p["value"] for p in lay["configById"]["Plot!ctrl"]["paths"]]
    assert "/drone/state.ctrl.x.u" in ctrl
