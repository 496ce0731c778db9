"""Chaos: fields where longitude wraps.  A field across the antimeridian gets its origin on the
field (not at the mean of +180 and -180, half the Earth away), its plans and map polygons are
cut at ±180° as RFC 7946 §3.1.9 asks, a field near a pole plans where it is and one around a
pole is refused with that reason, and a GeoJSON file written in local metres is refused with a
message that says so."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

import ag_uav
from ag_uav.cli import main
from ag_uav.record.geo import GeoFrame, dose_geojson, sprayed_geojson
from ag_uav.record.runlog import RunLog
from ag_uav.record.synthetic import synthetic_run
from ag_uav.world.field import Field, load_field, lonlat_to_enu
from ag_uav.world.geodesy import lonlat_centre, split_antimeridian
from ag_uav.world.mission import build_field

#: ~110 m × 67 m at latitude 10, across the antimeridian (the vertices at ±179.9995)
ACROSS = [[179.9995, 10.0], [-179.9995, 10.0], [-179.9995, 10.0006], [179.9995, 10.0006],
          [179.9995, 10.0]]


def _geojson(path: Path, ring: list[list[float]]) -> Path:
    path.write_text(json.dumps({"type": "Feature", "properties": {"name": path.stem},
                                "geometry": {"type": "Polygon", "coordinates": [ring]}}))
    return path


def _unwrap(lon: np.ndarray) -> np.ndarray:
    """Longitudes near ±180 as one run (179.9995 … 180.0005)."""
    return np.where(np.asarray(lon) < 0, np.asarray(lon) + 360.0, lon)


def _no_jump(ring) -> None:
    a = np.asarray(ring, dtype=float)
    assert np.all(np.abs(a[:, 0]) <= 180.0) and np.all(np.abs(np.diff(a[:, 0])) < 1.0), a


def _plan_lonlat(path: Path) -> np.ndarray:
    items = json.loads(path.read_text())["mission"]["items"]
    return np.array([(it["params"][5], it["params"][4]) for it in items if it["command"] == 16])


def test_a_field_across_the_antimeridian_plans_where_it_is(tmp_path, capsys):
    p = _geojson(tmp_path / "across.geojson", ACROSS)
    fld = build_field(ag_uav.load_config(None, {"mission.field": str(p)}))
    # the origin on the field (the plain mean of the degrees is lon 0: 19 600 km away)
    assert abs(fld.origin[0] - 10.0003) < 1e-6 and abs(abs(fld.origin[1]) - 180.0) < 1e-6
    assert abs(fld.area - 109.6 * 66.4) < 0.01 * fld.area
    out = tmp_path / "across.plan"
    assert main(["plan", str(p), "-o", str(out)]) == 0
    ll = _plan_lonlat(out)
    lon = _unwrap(ll[:, 0])
    assert len(ll) > 50
    assert lon.min() >= 179.9995 - 1e-9 and lon.max() <= 180.0005 + 1e-9
    assert ll[:, 1].min() >= 10.0 - 1e-9 and ll[:, 1].max() <= 10.0006 + 1e-9
    assert (ll[:, 0] > 0).any() and (ll[:, 0] < 0).any()  # both sides of the line are sprayed


def test_the_plan_geojson_is_cut_at_the_antimeridian(tmp_path):
    p = _geojson(tmp_path / "across.geojson", ACROSS)
    out = tmp_path / "across-plan.geojson"
    assert main(["plan", str(p), "-o", str(out)]) == 0
    feats = json.loads(out.read_text())["features"]
    field = feats[0]["geometry"]
    assert field["type"] == "MultiPolygon" and len(field["coordinates"]) == 2
    sides = []
    for poly in field["coordinates"]:
        _no_jump(poly[0])
        sides.append(np.sign(np.mean(np.asarray(poly[0])[:, 0])))
    assert sorted(sides) == [-1, 1]
    # the two pieces hold the whole field: their area back in the plane is the field's
    org = load_field(str(p)).origin
    area = sum(shapely.Polygon(lonlat_to_enu(*np.asarray(q[0]).T, org)[:, :2]).area
               for q in field["coordinates"])
    assert abs(area - load_field(str(p)).area) < 1e-3 * area
    lines = [f["geometry"] for f in feats if f["properties"].get("role") == "path"]
    assert any(g["type"] == "MultiLineString" for g in lines)
    for g in lines:
        for part in ([g["coordinates"]] if g["type"] == "LineString" else g["coordinates"]):
            _no_jump(part)


def test_the_plan_kml_and_the_field_geojson_are_cut_at_the_antimeridian(tmp_path):
    """The KML export and Field.to_geojson() cut at ±180° as the plan's GeoJSON does (before,
    their edges ran 360° the wrong way round the globe)."""
    import xml.etree.ElementTree as ET

    p = _geojson(tmp_path / "across.geojson", ACROSS)
    feat = load_field(str(p)).to_geojson()
    assert feat["geometry"]["type"] == "MultiPolygon" and len(feat["geometry"]["coordinates"]) == 2
    for poly in feat["geometry"]["coordinates"]:
        _no_jump(poly[0])
    out = tmp_path / "across.kml"
    assert main(["plan", str(p), "-o", str(out)]) == 0
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    root = ET.parse(out).getroot()

    def coords(el):
        text = el.find("k:coordinates", ns).text
        return [[float(v) for v in c.split(",")[:2]] for c in text.split()]

    rings = root.findall(".//k:LinearRing", ns)
    assert len(rings) == 2
    lines = root.findall(".//k:LineString", ns)
    assert len(lines) > sum(1 for _ in root.iterfind(".//k:Folder/k:Placemark/k:LineString", ns))
    for el in rings + lines:
        _no_jump(coords(el))


def _geo_messages(path: Path) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    with open(path, "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, ch, _, dec in r.iter_decoded_messages():
            if hasattr(dec, "geojson"):
                out.setdefault(ch.topic, []).append(json.loads(dec.geojson))
    return out


def test_the_map_topics_split_polygons_at_the_antimeridian(tmp_path):
    # the synthetic run's 60 m × 40 m field (a hole at x = 28-32 m) and lawnmower, from 45 m
    # west of ±180
    lon0 = 180.0 - 45.0 / (111_320.0 * np.cos(np.radians(10.0)))
    path = tmp_path / "run.mcap"
    with RunLog(path, channels="full", metadata={}, config_toml="") as log:
        synthetic_run(log, 20.0, origin=(10.0, lon0, 0.0))
    msgs = _geo_messages(path)
    assert {"/geo/field", "/geo/plan"} <= set(msgs)
    # the sprayed area and the dose bands, as the engine hands them to the log
    frame = GeoFrame((10.0, lon0, 0.0))
    msgs["/geo/sprayed"] = [json.loads(sprayed_geojson(frame, [shapely.box(5, 5, 55, 35)]))]
    dose = np.ones((40, 60))
    dose[10:20, 10:50] = 0.5
    msgs["/geo/dose"] = [json.loads(dose_geojson(frame, 0.5, 0.5, 1.0, dose, 1.0))]
    assert len(msgs["/geo/dose"][0]["features"]) == 2
    for topic in ("/geo/plan", "/geo/sprayed", "/geo/dose"):
        assert any(f["geometry"]["type"].startswith("Multi") for d in msgs[topic]
                   for f in d["features"]), topic
    (feat,) = msgs["/geo/field"][0]["features"]
    assert feat["geometry"]["type"] == "MultiPolygon"
    assert len(feat["geometry"]["coordinates"]) == 2  # two pieces, the hole kept on one
    assert sum(len(p) for p in feat["geometry"]["coordinates"]) == 3
    for docs in msgs.values():
        for doc in docs:
            for f in doc["features"]:
                g = f["geometry"]
                polys = ([g["coordinates"]] if g["type"] in ("Polygon", "LineString") else
                         g["coordinates"])
                for poly in polys:
                    for ring in (poly if g["type"].endswith("Polygon") else [poly]):
                        _no_jump(ring)
    # the field's area survives the cut: 60 m × 40 m less the 4 m × 4 m hole
    area = 0.0
    for poly in feat["geometry"]["coordinates"]:
        rings = [lonlat_to_enu(*np.asarray(r).T, (10.0, lon0, 0.0))[:, :2] for r in poly]
        area += shapely.Polygon(rings[0], rings[1:]).area
    assert abs(area - (60 * 40 - 16)) < 0.5


def test_split_antimeridian_leaves_other_geometry_alone():
    sq = shapely.Polygon([(10, 10), (10.001, 10), (10.001, 10.001), (10, 10.001)])
    assert split_antimeridian(sq) == [sq] and split_antimeridian(sq)[0] is sq
    # the automatic origin of a field away from ±180 is the plain mean, bit for bit
    lon, lat = np.array([-117.02, -117.01, -117.015]), np.array([46.73, 46.731, 46.735])
    assert lonlat_centre(lon, lat) == (float(lat.mean()), float(lon.mean()))


def test_a_field_near_the_pole_plans_where_it_is(tmp_path):
    # 60° of longitude at 89.999° N: some 110 m of ground; its longitudes span 60°
    ring = [[0.0, 89.999], [60.0, 89.999], [60.0, 89.9995], [0.0, 89.9995], [0.0, 89.999]]
    p = _geojson(tmp_path / "north.geojson", ring)
    out = tmp_path / "north.plan"
    assert main(["plan", str(p), "-o", str(out)]) == 0
    ll = _plan_lonlat(out)
    assert 0.0 < ll[:, 0].min() and ll[:, 0].max() < 60.0
    # every waypoint on the field (its edges are straight on the ground, so the chord of the
    # 89.9995° parallel comes 7 m nearer the pole than the parallel itself)
    fld = load_field(str(p))
    xy = lonlat_to_enu(ll[:, 0], ll[:, 1], fld.origin)[:, :2]
    assert shapely.contains_xy(fld.polygon.buffer(0.01), xy[:, 0], xy[:, 1]).all()
    assert 89.999 < ll[:, 1].min() and ll[:, 1].max() < 90.0 - 0.0005 * np.cos(np.radians(30))
    # across the antimeridian there too
    ring = [[170.0, 89.999], [-170.0, 89.999], [-170.0, 89.9995], [170.0, 89.9995],
            [170.0, 89.999]]
    fld = Field.from_geojson(_geojson(tmp_path / "north2.geojson", ring))
    assert abs(abs(fld.origin[1]) - 180.0) < 1e-6 and 89.999 < fld.origin[0] < 89.9995


@pytest.mark.parametrize(("ring", "words"), [
    # around the North pole: no lon/lat ring describes it
    ([[0.0, 89.999], [90.0, 89.999], [180.0, 89.999], [-90.0, 89.999], [0.0, 89.999]],
     ["around the North pole", "split the field"]),
    # local metres that read as degrees within range: a field 7 800 km wide
    ([[0.0, 0.0], [50.0, 0.0], [50.0, 80.0], [0.0, 80.0], [0.0, 0.0]],
     ["local metres", "spans 7", "RFC 7946"]),
    # local metres beyond the range of degrees (the built-in default field's outline)
    ([[0.0, 0.0], [112.0, 5.0], [116.0, 96.0], [-3.0, 90.0], [0.0, 0.0]],
     ["out of range", "local metres"]),
])
def test_fields_refused_with_the_true_reason(ring, words, tmp_path, capsys):
    p = _geojson(tmp_path / "bad.geojson", ring)
    assert main(["plan", str(p), "-o", str(tmp_path / "x.plan")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "origin_alt_m" not in err, err
    for w in words:
        assert w in err, (w, err)
