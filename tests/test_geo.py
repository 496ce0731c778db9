"""The run's geodetic origin and the log's geographic topics (ag_uav.record.geo): LocationFix of
the true position, the estimate and the GNSS fixes; GeoJSON of the field, plan, sprayed area and
dose; the Map panel of the layout; ``show``'s origin and bounds; the origin's config keys."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

import ag_uav
from ag_uav.config import ConfigError
from ag_uav.record.geo import DOSE_BANDS, dose_bands, fix_color
from ag_uav.record.runlog import RunLog
from ag_uav.record.synthetic import synthetic_run
from ag_uav.world.field import (
    DEFAULT_ORIGIN,
    enu_to_geodetic,
    enu_to_lonlat,
    load_field,
    lonlat_to_enu,
)
from ag_uav.world.mission import build_field

GEO_JSON_TOPICS = ("/geo/field", "/geo/plan", "/geo/sprayed", "/geo/dose")


def _messages(path, topics):
    """{topic: [(log_time ns, decoded message), ...]} of ``topics``; and the metadata."""
    out: dict[str, list] = {t: [] for t in topics}
    with open(path, "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, ch, msg, dec in r.iter_decoded_messages(topics=list(topics)):
            out[ch.topic].append((msg.log_time, dec))
        meta = {m.name: dict(m.metadata) for m in r.iter_metadata()}
    return out, meta


# --------------------------------------------------------------------------------------------
# the projection
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("origin", [DEFAULT_ORIGIN, (-35.31, 149.12, 580.0),
                                    (64.1, 179.999, 0.0), (0.0, -60.0, -20.0)])
def test_enu_and_geodetic_round_trip_under_a_micrometre(origin):
    rng = np.random.default_rng(3)
    enu = rng.uniform([-5000, -5000, -30], [5000, 5000, 200], (2000, 3))
    lon, lat, h = enu_to_geodetic(enu[:, 0], enu[:, 1], origin, enu[:, 2])
    back = lonlat_to_enu(lon, lat, origin, h)
    assert np.abs(back - enu).max() < 1e-6
    lon2, lat2 = enu_to_lonlat(enu[:, 0], enu[:, 1], origin, enu[:, 2])
    assert np.array_equal(lon2, lon) and np.array_equal(lat2, lat)
    # the origin itself
    o = enu_to_geodetic(0.0, 0.0, origin)
    assert abs(o[0] - origin[1]) < 1e-12 and abs(o[1] - origin[0]) < 1e-12
    assert abs(o[2] - origin[2]) < 1e-6


# --------------------------------------------------------------------------------------------
# a real flight over a lon/lat field
# --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """The ``hole`` field (a lon/lat GeoJSON file with a hole) flown for 30 s with the full
    log, the INS bank in the loop, an RTK receiver with fix types and false fixes."""
    from ag_uav.jobs.run import fly

    out = tmp_path_factory.mktemp("geo")
    cfg = ag_uav.load_config(None, {"mission.field": "hole", "sim.max_time_s": 30.0,
                                    "log.render": False})
    res, d = fly(cfg, out_root=out, run_id="hole")
    topics = ("/drone/pose", "/drone/pose_est", "/gps", "/dose", "/geo/true", "/geo/est",
              "/geo/gnss", *GEO_JSON_TOPICS)
    msgs, meta = _messages(d / "run.mcap", topics)
    return cfg, res, d, msgs, meta


def _lla(msgs):
    return {tn: (m.latitude, m.longitude, m.altitude) for tn, m in msgs}


def _pos(msgs):
    return {tn: (m.pose.position.x, m.pose.position.y, m.pose.position.z) for tn, m in msgs}


@pytest.mark.parametrize("fix,pose", [("/geo/true", "/drone/pose"),
                                      ("/geo/est", "/drone/pose_est"),
                                      ("/geo/gnss", "/gps")])
def test_location_fixes_map_back_onto_the_logged_enu_positions(flight, fix, pose):
    """lat/lon (with the altitude) of every LocationFix, converted back to local metres about
    the run's origin, lands within 1 mm of the ENU position logged at the same time."""
    cfg, _, _, msgs, meta = flight
    origin = tuple(float(meta["geo"][k]) for k in ("origin_lat_deg", "origin_lon_deg",
                                                   "origin_alt_m"))
    assert origin == build_field(cfg).origin  # the field file's own origin
    lla, enu = _lla(msgs[fix]), _pos(msgs[pose])
    common = sorted(set(lla) & set(enu))
    assert len(common) == len(lla) > 20
    a = np.array([lla[t] for t in common])
    back = lonlat_to_enu(a[:, 1], a[:, 0], origin, a[:, 2])
    err = np.abs(back - np.array([enu[t] for t in common])).max()
    print(f"{fix}: {len(common)} fixes, largest difference {err:.2e} m")
    assert err < 1e-3


def test_the_map_rates_and_the_gnss_report(flight):
    _, res, _, msgs, _ = flight
    t = np.array([tn for tn, _ in msgs["/geo/true"]]) * 1e-9
    assert np.allclose(np.diff(t), 0.2, atol=1e-6)  # 5 Hz, every other pose
    assert len(msgs["/geo/gnss"]) == len(msgs["/gps"]) == res.summary["gps_fixes"]
    types = res.summary["gps_fix_types"]
    seen = {}
    for _, m in msgs["/geo/gnss"]:
        kv = {p.key: p.value for p in m.metadata}
        assert kv["fix_type"] in types
        assert m.position_covariance_type == 2  # DIAGONAL_KNOWN
        c = np.array(m.position_covariance).reshape(3, 3)
        assert np.all(np.diag(c) > 0) and np.count_nonzero(c - np.diag(np.diag(c))) == 0
        assert np.allclose((m.color.r, m.color.g, m.color.b, m.color.a),
                           fix_color(kv["fix_type"]))
        seen[kv["fix_type"]] = seen.get(kv["fix_type"], 0) + 1
    assert sum(seen.values()) == len(msgs["/gps"])


def _rings(geom: dict) -> list[list]:
    if geom["type"] == "Polygon":
        return [geom["coordinates"]]
    if geom["type"] == "MultiPolygon":
        return geom["coordinates"]
    return []


def _check_geojson(text: str, origin) -> list[dict]:
    """RFC 7946 checks: a FeatureCollection of Features; [lon, lat] positions near the origin;
    closed rings of >= 4 positions, exteriors counter-clockwise, holes clockwise; valid
    polygons (shapely).  Returns the features."""
    gj = json.loads(text)
    assert gj["type"] == "FeatureCollection"
    for f in gj["features"]:
        assert f["type"] == "Feature" and isinstance(f["properties"]["name"], str)
        geom = f["geometry"]
        pts = np.array([p for poly in _rings(geom) for ring in poly for p in ring]
                       or geom["coordinates"])
        assert pts.shape[1] == 2
        assert np.abs(pts[:, 0] - origin[1]).max() < 0.01  # lon first
        assert np.abs(pts[:, 1] - origin[0]).max() < 0.01
        for poly in _rings(geom):
            for k, ring in enumerate(poly):
                assert len(ring) >= 4 and ring[0] == ring[-1]
                assert shapely.LinearRing(ring).is_ccw == (k == 0)
        if _rings(geom):
            assert shapely.geometry.shape(geom).is_valid
    return gj["features"]


def test_geojson_messages_are_valid_and_close_their_rings(flight):
    cfg, res, _, msgs, meta = flight
    origin = build_field(cfg).origin
    for topic in GEO_JSON_TOPICS:
        assert msgs[topic], topic
        for _, m in msgs[topic]:
            _check_geojson(m.geojson, origin)
    # the field: its hole kept, its area as flown (projected back onto the local plane)
    fld = build_field(cfg)
    (feat,) = json.loads(msgs["/geo/field"][0][1].geojson)["features"]
    poly = feat["geometry"]["coordinates"]
    assert len(poly) == 1 + len(fld.holes) == 2

    def local(ring):
        a = np.array(ring)
        return lonlat_to_enu(a[:, 0], a[:, 1], origin, origin[2])[:, :2]

    back = shapely.Polygon(local(poly[0]), [local(r) for r in poly[1:]])
    assert abs(back.area - fld.area) < 1e-3
    assert back.symmetric_difference(fld.polygon).area < 1e-3
    # the plan: one LineString per segment, its first position on the plan's first point
    from ag_uav.engine.missions import build_plan

    plan = build_plan(cfg, fld)
    feats = json.loads(msgs["/geo/plan"][0][1].geojson)["features"]
    assert len(feats) == len([s for s in plan.segments if len(s.points) >= 2])
    first = local([feats[0]["geometry"]["coordinates"][0]])[0]
    assert np.hypot(*(first - np.asarray(plan.segments[0].points)[0, :2])) < 2e-3
    # the sprayed area: as large as the run's summary says (the same footprint)
    (sp,) = json.loads(msgs["/geo/sprayed"][-1][1].geojson)["features"]
    area = sum(shapely.Polygon(local(p[0]), [local(r) for r in p[1:]]).area
               for p in _rings(sp["geometry"]))
    assert abs(area - res.summary["sprayed_area_m2"]) < 0.01 * res.summary["sprayed_area_m2"]
    # the dose: one /dose map in three (15 s of 5 s) and the last one, as bands
    t_geo, t_dose = [t for t, _ in msgs["/geo/dose"]], [t for t, _ in msgs["/dose"]]
    assert t_geo == t_dose[:-1:3] + t_dose[-1:] and len(t_geo) == 3
    last = json.loads(msgs["/geo/dose"][-1][1].geojson)["features"]
    names = {b[2] for b in DOSE_BANDS}
    assert last and all(f["properties"]["name"].split(":")[0][5:] in names for f in last)


def test_dose_bands_follow_the_dose(tmp_path):
    """A block of cells on target inside a one-cell ring at half the target: the on-target band
    reaches 0.4 of a cell beyond the block's outer cell centres (the 0.8 level, interpolating
    from 1.0 to 0.5 of the target), less its cut corners; the under-dosed band lies outside it;
    nothing is over-dosed."""
    dose = np.zeros((30, 40))
    dose[10:20, 10:30] = 2.0  # L/ha: target 2
    dose[9, 9:31] = dose[20, 9:31] = dose[10:20, 9] = dose[10:20, 30] = 1.0
    cell, out = dose_bands(5.0, -3.0, 0.5, dose, 2.0, simplify=0.0)
    assert cell == 0.5
    bands = {name: shapely.MultiPolygon([(p[0], p[1:]) for p in polys])
             for name, _, polys, _ in out}
    assert all(abs(bands[name].area - area) < 1e-9 for name, _, _, area in out)
    on, under = bands[DOSE_BANDS[1][2]], bands[DOSE_BANDS[0][2]]
    assert DOSE_BANDS[2][2] not in bands
    inner = shapely.box(5.0 + 10.5 * 0.5, -3.0 + 10.5 * 0.5, 5.0 + 29.5 * 0.5, -3.0 + 19.5 * 0.5)
    reach = 0.4 * 0.5
    assert on.contains(inner.buffer(0.5 * reach))
    full = inner.buffer(reach, join_style="mitre").area
    assert full - 4 * reach * reach / 2 - 1e-9 <= on.area <= full + 1e-9
    assert under.area > 0 and on.intersection(under).area < 1e-9
    assert under.disjoint(inner.buffer(0.5 * reach))
    # simplified (the default: half a cell), each band stays within that of the exact one
    simp = {name: shapely.MultiPolygon([(p[0], p[1:]) for p in polys])
            for name, _, polys, _ in dose_bands(5.0, -3.0, 0.5, dose, 2.0)[1]}
    assert simp.keys() == bands.keys()
    assert all(simp[k].hausdorff_distance(bands[k]) <= 0.25 + 1e-9 for k in bands)


def test_a_ragged_dose_map_is_coarsened_to_bound_the_message():
    """Noise around the band limits makes many small contours: the map is block-averaged until
    its bands hold at most ``max_points`` vertices, the banded area kept to a few per cent."""
    rng = np.random.default_rng(0)
    dose = np.zeros((136, 140))
    for j in range(10, 120, 6):  # sprayed strips whose dose straddles 0.8 and 1.2 of target
        dose[j:j + 5, 10:125] = rng.uniform(0.6, 1.4, (5, 115))

    def n_vertices(out):
        return sum(len(r) for _, _, polys, _ in out for p in polys for r in p)

    fine_cell, fine = dose_bands(-10.0, -10.0, 1.0, dose, 1.0, max_points=10**9)
    cell, out = dose_bands(-10.0, -10.0, 1.0, dose, 1.0, max_points=2000)
    assert fine_cell == 1.0 and n_vertices(fine) > 2000 >= n_vertices(out) and cell > 1.0
    total = sum(a for *_, a in out)
    assert abs(total - sum(a for *_, a in fine)) < 0.1 * total
    raw = dose_bands(-10.0, -10.0, 1.0, dose, 1.0, max_points=10**9, simplify=0.0)[1]
    assert n_vertices(raw) > 2 * n_vertices(fine)  # the simplification's share


# --------------------------------------------------------------------------------------------
# the log and the layout
# --------------------------------------------------------------------------------------------

def test_the_light_set_keeps_the_map_topics_at_one_hertz(tmp_path):
    counts = {}
    for channels in ("full", "light"):
        path = tmp_path / f"{channels}.mcap"
        with RunLog(path, channels=channels, metadata={}, config_toml="") as log:
            synthetic_run(log, 20.0, origin=DEFAULT_ORIGIN)
            counts[channels] = log.counts
        with open(path, "rb") as f:
            s = make_reader(f).get_summary()
            assert {s.channels[c].topic: n for c, n in
                    s.statistics.channel_message_counts.items()} == counts[channels]
    full, light = counts["full"], counts["light"]
    assert full["/geo/true"] == full["/geo/est"] == 100 and full["/geo/gnss"] == 200
    assert light["/geo/true"] == light["/geo/est"] == light["/geo/gnss"] == 20
    assert light["/geo/field"] == light["/geo/plan"] == 1


def test_a_log_without_the_geo_group_or_an_estimate_names_no_such_topic(tmp_path):
    with RunLog(tmp_path / "a" / "run.mcap", channels="full", rates={"geo": 0}, metadata={},
                config_toml="") as log:
        synthetic_run(log, 3.0, origin=DEFAULT_ORIGIN)
    assert not any(t.startswith("/geo/") for t in log.counts)
    layout = json.loads((tmp_path / "a" / "layout.json").read_text())
    assert not any(p.startswith("Map!") for p in layout["configById"])
    with RunLog(tmp_path / "b" / "run.mcap", channels="full", metadata={},
                config_toml="") as log:
        synthetic_run(log, 3.0, estimators=(), origin=DEFAULT_ORIGIN)
    assert "/geo/true" in log.counts and "/geo/est" not in log.counts
    mp = json.loads((tmp_path / "b" / "layout.json").read_text())["configById"]["Map!aguavmap"]
    named = {*mp["topicConfig"], *mp["topicColors"], mp["followTopic"]}
    assert named == set(log.counts) & named and "/geo/est" not in named


def test_show_prints_the_origin_and_the_flight_bounds(flight):
    from ag_uav.analysis.viewing import show

    cfg, _, d, msgs, _ = flight
    text = show(d)
    lat0, lon0, h0 = build_field(cfg).origin
    assert f"origin: lat {lat0:.7f}, lon {lon0:.7f} (WGS-84 degrees), height {h0:.1f} m" in text
    lla = np.array(list(_lla(msgs["/geo/true"]).values()))
    assert (f"flight bounds: lat {lla[:, 0].min():.7f} .. {lla[:, 0].max():.7f}, lon "
            f"{lla[:, 1].min():.7f} .. {lla[:, 1].max():.7f}") in text


# --------------------------------------------------------------------------------------------
# the origin's config keys
# --------------------------------------------------------------------------------------------

def test_the_origin_of_each_kind_of_field():
    assert build_field(ag_uav.load_config(None, {})).origin == DEFAULT_ORIGIN
    two = load_field("two-part")
    assert build_field(ag_uav.load_config(None, {"mission.field": "two-part"})).origin == \
        two.origin
    over = {"mission.field": "two-part", "mission.origin_lat_deg": 46.7322,
            "mission.origin_lon_deg": -117.0071, "mission.origin_alt_m": 780.0}
    moved = build_field(ag_uav.load_config(None, over))
    assert moved.origin == (46.7322, -117.0071, 780.0)
    # projected about the origin given, at its height: the same ground, shifted in local
    # metres and 780 m further from the Earth's centre (areas grow by 2h/R = 2.45e-4)
    assert abs(moved.area / two.area - 1.0 - 2 * 780.0 / 6.378e6) < 2e-6
    lon, lat = enu_to_lonlat(*moved.exterior[:-1].T, moved.origin)
    lon2, lat2 = enu_to_lonlat(*two.exterior[:-1].T, two.origin)
    assert np.abs(lon - lon2).max() < 1e-9 and np.abs(lat - lat2).max() < 1e-9
    # the local default field keeps its metres, only its origin moves
    d = build_field(ag_uav.load_config(None, {"mission.origin_lat_deg": -35.3,
                                              "mission.origin_lon_deg": 149.1}))
    assert d.origin == (-35.3, 149.1, DEFAULT_ORIGIN[2])
    assert d.bounds == build_field(ag_uav.load_config(None, {})).bounds


@pytest.mark.parametrize("over,msg", [
    ({"mission.origin_lat_deg": 90}, "mission.origin_lat_deg = 90.0: must be < 90"),
    ({"mission.origin_lon_deg": "east"}, "mission.origin_lon_deg = \"east\": expected a number "
                                         "or \"auto\""),
    ({"mission.origin_alt_m": 1e5}, "mission.origin_alt_m = 100000.0: must be <= 9000"),
    ({"mission.origin_lat_deg": 46.7}, "mission.origin_lat_deg = 46.7: must come with "
                                       "mission.origin_lon_deg"),
])
def test_bad_origin_keys_are_refused_in_one_line(over, msg):
    with pytest.raises(ConfigError) as e:
        ag_uav.load_config(None, over)
    assert str(e.value).startswith(msg) and "\n" not in str(e.value)


def test_an_origin_far_from_a_file_field_is_refused():
    cfg = ag_uav.load_config(None, {"mission.field": "hole", "mission.origin_lat_deg": 47.0,
                                    "mission.origin_lon_deg": -117.0})
    with pytest.raises(ConfigError, match=r"mission.origin_lat_deg = 47.0: the field reaches "
                                          r"30\.\d km from the origin .*within 20 km"):
        build_field(cfg)
    near = build_field(ag_uav.load_config(None, {  # ~8 km north: allowed
        "mission.field": "hole", "mission.origin_lat_deg": 46.8,
        "mission.origin_lon_deg": -117.02}))
    assert 7000 < -near.bounds[1] < 8000


def test_a_bad_origin_on_the_command_line_exits_2(capsys):
    from ag_uav.cli import main

    assert main(["config", "--set", "mission.origin_lat_deg=-91"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "ag-uav: config error: mission.origin_lat_deg = -91.0: must be > -90"]
