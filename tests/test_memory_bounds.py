"""Memory is bounded by what is flown: a plan longer than ``sim.max_time_s`` can fly is cut to its
head before it is densified (bit-identical up to the horizon), the run says so before flying, and
``sim.memory_budget_mb`` refuses a run whose tables would not fit (one line, exit 2)."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from ag_uav.cli import main
from ag_uav.config import ConfigError, load_config
from ag_uav.engine.missions import build_reference, mission_setup, reach_m
from ag_uav.world.mission import build_field, build_plan


def square_field(path, side_m: float) -> str:
    """A side_m × side_m lon/lat square (GeoJSON) near 46.7° N."""
    lat0, lon0 = 46.735, -116.98
    dlat = side_m / 111_132.0
    dlon = side_m / (111_320.0 * math.cos(math.radians(lat0)))
    ring = [[lon0, lat0], [lon0 + dlon, lat0], [lon0 + dlon, lat0 + dlat], [lon0, lat0 + dlat],
            [lon0, lat0]]
    path.write_text(json.dumps({"type": "Polygon", "coordinates": [ring]}))
    return str(path)


# child: fly in a fresh process and report its own children's peak RSS (KiB on Linux), so that
# nothing else this test process ran counts
_MEASURE = """
import resource, subprocess, sys
r = subprocess.run([sys.executable, "-m", "ag_uav.cli", *sys.argv[1:]], capture_output=True,
                   text=True)
sys.stderr.write(r.stderr)
print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
"""


@pytest.mark.skipif(sys.platform != "linux", reason="ru_maxrss in KiB is Linux's")
def test_10km_field_flies_its_max_time_in_bounded_memory(tmp_path):
    """A 10 km × 10 km field (16,700 km of coverage path, > 900 h of flight) with
    sim.max_time_s = 30: before the plan was cut at its head this grew past 23 GB and was
    OOM-killed; now it flies its 30 s, says why before and after, in a few hundred MB."""
    field = square_field(tmp_path / "sq10km.geojson", 10_000.0)
    r = subprocess.run([sys.executable, "-c", _MEASURE, "fly", "--no-render", "--no-log", "-q",
                        "--out", str(tmp_path), "--run-id", "big", "--set",
                        f'mission.field="{field}"', "--set", "sim.max_time_s=30",
                        "--set", "mission.swath_m=6", "--set", "mission.headland_m=6",
                        "--set", "mission.direction_deg=0"],
                       capture_output=True, text=True, timeout=600)
    rc, maxrss_kib = (int(v) for v in r.stdout.split()[-2:])
    assert rc == 0, r.stderr
    assert maxrss_kib < 1.5 * 2**20, f"peak RSS {maxrss_kib / 2**10:.0f} MB"
    notice = [ln for ln in r.stderr.splitlines() if "sim.max_time_s = 30 s" in ln]
    assert len(notice) == 1 and "the plan needs at least" in notice[0]
    summ = json.loads((tmp_path / "big" / "summary.json").read_text())
    assert summ["sim_time_s"] == pytest.approx(30.0)
    assert summ["completed"] is False
    assert summ["incomplete_reason"].startswith("cut by sim.max_time_s = 30 s after 0 of 1666")
    assert "km of path" in summ["incomplete_reason"]
    assert summ["planned_to_m"] < 400.0 < 16e6 < summ["planned_path_length_m"]


@pytest.mark.parametrize("budget, what", [(1, "the plan"), (64, "the reference")])
def test_memory_budget_refuses_before_flying_one_line_exit_2(tmp_path, capsys, budget, what):
    """The default mission at 6 m lanes needs ~48,500 control ticks (~71 MB of tables at 1.5 KB a
    tick): 1 MB is refused on the plan's lower bound (394 s at cruise speed, before the
    reference is built), 64 MB on the reference's duration (485 s); planned on the flown wind
    (a drawn forecast moves the legs and the plan's length)."""
    six = {"mission.swath_m": 6.0, "mission.headland_m": 6.0}
    rc = main(["fly", "--no-render", "--no-log", "-q", "--out", str(tmp_path), "--set",
               f"sim.memory_budget_mb={budget}", "--set", "mission.swath_m=6", "--set",
               "mission.headland_m=6", "--set", "forecast.speed_sigma_mps=0", "--set",
               "forecast.direction_sigma_deg=0"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1, err
    assert err[0].startswith(f"ag-uav: config error: sim.memory_budget_mb = {budget}: {what} "
                             "needs about")
    assert "raise sim.memory_budget_mb or lower sim.max_time_s" in err[0]
    assert not [f for f in tmp_path.rglob("*") if f.is_file()]  # nothing flown, nothing written
    # a short enough flight fits the same budget
    cfg = load_config(None, {"sim.memory_budget_mb": 64.0, "sim.max_time_s": 300.0, **six})
    assert mission_setup(cfg)[2].duration > 300.0


@pytest.mark.parametrize("value", [0, -5.0, "lots"])
def test_memory_budget_key_is_validated(value):
    with pytest.raises(ConfigError, match="sim.memory_budget_mb"):
        load_config(None, {"sim.memory_budget_mb": value})


@pytest.mark.parametrize("field, overrides, horizons", [
    ("default", {}, (10.0, 40.0, 100.0)),
    ("default", {"spray.tank_l": 0.5}, (40.0, 100.0)),         # sorties inside the horizon
    ("hole", {"battery.capacity_wh": 40.0}, (100.0,)),
    ("l-shape", {"mission.speed_mps": 12.0}, (40.0,)),
    ("default", {"spray.enabled": False}, (300.0,)),
])
def test_cut_plan_flies_the_same_reference_up_to_the_horizon(field, overrides, horizons):
    """The head of the plan gives, tick for tick up to the horizon, bit for bit the reference
    (and the sortie plan) of the whole plan."""
    cfg = load_config(None, {"mission.field": field, **overrides})
    plan = build_plan(cfg, build_field(cfg))
    full = build_reference(cfg, plan)
    for h in horizons:
        cut = build_reference(cfg, plan, horizon_s=h)
        assert cut.plan_cut is not None and cut.plan_cut.path_m == pytest.approx(plan.length)
        assert cut.plan_cut.planned_m == pytest.approx(reach_m(cfg, h))
        assert h < cut.duration < full.duration
        t = np.arange(int(math.ceil(h * cfg.sim.control_hz))) / cfg.sim.control_hz
        a, b = full.sample_all(t), cut.sample_all(t)
        for k in ("pos", "vel", "acc", "yaw", "yaw_rate", "spray", "seg"):
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"{k} at horizon {h}")
    assert build_reference(cfg, plan, horizon_s=full.duration + 1.0).plan_cut is None


def test_plan_head():
    cfg = load_config(None)
    plan = build_plan(cfg, build_field(cfg))
    head = plan.head(500.0)
    assert head.length == pytest.approx(500.0, abs=1e-9)
    assert head.meta["head_of_m"] == pytest.approx(plan.length)
    n = len(head.segments)
    for a, b in zip(head.segments[:-1], plan.segments[:n - 1], strict=True):
        assert a is b
    last, orig = head.segments[-1], plan.segments[n - 1]
    assert (last.kind, last.spray) == (orig.kind, orig.spray)
    np.testing.assert_array_equal(last.points[:-1], orig.points[:len(last.points) - 1])
    assert plan.head(plan.length + 1.0) is plan
