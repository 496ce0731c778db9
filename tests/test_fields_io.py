"""Fields as farmers keep them: MultiPolygon, Feature(Collection) selection, KML/KMZ, shapefile,
holes wound either way, bad files rejected in one line; the two-part field planned and flown."""

import json
import subprocess
import sys
import zipfile

import numpy as np
import pytest
import shapefile  # pyshp
import shapely
from shapely.geometry import LineString, Polygon

import ag_uav
from ag_uav.analysis.coverage import spray_coverage
from ag_uav.cli import main
from ag_uav.world.field import Field, enu_to_lonlat, load_field
from ag_uav.world.plan import plan_coverage

ORG = (46.7300, -117.0000, 0.0)


def ll(ring_xy, reverse=False):
    """Local-metre ring -> closed [[lon, lat], ...] about ORG."""
    r = list(ring_xy)[::-1] if reverse else list(ring_xy)
    r = r + [r[0]]
    lon, lat = enu_to_lonlat([p[0] for p in r], [p[1] for p in r], ORG)
    return [[float(a), float(b)] for a, b in zip(lon, lat, strict=True)]


SQ_A = [(0, 0), (40, 0), (40, 30), (0, 30)]            # 1200 m²
HOLE_A = [(10, 10), (20, 10), (20, 18), (10, 18)]      # 80 m²
SQ_B = [(80, 0), (110, 0), (110, 20), (80, 20)]        # 600 m²


def multipolygon(hole_reverse=False):
    return {"type": "MultiPolygon",
            "coordinates": [[ll(SQ_A), ll(HOLE_A, hole_reverse)], [ll(SQ_B)]]}


def collection():
    return {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": "North", "id": 7},
         "geometry": {"type": "Polygon", "coordinates": [ll(SQ_A)]}},
        {"type": "Feature", "properties": {"name": "South", "id": 8},
         "geometry": multipolygon()},
        {"type": "Feature", "properties": {"name": "gate"},
         "geometry": {"type": "Point", "coordinates": ll(SQ_A)[0]}},
    ]}


# ------------------------------------------------------------------------------------ GeoJSON
@pytest.mark.parametrize("hole_reverse", [False, True])
def test_multipolygon_keeps_every_part_and_hole_either_winding(hole_reverse):
    f = Field.from_geojson(multipolygon(hole_reverse))
    assert len(f.parts) == 2
    assert f.area == pytest.approx(1200 - 80 + 600, rel=1e-5)
    assert len(f.parts[0].interiors) + len(f.parts[1].interiors) == 1
    for p in f.parts:  # normalised: CCW boundary, CW holes
        assert p.exterior.is_ccw and all(not r.is_ccw for r in p.interiors)


def test_outer_ring_wound_clockwise_is_accepted():
    f = Field.from_geojson({"type": "Polygon",
                            "coordinates": [ll(SQ_A, reverse=True), ll(HOLE_A)]})
    assert f.area == pytest.approx(1200 - 80, rel=1e-5)


def test_feature_collection_pick_by_property(tmp_path):
    p = tmp_path / "farm.geojson"
    p.write_text(json.dumps(collection()))
    north = load_field(f"{p}#name=North")
    assert north.name == "North" and north.area == pytest.approx(1200, rel=1e-5)
    south = load_field(f"{p}#South")  # bare value = name
    assert len(south.parts) == 2 and south.meta["id"] == 8
    assert load_field(f"{p}#id=7").area == pytest.approx(1200, rel=1e-5)
    with pytest.raises(ValueError, match='2 polygon features .*"North", "South".*pick one'):
        load_field(str(p))
    with pytest.raises(ValueError, match='no polygon feature with name = "East"; name values: '
                                         '"North", "South"'):
        load_field(f"{p}#name=East")


def test_overlapping_parts_are_rejected():
    gj = {"type": "MultiPolygon", "coordinates": [[ll(SQ_A)], [ll([(30, 0), (60, 0), (60, 10)])]]}
    with pytest.raises(ValueError, match="parts 1 and 2 overlap"):
        Field.from_geojson(gj)


# ---------------------------------------------------------------------------------- KML / KMZ
def kml_text(hole_reverse=True):
    def coords(r):
        return " ".join(f"{a:.10f},{b:.10f},0" for a, b in r)

    def poly(outer, holes=()):
        inner = "".join(f"<innerBoundaryIs><LinearRing><coordinates>{coords(h)}</coordinates>"
                        "</LinearRing></innerBoundaryIs>" for h in holes)
        return (f"<Polygon><outerBoundaryIs><LinearRing><coordinates>\n  {coords(outer)}\n"
                f"</coordinates></LinearRing></outerBoundaryIs>{inner}</Polygon>")

    return f"""<?xml version="1.0" encoding="UTF-8"?>
<kml xmlns="http://www.opengis.net/kml/2.2"><Document><Folder>
 <Placemark><name>North</name>{poly(ll(SQ_A))}</Placemark>
 <Placemark><name>South</name>
  <ExtendedData><Data name="crop"><value>barley</value></Data></ExtendedData>
  <MultiGeometry>{poly(ll(SQ_A), [ll(HOLE_A, hole_reverse)])}{poly(ll(SQ_B))}</MultiGeometry>
 </Placemark>
 <Placemark><name>gate</name><Point><coordinates>-117,46.73,0</coordinates></Point></Placemark>
</Folder></Document></kml>"""


def test_kml_placemarks_multigeometry_and_selection(tmp_path):
    p = tmp_path / "farm.kml"
    p.write_text(kml_text())
    south = load_field(f"{p}#name=South")
    assert len(south.parts) == 2
    assert south.area == pytest.approx(1200 - 80 + 600, rel=1e-5)
    assert south.meta["crop"] == "barley"
    assert load_field(f"{p}#crop=barley").area == pytest.approx(south.area)
    assert load_field(f"{p}#North").area == pytest.approx(1200, rel=1e-5)
    # the same field from GeoJSON lands on the same ground (same default origin rule)
    gj = Field.from_geojson(multipolygon())
    assert south.polygon.symmetric_difference(gj.polygon).area < 1e-3
    kmz = tmp_path / "farm.kmz"
    with zipfile.ZipFile(kmz, "w") as z:
        z.writestr("doc.kml", kml_text())
    assert load_field(f"{kmz}#South").area == pytest.approx(south.area)


def test_kml_without_polygons_is_rejected(tmp_path):
    p = tmp_path / "points.kml"
    p.write_text('<kml xmlns="http://www.opengis.net/kml/2.2"><Placemark><Point><coordinates>'
                 "-117,46.73</coordinates></Point></Placemark></kml>")
    with pytest.raises(ValueError, match="KML: no polygon found"):
        load_field(str(p))
    p.write_text("<kml><Placemark>")
    with pytest.raises(ValueError, match="not well-formed"):
        load_field(str(p))


# ---------------------------------------------------------------------------------- shapefile
def write_shp(path, reverse_hole):
    with shapefile.Writer(str(path), shapeType=shapefile.POLYGON) as w:
        w.field("name", "C", size=20)
        w.field("ha", "N", decimal=3)
        # shapefile order: boundaries clockwise, holes counter-clockwise; this writer keeps the
        # order given, so the hole can be wound the "wrong" way too
        w.poly([ll(SQ_A, reverse=True), ll(HOLE_A, reverse=reverse_hole), ll(SQ_B, reverse=True)])
        w.record("South", 0.172)
        w.poly([ll(SQ_A, reverse=True)])
        w.record("North", 0.12)
    path.with_suffix(".prj").write_text(
        'GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],'
        'PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]]')


@pytest.mark.parametrize("reverse_hole", [False, True])
def test_shapefile_multipart_record_with_hole(tmp_path, reverse_hole):
    p = tmp_path / "farm.shp"
    write_shp(p, reverse_hole)
    south = load_field(f"{p}#name=South")
    assert len(south.parts) == 2
    assert south.area == pytest.approx(1200 - 80 + 600, rel=1e-5)
    assert south.meta["ha"] == pytest.approx(0.172)
    assert load_field(f"{p}#North").area == pytest.approx(1200, rel=1e-5)


def test_projected_shapefile_is_refused(tmp_path):
    p = tmp_path / "utm.shp"
    write_shp(p, False)
    p.with_suffix(".prj").write_text('PROJCS["WGS_1984_UTM_Zone_11N",GEOGCS["GCS_WGS_1984"]]')
    with pytest.raises(ValueError, match="projected CRS .WGS_1984_UTM_Zone_11N.*EPSG:4326"):
        load_field(f"{p}#North")


# ----------------------------------------------------------------------- CLI: one line, exit 2
@pytest.mark.parametrize("content, suffix, expect", [
    ("{not json", ".geojson", "not valid JSON"),
    (json.dumps({"type": "FeatureCollection", "features": []}), ".geojson", "no polygon found"),
    ('<kml xmlns="http://www.opengis.net/kml/2.2"><Document/></kml>', ".kml", "no polygon found"),
    ("garbage", ".shp", "cannot read shapefile"),
])
def test_bad_field_files_one_line_exit_2(tmp_path, capsys, content, suffix, expect):
    p = tmp_path / f"bad{suffix}"
    p.write_text(content)
    assert main(["plan", str(p), "-o", str(tmp_path / "x.plan")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert f'ag-uav: config error: mission.field = "{p}"' in lines[0] and expect in lines[0]
    assert not (tmp_path / "x.plan").exists()


def test_missing_feature_one_line_exit_2(tmp_path):
    p = tmp_path / "farm.geojson"
    p.write_text(json.dumps(collection()))
    r = subprocess.run([sys.executable, "-m", "ag_uav.cli", "fly", "--set",
                        f"mission.field={p}#name=East", "--no-log", "-q", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "Traceback" not in r.stderr
    assert "name values: \"North\", \"South\"" in r.stderr


# ------------------------------------------------------------------------- multi-part planning
def test_multipart_plan_covers_every_part_with_spray_off_transits():
    f = Field.from_geojson(multipolygon())
    p = plan_coverage(f, swath=6.0)
    assert p.legs == sum(d["legs"] for d in p.meta["parts"]) and len(p.meta["parts"]) == 2
    for a, b in zip(p.segments[:-1], p.segments[1:], strict=True):
        assert np.allclose(a.points[-1], b.points[0], atol=1e-6)
    # every spraying stretch stays inside one part; a transit joins the parts with spray off
    parts = [g.buffer(1e-6) for g in f.parts]
    for s in p.segments:
        if s.spray:
            assert any(g.covers(LineString(s.points)) for g in parts), s.kind
    between = [s for s in p.segments if not any(g.covers(LineString(s.points)) for g in parts)]
    assert between and all(s.kind == "transit" and not s.spray for s in between)
    # the transit does not cross the hole
    hole = Polygon(f.parts[0].interiors[0]).buffer(-1e-6)
    assert not any(LineString(s.points).intersects(hole) for s in p.segments)
    cov, _ = spray_coverage(f, p.spray_tracks(), p.swath)
    assert cov >= 0.98
    # each part is covered exactly as the one-part planner covers it on its own
    for g in f.parts:
        one = Field(g, origin=f.origin)
        alone = spray_coverage(one, plan_coverage(one, swath=6.0).spray_tracks(), 6.0)[0]
        assert spray_coverage(one, p.spray_tracks(), 6.0)[0] == pytest.approx(alone, abs=1e-9)
        assert alone > 0.98


def test_two_part_field_flies_complete():
    """Acceptance: a two-part MultiPolygon field completes with coverage >= 95 %."""
    cfg = ag_uav.load_config(None, {"mission.field": "two-part"})
    cfg.log.enabled = False
    res = ag_uav.simulate(cfg)
    s = res.summary
    assert s["completed"] and not s["crashed"]
    assert s["legs_flown"] == s["legs"] == res.plan.legs >= 2 * len(res.field.parts)
    assert s["coverage_fraction"] >= 0.95
    # the drone sprayed on both parts and never between them
    fld = res.field
    on = res.p_true[res.spray, :2]
    near = [np.min(np.hypot(*(on - np.asarray(g.centroid.coords[0])).T)) for g in fld.parts]
    assert max(near) < 25.0
    inside = shapely.contains_xy(fld.polygon.buffer(1.0), on[:, 0], on[:, 1])
    assert inside.all()


def test_example_farm_kml():
    """examples/farm.kml (the README's example): North has a hole, South is kept in two parts."""
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / "farm.kml"
    north = load_field(f"{path}#name=North")
    south = load_field(f"{path}#South")
    assert len(north.parts) == 1 and len(north.parts[0].interiors) == 1
    assert north.area == pytest.approx(3132.0, abs=1.0) and north.meta["crop"] == "winter wheat"
    assert len(south.parts) == 2 and south.area == pytest.approx(2647.5, abs=1.0)
    p = plan_coverage(south)
    assert sum(1 for s in p.segments if s.kind == "transit" and not s.spray) >= 1
    cov, _ = spray_coverage(south, p.spray_tracks(), p.swath)
    assert cov >= 0.98


def test_a_multi_part_field_is_drawn_whole(tmp_path):
    """The log's /field scene and the map outline every part (not just the first)."""
    from ag_uav.analysis.plots import _scene_lines
    from ag_uav.analysis.rundata import read_run
    from ag_uav.jobs.run import fly

    cfg = ag_uav.load_config(None, {"mission.field": "two-part", "sim.max_time_s": 3.0,
                                    "log.render": False})
    _, run_dir = fly(cfg, out_root=tmp_path, run_id="two")
    d = read_run(run_dir, images=False)
    lines = _scene_lines(d.scenes["/field"], "field")
    outlines = [pts for pts, col in lines if col[1] > 0.5]       # gold: part boundaries
    assert len(outlines) == 2
    xs = sorted(float(np.mean(p[:, 0])) for p in outlines)
    assert xs[0] < -20 < 20 < xs[1]                             # the two parts, 30 m apart
