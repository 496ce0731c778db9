"""Chaos: inputs that must not escape or mislead.  Run ids that are paths, an origin that would
move a georeferenced field's plan, a KMZ zip bomb and oversized field files, empty or out-of-
envelope experiment axes, and a spray-settings search that would recommend what ``fly``
refuses.  Each case ends in one line and exit 2, or in a correct result."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import shapely
from shapely.geometry import Polygon

from ag_uav.cli import main
from ag_uav.config import ConfigError
from ag_uav.jobs.outdir import check_run_id
from ag_uav.jobs.run import fly

ROOT = Path(__file__).resolve().parents[1]
KML = "{http://www.opengis.net/kml/2.2}"


def _one_line_exit2(capsys, argv: list[str], *words: str) -> str:
    """``ag-uav argv`` exits 2 with one stderr line holding every word; returns the line."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, (w, err)
    return err


# ---------------------------------------------------------------------------- run ids are names
@pytest.mark.parametrize("rid", ["../../escaped", "/tmp/abs-run", ".", "..", "", "a/b", "a\\b",
                                 "x\x00y", "x" * 256])
def test_run_id_that_is_a_path_is_refused(rid, tmp_path, capsys):
    out = tmp_path / "runs" / "rid"
    _one_line_exit2(capsys, ["fly", "--out", str(out), "--run-id", rid, "--no-log", "-q"],
                    "--run-id", "folder name")
    assert not out.exists() and not (tmp_path / "escaped").exists()
    with pytest.raises(ConfigError, match="--run-id"):  # the library refuses it too
        fly(None, out_root=out, run_id=rid)  # type: ignore[arg-type]
    assert not out.exists()


@pytest.mark.parametrize("rid", ["run-1", "2026_a.b", "feld-Ost", "..x", "a..b"])
def test_run_id_names_are_accepted(rid):
    assert check_run_id(rid) == rid


# ------------------------------------------------------------ a plan flies where the field is
L_SHAPE = ROOT / "ag_uav" / "data" / "l-shape.geojson"


def _file_polygon(path: Path) -> Polygon:
    """The field's own lon/lat polygon, read straight from its GeoJSON file."""
    geom = json.loads(path.read_text())
    geom = geom.get("geometry", geom) if geom["type"] == "Feature" else geom["features"][0][
        "geometry"]
    rings = geom["coordinates"]
    return Polygon(rings[0], rings[1:])


def _export_lonlat(path: Path) -> np.ndarray:
    """Every waypoint (lon, lat) of an exported plan, read as an autopilot or a GIS would."""
    if path.suffix == ".plan":
        items = json.loads(path.read_text())["mission"]["items"]
        return np.array([(it["params"][5], it["params"][4]) for it in items
                         if it["command"] == 16])
    if path.suffix == ".geojson":
        feats = json.loads(path.read_text())["features"]
        return np.array([c[:2] for f in feats if f["properties"].get("role") == "path"
                         for c in f["geometry"]["coordinates"]])
    pts = []
    for pm in ET.parse(path).getroot().iter(f"{KML}Placemark"):
        for ls in pm.iter(f"{KML}LineString"):
            txt = ls.find(f"{KML}coordinates").text
            pts += [tuple(map(float, t.split(",")[:2])) for t in txt.split()]
    return np.array(pts)


@pytest.mark.parametrize("ext", [".plan", ".geojson", ".kml"])
def test_every_export_lies_on_the_field_and_origin_is_refused(ext, tmp_path, capsys):
    poly = _file_polygon(L_SHAPE)
    out = tmp_path / f"l{ext}"
    assert main(["plan", str(L_SHAPE), "-o", str(out)]) == 0
    ll = _export_lonlat(out)
    assert len(ll) >= 100
    # every waypoint inside the file's own polygon (1e-7 deg: about 1 cm)
    inside = shapely.contains_xy(poly.buffer(1e-7), ll[:, 0], ll[:, 1])
    assert inside.all(), ll[~inside][:3]
    # and they cover it: the waypoints' extent reaches within 10 m (1.3e-4 deg) of the field's
    lo, la = poly.bounds[0::2], poly.bounds[1::2]
    assert abs(ll[:, 0].min() - lo[0]) < 1.3e-4 and abs(ll[:, 0].max() - lo[1]) < 1.3e-4
    assert abs(ll[:, 1].min() - la[0]) < 1e-4 and abs(ll[:, 1].max() - la[1]) < 1e-4
    capsys.readouterr()
    # --origin on a lon/lat field: refused, nothing written
    moved = tmp_path / f"moved{ext}"
    _one_line_exit2(capsys, ["plan", str(L_SHAPE), "--origin", "46.74,-117.0", "-o",
                             str(moved)], "--origin", "georeferenced")
    assert not moved.exists()
    # the config's origin projects the field about another point: the waypoints stay on it
    assert main(["plan", str(L_SHAPE), "--set", "mission.origin_lat_deg=46.74", "--set",
                 "mission.origin_lon_deg=-117.0", "-o", str(moved)]) == 0
    ll2 = _export_lonlat(moved)
    assert shapely.contains_xy(poly.buffer(1e-7), ll2[:, 0], ll2[:, 1]).all()
    assert np.abs(ll2.min(axis=0) - ll.min(axis=0)).max() < 2e-6  # ~0.2 m
    assert np.abs(ll2.max(axis=0) - ll.max(axis=0)).max() < 2e-6


def test_origin_places_a_local_field_like_the_config(tmp_path, capsys):
    a, b = tmp_path / "a.plan", tmp_path / "b.plan"
    assert main(["plan", "default", "--origin=-35.3,149.1", "-o", str(a)]) == 0
    assert main(["plan", "default", "--set", "mission.origin_lat_deg=-35.3", "--set",
                 "mission.origin_lon_deg=149.1", "-o", str(b)]) == 0
    assert np.array_equal(_export_lonlat(a), _export_lonlat(b))
    assert a.read_text() == b.read_text()
    _one_line_exit2(capsys, ["plan", "default", "--origin", "95,10", "-o", str(a)], "--origin")


def test_write_plan_refuses_to_move_a_georeferenced_field():
    from ag_uav.world.field import load_field
    from ag_uav.world.plan import plan_coverage
    from ag_uav.world.plan_export import plan_waypoints

    fld = load_field("l-shape")
    plan = plan_coverage(fld)
    with pytest.raises(ValueError, match="georeferenced"):
        plan_waypoints(plan, origin=(46.74, -117.0))
    assert len(plan_waypoints(plan, origin=fld.origin)) == len(plan_waypoints(plan))


# ------------------------------------------------- experiment axes are checked like config keys
AXES = [
    (["spray-settings", "--heights", ""], ["--heights", "empty"]),
    (["spray-settings", "--speeds", "3,x"], ["--speeds", "not a number"]),
    (["spray-settings", "--heights", "-2"], ["--heights", "out of range"]),
    (["spray-settings", "--spectra", " , "], ["--spectra", "empty"]),
    (["spray-settings", "--spacings", "0.1:2:0.1"], ["--spacings", "mission.swath_m"]),
    (["spray-settings", "--wind", "nan"], ["--wind"]),
    (["drift", "--winds", ""], ["--winds", "empty"]),
    (["drift", "--winds", "-1"], ["--winds", "out of range"]),
    (["drift", "--winds", "30"], ["--winds", "wind.speed_mps"]),
    (["drift", "--heights", "10"], ["--heights", "mission.altitude_m"]),
    (["drift", "--speeds", "0"], ["--speeds"]),
    (["drift", "--rhs", ""], ["--rhs", "empty"]),
    (["drift", "--rhs", "120"], ["rh_percent"]),
    (["drift", "--passes", "0"], ["--passes"]),
    (["drift", "--mass", "0.1"], ["--mass", "vehicle.mass_kg"]),
    (["swath", "--heights", ""], ["--heights", "empty"]),
    (["swath", "--winds", "inf"], ["--winds"]),
    (["swath", "--turbulence", "-1"], ["--turbulence"]),
    (["ins-nav", "--what", "sweep", "--sigmas", "", "--kernels", ""], ["--sigmas", "--kernels"]),
    (["ins-nav", "--what", "sweep", "--sigmas", "0"], ["--sigmas"]),
    (["ins-nav", "--what", "rules", "--presets", "rtk,nope"], ["--presets", "nope"]),
    (["ins-nav", "--what", "rules", "--r-sources", "generator"], ["--r-sources"]),
    (["ins-nav", "--what", "replay"], ["--logs"]),
    (["ins-nav", "--what", "replay", "--logs", "no/such/log.ulg"], ["--logs", "log.ulg"]),
    (["table2", "--estimators", ","], ["--estimators", "empty"]),
    (["outage", "--duration", "-1"], ["--duration"]),
    (["langevin", "--snr", ""], ["--snr"]),
    (["controllers", "--controllers", ""], ["--controllers"]),
    (["optimisers", "--optimizers", ""], ["--optimizers"]),
    (["bearing-tracking", "--methods", ""], ["--methods"]),
]


@pytest.mark.parametrize(("argv", "words"), AXES, ids=[" ".join(a) for a, _ in AXES])
def test_bad_experiment_axis_is_one_line(argv, words, tmp_path, capsys):
    out = tmp_path / "out"
    _one_line_exit2(capsys, ["experiment", *argv, "--out", str(out)], *words)
    assert not out.exists() or not any(out.iterdir())  # nothing written


def test_spray_settings_searches_only_what_fly_accepts(tmp_path, capsys):
    out = tmp_path / "ss"
    # the finding: 10 m was listed as a pick, then the confirming flight failed
    err = _one_line_exit2(capsys, ["experiment", "spray-settings", "--heights", "10",
                                   "--confirm", "1", "--out", str(out), "-q"],
                          "--heights", "mission.altitude_m", "spray.max_height_m = 6")
    assert "10" in err and not out.exists()
    # the limits are the base config's, as the confirming flights load it
    _one_line_exit2(capsys, ["experiment", "spray-settings", "--heights", "2,3.5",
                             "--set", "spray.max_height_m=3", "--set", "mission.altitude_m=2",
                             "--out", str(out), "-q"], "3.5", "spray.max_height_m = 3")
    # inside the envelope: every point of the search is one fly accepts
    from ag_uav.config import load_config

    assert main(["experiment", "spray-settings", "--heights", "2,5.5", "--speeds", "5",
                 "--spectra", "medium", "--spacings", "3:4:1", "--out", str(out), "-q"]) == 0
    import csv

    rows = list(csv.DictReader((out / "settings.csv").open()))
    assert {float(r["height_m"]) for r in rows} == {2.0, 5.5} and len(rows) == 4
    for r in rows:
        load_config(None, {"mission.altitude_m": float(r["height_m"]),
                           "mission.speed_mps": float(r["speed_mps"]),
                           "mission.swath_m": float(r["spacing_m"])})


# --------------------------------------------------------- bounded inputs: zip bombs, big files
KML_DOC = (b"<?xml version='1.0'?><kml xmlns='http://www.opengis.net/kml/2.2'><Placemark>"
           b"<name>f</name><Polygon><outerBoundaryIs><LinearRing><coordinates>"
           b"-117.0,46.73 -116.999,46.73 -116.999,46.731 -117.0,46.731 -117.0,46.73"
           b"</coordinates></LinearRing></outerBoundaryIs></Polygon></Placemark></kml>")


def _kmz(path: Path, doc: bytes, declared: int | None = None) -> Path:
    """A KMZ holding ``doc`` as doc.kml; ``declared``: the uncompressed size its local header
    and central directory claim (a bomb's few bytes that say they inflate to gigabytes)."""
    import io
    import struct
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("doc.kml", doc)
    b = bytearray(buf.getvalue())
    if declared is not None:  # APPNOTE.TXT 4.3.7 / 4.3.12: uncompressed size at +22 / +24
        struct.pack_into("<I", b, b.find(b"PK\x03\x04") + 22, declared)
        struct.pack_into("<I", b, b.find(b"PK\x01\x02") + 24, declared)
    path.write_bytes(bytes(b))
    return path


def test_kmz_bomb_is_refused_before_it_is_inflated(tmp_path, capsys):
    import resource

    good = _kmz(tmp_path / "good.kmz", KML_DOC)
    assert main(["plan", str(good), "-o", str(tmp_path / "g.plan")]) == 0
    capsys.readouterr()
    bomb = _kmz(tmp_path / "bomb.kmz", KML_DOC, declared=0xFFFF0000)  # "4 GiB"
    assert bomb.stat().st_size < 1000
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    err = _one_line_exit2(capsys, ["plan", str(bomb), "-o", str(tmp_path / "b.plan")],
                          "bomb.kmz", "KMZ document", "4095.9 MiB", "64 MiB")
    assert "inflated" in err
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0 < 200_000  # KiB
    # a member that inflates past the size it declares: the archive's CRC check stops it
    liar = _kmz(tmp_path / "liar.kmz", KML_DOC + b" " * 100_000, declared=len(KML_DOC))
    _one_line_exit2(capsys, ["plan", str(liar), "-o", str(tmp_path / "l.plan")],
                    "liar.kmz", "not a valid zip archive")


@pytest.mark.parametrize("name", ["big.geojson", "big.kml", "big.kmz", "big.shp"])
def test_oversized_field_file_is_refused_before_it_is_read(name, tmp_path, capsys):
    p = tmp_path / name
    with open(p, "wb") as f:  # sparse: 2 GiB on paper, no blocks on the disk
        f.truncate(2 * 2**30)
    if name.endswith(".shp"):
        for suf in (".shx", ".dbf"):
            p.with_suffix(suf).write_bytes(b"")
    _one_line_exit2(capsys, ["plan", str(p), "-o", str(tmp_path / "x.plan")],
                    name, "2048.0 MiB", "64 MiB")


def test_oversized_shapefile_part_is_refused(tmp_path, capsys):
    import shapefile

    p = tmp_path / "f.shp"
    with shapefile.Writer(str(p), shapeType=shapefile.POLYGON) as w:
        w.field("name", "C")
        w.poly([[[-117.0, 46.73], [-117.0, 46.731], [-116.999, 46.731], [-116.999, 46.73],
                 [-117.0, 46.73]]])
        w.record("f")
    assert main(["plan", str(p), "-o", str(tmp_path / "ok.plan")]) == 0
    capsys.readouterr()
    with open(p.with_suffix(".dbf"), "r+b") as f:
        f.truncate(2 * 2**30)
    _one_line_exit2(capsys, ["plan", str(p), "-o", str(tmp_path / "x.plan")],
                    "f.dbf", "64 MiB")


def test_deeply_nested_geojson_and_entity_expansion_are_one_line(tmp_path, capsys):
    deep = tmp_path / "deep.geojson"
    deep.write_text('{"type": "Polygon", "coordinates": ' + "[" * 100_000 + "]" * 100_000 + "}")
    _one_line_exit2(capsys, ["plan", str(deep), "-o", str(tmp_path / "d.plan")],
                    "deep.geojson", "nested too deeply")
    import pyexpat

    if tuple(int(v) for v in pyexpat.EXPAT_VERSION.split("_")[1].split(".")) < (2, 4, 1):
        pytest.skip(f"{pyexpat.EXPAT_VERSION} has no amplification limit")
    # "billion laughs": 10^10 characters from a few hundred bytes of entities
    ents = '<!ENTITY a0 "xxxxxxxxxx">' + "".join(
        f'<!ENTITY a{i} "{f"&a{i - 1};" * 10}">' for i in range(1, 10))
    laughs = tmp_path / "laughs.kml"
    laughs.write_text(f'<?xml version="1.0"?><!DOCTYPE kml [{ents}]><kml xmlns="http://www.'
                      'opengis.net/kml/2.2"><Placemark><name>&a9;</name></Placemark></kml>')
    _one_line_exit2(capsys, ["plan", str(laughs), "-o", str(tmp_path / "l.plan")],
                    "laughs.kml", "not well-formed")
