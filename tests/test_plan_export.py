"""Plans out of the simulator: `ag-uav plan` writes GeoJSON, KML and QGroundControl .plan files;
each is read back (JSON / an XML parser) and its points checked against the plan."""

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString

import ag_uav
from ag_uav.analysis.coverage import spray_coverage
from ag_uav.cli import main
from ag_uav.world.field import Field, enu_to_lonlat, load_field, lonlat_to_enu
from ag_uav.world.mission import build_plan
from ag_uav.world.plan import plan_coverage
from ag_uav.world.plan_export import plan_waypoints, write_plan

KML = "{http://www.opengis.net/kml/2.2}"
ITEM_KEYS = {"autoContinue", "command", "doJumpId", "frame", "params", "type"}


@pytest.fixture(scope="module", params=["two-part", "hole"])
def planned(request):
    cfg = ag_uav.load_config(None, {"mission.field": request.param})
    fld = load_field(request.param)
    return cfg, fld, build_plan(cfg, fld)


def enu(fld, lon, lat):
    return lonlat_to_enu(np.asarray(lon), np.asarray(lat), fld.origin)[..., :2]


def assert_has_point(xy, p, tol=0.01):
    assert np.min(np.hypot(*(np.asarray(xy) - p).T)) < tol, p


def test_qgc_plan_structure_and_points(planned, tmp_path, capsys):
    cfg, fld, plan = planned
    out = tmp_path / "mission.plan"
    # no valve delay: the commands sit on the sprayed edges (the lead has its own test)
    assert main(["plan", cfg.mission.field, "-o", str(out), "--set",
                 "spray.nozzle_on_delay_s=0"]) == 0
    assert "QGroundControl plan" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    # QGroundControl's plan file: top level, mission, geoFence, rallyPoints
    assert doc["fileType"] == "Plan" and doc["version"] == 1
    assert isinstance(doc["groundStation"], str)
    m = doc["mission"]
    assert m["version"] == 2 and m["firmwareType"] == 3 and m["vehicleType"] == 2
    assert m["cruiseSpeed"] == m["hoverSpeed"] == cfg.mission.speed_mps
    assert len(m["plannedHomePosition"]) == 3
    assert doc["geoFence"] == {"version": 2, "circles": [], "polygons": []}
    assert doc["rallyPoints"] == {"version": 2, "points": []}
    items = m["items"]
    for k, it in enumerate(items, start=1):
        assert set(it) == ITEM_KEYS and it["type"] == "SimpleItem" and it["autoContinue"] is True
        assert it["doJumpId"] == k and len(it["params"]) == 7
    assert items[0]["command"] == 22 and items[0]["params"][6] == cfg.mission.altitude_m
    assert items[1]["command"] == 178 and items[1]["params"][:2] == [1, cfg.mission.speed_mps]
    wps = [it for it in items if it["command"] == 16]
    assert len(wps) >= 10
    assert all(it["frame"] == 3 and it["params"][6] == cfg.mission.altitude_m for it in wps)
    lat = np.array([it["params"][4] for it in wps])
    lon = np.array([it["params"][5] for it in wps])
    # latitudes (and longitudes) lie in the field: its bounds, and its hull grown by a swath
    outer = np.concatenate([o for o, _ in fld.rings()])
    flat = np.stack(enu_to_lonlat(outer[:, 0], outer[:, 1], fld.origin), axis=1)
    assert flat[:, 1].min() <= lat.min() and lat.max() <= flat[:, 1].max()
    assert flat[:, 0].min() <= lon.min() and lon.max() <= flat[:, 0].max()
    xy = enu(fld, lon, lat)
    hull = fld.polygon.convex_hull.buffer(plan.swath)
    assert shapely.contains_xy(hull, xy[:, 0], xy[:, 1]).all()
    # every sweep-leg end is a waypoint (within 1 cm)
    for s in plan.segments:
        if s.kind == "leg":
            assert_has_point(xy, s.points[0])
            assert_has_point(xy, s.points[-1])
    # nozzles: DO_SPRAYER on/off alternate; the stretches between them are the plan's spray tracks
    spray = [(k, it["params"][0]) for k, it in enumerate(items) if it["command"] == 216]
    assert [v for _, v in spray] == [1, 0] * len(plan.spray_tracks())
    runs, cur, on = [], [], False
    for it in items[2:]:
        if it["command"] == 16:
            p = enu(fld, it["params"][5], it["params"][4])
            if on:
                cur.append(p)
            last = p
        elif it["command"] == 216:
            on = it["params"][0] == 1
            if on:
                cur = [last]
            else:
                runs.append(np.array(cur))
    nominal = plan.spray_tracks()
    assert len(runs) == len(nominal)
    for r, t in zip(runs, nominal, strict=True):
        assert np.hypot(*(r[0] - t[0])) < 0.01 and np.hypot(*(r[-1] - t[-1])) < 0.01
    # the exported sprayed stretches cover what the plan covers
    c_plan = spray_coverage(fld, nominal, plan.swath)[0]
    c_file = spray_coverage(fld, runs, plan.swath)[0]
    assert c_file == pytest.approx(c_plan, abs=2e-3)


def test_kml_parses_and_matches_plan(planned, tmp_path):
    cfg, fld, plan = planned
    out = tmp_path / "plan.kml"
    assert main(["plan", cfg.mission.field, "-o", str(out)]) == 0
    root = ET.parse(out).getroot()
    assert root.tag == f"{KML}kml"
    doc = root.find(f"{KML}Document")
    folders = {f.findtext(f"{KML}name"): f for f in doc.findall(f"{KML}Folder")}
    path_pms = folders["path"].findall(f"{KML}Placemark")
    assert len(path_pms) == len(plan.segments)
    for pm, s in zip(path_pms, plan.segments, strict=True):
        ls = pm.find(f"{KML}LineString")
        assert ls.findtext(f"{KML}altitudeMode") == "relativeToGround"
        tup = [[float(v) for v in t.split(",")] for t in ls.findtext(f"{KML}coordinates").split()]
        a = np.array(tup)
        assert np.all(a[:, 2] == cfg.mission.altitude_m)
        xy = enu(fld, a[:, 0], a[:, 1])
        assert np.hypot(*(xy[0] - s.points[0])) < 0.01 and np.hypot(*(xy[-1] - s.points[-1])) < 0.01
        assert pm.findtext(f"{KML}styleUrl") == ("#spray" if s.spray else "#off")
        # thinning keeps the line within the tolerance of the plan's polyline
        assert LineString(xy).hausdorff_distance(LineString(s.points)) < 0.2 + 1e-3
    noz = folders["nozzles"].findall(f"{KML}Placemark")
    names = [p.findtext(f"{KML}name") for p in noz]
    assert names == ["spray on", "spray off"] * len(plan.spray_tracks())
    # the field placemark reads back as the same field
    back = Field.from_kml(out, origin=fld.origin)
    assert len(back.parts) == len(fld.parts)
    assert back.polygon.symmetric_difference(fld.polygon).area < 1e-2


def test_geojson_reads_back(planned, tmp_path):
    cfg, fld, plan = planned
    out = tmp_path / "plan.geojson"
    assert main(["plan", cfg.mission.field, "-o", str(out)]) == 0
    gj = json.loads(out.read_text())
    assert gj["type"] == "FeatureCollection"
    roles = [f["properties"]["role"] for f in gj["features"]]
    assert roles.count("field") == 1
    paths = [f for f in gj["features"] if f["properties"]["role"] == "path"]
    assert len(paths) == len(plan.segments)
    for f, s in zip(paths, plan.segments, strict=True):
        assert f["geometry"]["type"] == "LineString"
        assert f["properties"]["spray"] == s.spray and f["properties"]["kind"] == s.kind
        a = np.asarray(f["geometry"]["coordinates"])
        xy = enu(fld, a[:, 0], a[:, 1])
        assert np.hypot(*(xy[0] - s.points[0])) < 0.01 and np.hypot(*(xy[-1] - s.points[-1])) < 0.01
    assert roles.count("spray_on") == roles.count("spray_off") == len(plan.spray_tracks())
    back = Field.from_geojson(out, origin=fld.origin)  # the one polygon feature: the field
    assert back.polygon.symmetric_difference(fld.polygon).area < 1e-2


def test_waypoints_spray_flags_follow_the_segments():
    fld = load_field("two-part")
    plan = plan_coverage(fld)
    wps = plan_waypoints(plan)
    assert wps[0].spray and wps[0].event == "spray_on"
    assert wps[-1].kind == "end" and not wps[-1].spray and wps[-1].event == "spray_off"
    transits = [w for w in wps if w.kind == "transit"]
    assert transits and not any(w.spray for w in transits)
    # consecutive waypoints are distinct and the spray flag only flips at an event
    for a, b in zip(wps[:-1], wps[1:], strict=True):
        assert np.hypot(b.x - a.x, b.y - a.y) > 1e-6
        assert (a.spray != b.spray) == (b.event is not None)


def _plan_lats(path) -> list[float]:
    items = json.loads(path.read_text())["mission"]["items"]
    return [it["params"][4] for it in items if it["command"] == 16]


def test_local_field_takes_the_mission_origin(tmp_path, capsys):
    """The default field (local metres) lies at the run's origin: ``mission.origin_*``, by
    default DEFAULT_ORIGIN; ``--origin`` overrides it for the export."""
    out = tmp_path / "d.plan"
    assert main(["plan", "default", "-o", str(out)]) == 0
    lat = _plan_lats(out)  # the field reaches ~100 m north of DEFAULT_ORIGIN's 46.725
    assert len(lat) >= 10 and all(46.7250 < v < 46.7260 for v in lat)
    assert main(["plan", "default", "--set", "mission.origin_lat_deg=-35.3",
                 "--set", "mission.origin_lon_deg=149.1", "-o", str(out)]) == 0
    assert all(-35.3 < v < -35.299 for v in _plan_lats(out))
    assert main(["plan", "default", "--origin", "46.73,-117.0", "-o", str(out)]) == 0
    lat = _plan_lats(out)
    assert len(lat) >= 10 and all(46.729 < v < 46.732 for v in lat)
    assert main(["plan", "default", "--origin", "north", "-o", str(out)]) == 2
    assert main(["plan", "hole", "-o", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "allowed: .geojson, .json, .kml, .plan" in err[-1]


def test_write_plan_rejects_unknown_suffix(tmp_path):
    plan = plan_coverage(load_field("two-part"))
    with pytest.raises(ValueError, match="unknown plan file type '.gpx'"):
        write_plan(plan, tmp_path / "a.gpx", altitude=3.0, speed=5.0)


def _path_s(wps) -> np.ndarray:
    xy = np.array([(w.x, w.y) for w in wps])
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])


@pytest.mark.parametrize("lead_on, lead_off", [(0.5, 0.0), (1.3, 2.0)])
def test_nozzle_commands_lead_the_sprayed_edges(lead_on, lead_off):
    """Each command sits its lead (v·d) of path before the edge the plan sprays from; the path
    itself is unchanged (the command waypoints are inserted on it)."""
    plan = plan_coverage(load_field("two-part"))
    base = plan_waypoints(plan)
    led = plan_waypoints(plan, lead_on_m=lead_on, lead_off_m=lead_off)
    s0, s1 = _path_s(base), _path_s(led)
    assert s1[-1] == pytest.approx(s0[-1], abs=1e-6)
    ev0 = [(w.event, s) for w, s in zip(base, s0, strict=True) if w.event]
    ev1 = [(w.event, s) for w, s in zip(led, s1, strict=True) if w.event]
    assert [e for e, _ in ev1] == [e for e, _ in ev0]
    for (e, a), (_, b) in zip(ev0, ev1, strict=True):
        want = min(lead_on if e == "spray_on" else lead_off, a)  # not before the path's start
        assert a - b == pytest.approx(want, abs=1e-6), e
    # the spray flag flips only at a command
    for a, b in zip(led[:-1], led[1:], strict=True):
        assert (a.spray != b.spray) == (b.event is not None)


def test_plan_cli_leads_by_the_configured_delay(tmp_path):
    out = tmp_path / "m.plan"
    assert main(["plan", "two-part", "-o", str(out), "--set", "spray.nozzle_on_delay_s=0.2"]) == 0
    fld = load_field("two-part")
    cfg = ag_uav.load_config(None, {"mission.field": "two-part", "spray.nozzle_on_delay_s": 0.2})
    tracks = build_plan(cfg, fld).spray_tracks()
    items = json.loads(out.read_text())["mission"]["items"]
    ons = [enu(fld, items[k - 1]["params"][5], items[k - 1]["params"][4])
           for k, it in enumerate(items) if it["command"] == 216 and it["params"][0] == 1]
    lead = cfg.mission.speed_mps * 0.2  # 1 m of path (a chord of a turn is at most that)
    assert len(ons) == len(tracks)
    for p, t in zip(ons[1:], tracks[1:], strict=True):  # the first starts the path
        assert 0.9 * lead < np.hypot(*(p - t[0])) < lead + 1e-3  # lon/lat round trip
