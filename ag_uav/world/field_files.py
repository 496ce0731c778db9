"""Reading a field's polygons from GeoJSON, KML / KMZ and ESRI shapefiles (the formats and the
feature selector are described in :mod:`ag_uav.world.field`): each file's polygon features with
their properties, and the one picked by the selector.

Every input is bounded before it is read: a field file (and each part of a shapefile) larger
than :data:`MAX_FIELD_BYTES` is refused from its size on disk, and a KMZ's KML document from
the uncompressed size its zip entry declares (the archive's central directory, APPNOTE.TXT
§4.4.9), so a small archive that inflates to gigabytes (a "zip bomb") is refused before any of
it is inflated; a member that inflates past its declared size fails the archive's CRC check
(Python's :mod:`zipfile` stops at the declared size).  Each refusal is a one-line
``ValueError``."""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from shapely.geometry import Polygon

from numkit.axes import XY

#: file name endings :func:`load_field` and :meth:`Field.from_file` accept
FIELD_FILE_SUFFIXES = (".geojson", ".json", ".kml", ".kmz", ".shp")
#: the largest field file (or shapefile part, or KMZ document once inflated) read, in bytes:
#: 64 MiB, some 300 000 vertices of GeoJSON text, far more than a farm's fields; a parsed
#: document takes several times its size in memory
MAX_FIELD_BYTES = 64 * 2**20
#: how many property values an error message lists
_SHOWN = 12


def _too_big(what: str, p: Path | str, size: int) -> ValueError:
    return ValueError(f"{what} {p} is {size / 2**20:.1f} MiB, more than the "
                      f"{MAX_FIELD_BYTES / 2**20:g} MiB a field file may hold; export only the "
                      "field (one feature) from the GIS")


def check_size(p: Path, what: str) -> None:
    """Refuse ``p`` (one line) where its size on disk exceeds :data:`MAX_FIELD_BYTES`."""
    try:
        size = p.stat().st_size
    except OSError:
        return  # missing or unreadable: the reader says so
    if size > MAX_FIELD_BYTES:
        raise _too_big(f"{what} file", p, size)


@dataclass
class _Feature:
    """One polygonal feature read from a file: its properties and its parts in lon/lat."""

    props: dict[str, Any]
    parts: list[list[np.ndarray]]


def read_bytes(p: Path, what: str) -> bytes:
    """The bytes of ``p``, at most :data:`MAX_FIELD_BYTES` of them: a larger file is refused
    from its size before it is read (and a special file that streams more, while reading)."""
    try:
        check_size(p, what)
        with open(p, "rb") as f:
            data = f.read(MAX_FIELD_BYTES + 1)
        if len(data) > MAX_FIELD_BYTES:
            raise _too_big(f"{what} file", p, len(data))
        return data
    except FileNotFoundError:
        raise ValueError(f"{what} file not found: {p}") from None
    except OSError as e:
        raise ValueError(f"cannot read {what} file {p}: {e.strerror or e}") from None


def json_loads(s: str | bytes) -> Any:
    try:
        return json.loads(s)
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"not valid JSON: {e}") from None
    except RecursionError:  # "[[[[..." thousands deep: Python's parser recurses per level
        raise ValueError("JSON nested too deeply (arrays or objects thousands of levels "
                         "deep); a field's GeoJSON needs four") from None


def _parse_selector(select: str) -> tuple[str, str]:
    key, sep, val = select.partition("=")
    if not sep:
        return "name", select.strip()
    key = key.strip()
    if not key:
        raise ValueError(f"bad feature selector {select!r}; expected KEY=VALUE or a name")
    return key, val.strip()


def _prop_get(props: dict[str, Any], key: str) -> Any:
    if key in props:
        return props[key]
    low = {str(k).lower(): v for k, v in props.items()}
    return low.get(key.lower())


def _fmt_val(v: Any) -> str:
    if isinstance(v, float) and v.is_integer():
        v = int(v)
    return str(v).strip()


def from_features(cls, feats: list[_Feature], select: str | None, what: str,
                   origin: Sequence[float] | None, name: str | None,
                   fallback: str = "field") -> Any:
    """Pick one feature (by ``select``) and build a field of it with ``cls.from_lonlat_parts``
    (``cls``: :class:`~ag_uav.world.field.Field`); its name is ``name``, else the
    feature's ``name`` property, else ``fallback`` (the file's stem)."""
    if not feats:
        raise ValueError(f"{what}: no polygon found (need a Polygon or MultiPolygon)")
    if select is not None:
        key, val = _parse_selector(select)
        hits = [f for f in feats if _fmt_val(_prop_get(f.props, key)) == val
                and _prop_get(f.props, key) is not None]
        if len(hits) != 1:
            have = [_fmt_val(v) for f in feats if (v := _prop_get(f.props, key)) is not None]
            allowed = (", ".join(f'"{h}"' for h in have[:_SHOWN])
                       + (" …" if len(have) > _SHOWN else "")
                       if have else f"none of the {len(feats)} polygon features has a {key!r}")
            if len(hits) > 1:
                raise ValueError(f"{what}: {len(hits)} polygon features have {key} = \"{val}\"; "
                                 "pick by a property that is unique")
            raise ValueError(f"{what}: no polygon feature with {key} = \"{val}\"; "
                             f"{key} values: {allowed}")
        feat = hits[0]
    elif len(feats) > 1:
        names = [_fmt_val(v) for f in feats if (v := _prop_get(f.props, "name")) is not None]
        hint = (" (names: " + ", ".join(f'"{n}"' for n in names[:_SHOWN]) + ")") if names else ""
        raise ValueError(f"{what}: {len(feats)} polygon features{hint}; pick one with "
                         "PATH#name=VALUE or PATH#KEY=VALUE")
    else:
        feat = feats[0]
    props = {str(k): v for k, v in feat.props.items()}
    nm = name or (_fmt_val(props["name"]) if props.get("name") not in (None, "") else fallback)
    return cls.from_lonlat_parts(feat.parts, origin=origin, name=nm,
                                 meta={k: v for k, v in props.items() if k != "name"})


def _gj_polygon_parts(geom: Any) -> list[list[np.ndarray]] | None:
    """Parts of a GeoJSON geometry (None if it is not polygonal)."""
    if not isinstance(geom, dict):
        return None
    t = geom.get("type")

    def poly(rings: Any, where: str) -> list[np.ndarray]:
        if not isinstance(rings, list) or not rings:
            raise ValueError(f"GeoJSON {where}: expected a list of rings [[[lon, lat], ...], ...]")
        out = []
        for i, r in enumerate(rings):
            try:
                a = np.asarray(r, dtype=float)
            except (TypeError, ValueError):
                a = np.empty((0,))
            if a.ndim != 2 or a.shape[1] < 2:
                raise ValueError(f"GeoJSON {where} ring {i}: expected [[lon, lat], ...]")
            out.append(a)
        return out

    if t == "Polygon":
        return [poly(geom.get("coordinates"), "Polygon")]
    if t == "MultiPolygon":
        cs = geom.get("coordinates")
        if not isinstance(cs, list) or not cs:
            raise ValueError("GeoJSON MultiPolygon has no parts")
        return [poly(c, f"MultiPolygon part {k + 1}") for k, c in enumerate(cs)]
    if t == "GeometryCollection":
        parts: list[list[np.ndarray]] = []
        for g in geom.get("geometries") or []:
            parts += _gj_polygon_parts(g) or []
        return parts or None
    return None


def geojson_features(gj: dict) -> list[_Feature]:
    t = gj.get("type")
    if t == "FeatureCollection":
        feats = gj.get("features")
        if not isinstance(feats, list):
            raise ValueError("GeoJSON FeatureCollection has no \"features\" list")
        out = []
        for f in feats:
            if isinstance(f, dict):
                out += geojson_features(f) if f.get("type") == "Feature" else []
        return out
    if t == "Feature":
        parts = _gj_polygon_parts(gj.get("geometry"))
        return [_Feature(dict(gj.get("properties") or {}), parts)] if parts else []
    if t in ("Polygon", "MultiPolygon", "GeometryCollection"):
        parts = _gj_polygon_parts(gj)
        return [_Feature({}, parts)] if parts else []
    raise ValueError(f"GeoJSON: expected a Polygon, MultiPolygon, Feature or FeatureCollection, "
                     f"got {t!r}")


# KML ------------------------------------------------------------------------------------------
def _local(tag: Any) -> str:
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _kml_coords(text: str | None) -> np.ndarray:
    """KML ``<coordinates>``: whitespace-separated ``lon,lat[,alt]`` tuples → (N, 2)."""
    s = re.sub(r"\s*,\s*", ",", (text or "").strip())
    pts = []
    for tup in s.split():
        vals = tup.split(",")
        try:
            pts.append((float(vals[0]), float(vals[1])))
        except (ValueError, IndexError):
            raise ValueError(f"KML: bad coordinate tuple {tup!r}; expected lon,lat[,alt]") from None
    return np.asarray(pts, dtype=float).reshape(-1, 2)


def _kml_ring(boundary: Any) -> list[np.ndarray]:
    out = []
    for el in boundary.iter():
        if _local(el.tag) == "LinearRing":
            for c in el:
                if _local(c.tag) == "coordinates":
                    out.append(_kml_coords(c.text))
    return out


def kml_features(data: bytes) -> list[_Feature]:
    import xml.etree.ElementTree as ET

    try:
        root = ET.fromstring(data)
    except ET.ParseError as e:
        raise ValueError(f"KML is not well-formed XML: {e}") from None
    if _local(root.tag) != "kml":
        raise ValueError(f"not a KML document (root element <{_local(root.tag)}>, expected <kml>)")
    feats = []
    for pm in root.iter():
        if _local(pm.tag) != "Placemark":
            continue
        props: dict[str, Any] = {}
        parts: list[list[np.ndarray]] = []
        for ch in pm:
            tag = _local(ch.tag)
            if tag in ("name", "description") and ch.text:
                props[tag] = ch.text.strip()
            elif tag == "ExtendedData":
                for d in ch.iter():
                    dt = _local(d.tag)
                    if dt == "Data" and d.get("name"):
                        v = next((x.text for x in d if _local(x.tag) == "value"), None)
                        props.setdefault(d.get("name"), (v or "").strip())
                    elif dt == "SimpleData" and d.get("name"):
                        props.setdefault(d.get("name"), (d.text or "").strip())
        for g in pm.iter():
            if _local(g.tag) != "Polygon":
                continue
            outer: list[np.ndarray] = []
            inner: list[np.ndarray] = []
            for b in g:
                bt = _local(b.tag)
                if bt == "outerBoundaryIs":
                    outer += _kml_ring(b)
                elif bt == "innerBoundaryIs":
                    inner += _kml_ring(b)
            if len(outer) != 1:
                nm = f" {props['name']!r}" if "name" in props else ""
                raise ValueError(f"KML Polygon{nm}: needs exactly one outerBoundaryIs "
                                 f"LinearRing, has {len(outer)}")
            parts.append([outer[0], *inner])
        if parts:
            feats.append(_Feature(props, parts))
    return feats


def kmz_doc(p: Path) -> bytes:
    """The KML document inside a KMZ (``doc.kml``, else the first ``.kml`` entry); refused
    before it is inflated where its entry declares more than :data:`MAX_FIELD_BYTES`."""
    import zipfile
    import zlib

    try:
        with zipfile.ZipFile(p) as z:
            names = [n for n in z.namelist() if n.lower().endswith(".kml")]
            if not names:
                raise ValueError(f"KMZ {p} holds no .kml document")
            name = "doc.kml" if "doc.kml" in names else names[0]
            size = z.getinfo(name).file_size
            if size > MAX_FIELD_BYTES:
                raise _too_big("KMZ document", f"{p}!{name} (inflated)", size)
            with z.open(name) as f:
                return f.read(MAX_FIELD_BYTES)  # zipfile stops at the declared size
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError) as e:
        raise ValueError(f"KMZ {p} is not a valid zip archive: {e}") from None


# shapefile ------------------------------------------------------------------------------------
def _group_rings(rings: list[np.ndarray]) -> list[list[np.ndarray]]:
    """Sort rings into parts by containment (even nesting depth = boundary, odd = hole of the
    smallest boundary around it); winding is ignored."""
    polys = [Polygon(r[:, XY]) for r in rings]  # callers pass rings of >= 3 points
    # a point strictly inside each ring (an invalid ring is reported later, by _make_polygon)
    probe = [p.representative_point() if p.is_valid else p.centroid for p in polys]
    areas = [p.area for p in polys]
    n = len(rings)
    containers = [[j for j in range(n) if j != i and areas[j] > areas[i]
                   and polys[j].is_valid and polys[j].contains(probe[i])] for i in range(n)]
    depth = [len(c) for c in containers]
    parts: dict[int, list[np.ndarray]] = {}
    order = [i for i in range(n) if depth[i] % 2 == 0]
    for i in order:
        parts[i] = [rings[i]]
    for i in range(n):
        if depth[i] % 2 == 1:
            outs = [j for j in containers[i] if depth[j] == depth[i] - 1]
            if outs:
                parts[min(outs, key=lambda j: areas[j])].append(rings[i])
    return [parts[i] for i in order]


def shp_features(p: Path) -> list[_Feature]:
    import shapefile  # pyshp

    if not p.exists():
        raise ValueError(f"shapefile not found: {p}")
    for part in (p, *(p.with_suffix(s) for s in (".shx", ".dbf", ".SHX", ".DBF", ".prj"))):
        check_size(part, "shapefile part")
    prj = p.with_suffix(".prj")
    if not prj.exists():
        prj = p.with_suffix(".PRJ")
    if prj.exists():
        wkt = prj.read_text(errors="replace").strip()
        if wkt.upper().startswith("PROJCS") or wkt.upper().startswith("PROJCRS"):
            crs = wkt.split('"')[1] if wkt.count('"') >= 2 else "projected"
            raise ValueError(f"shapefile is in a projected CRS ({crs}); reproject it to WGS-84 "
                             "lon/lat (EPSG:4326)")
    poly_types = {shapefile.POLYGON, shapefile.POLYGONZ, shapefile.POLYGONM}
    feats = []
    bad_type = None
    try:
        with shapefile.Reader(str(p)) as r:
            if r.shapeType not in poly_types and r.shapeType != shapefile.NULL:
                bad_type = r.shapeTypeName
            has_dbf = r.dbf is not None
            for i in range(0 if bad_type else len(r)):
                shp = r.shape(i)
                if shp.shapeType not in poly_types or not shp.points:
                    continue
                pts = np.asarray(shp.points, dtype=float)[:, XY]
                idx = [*list(shp.parts), len(pts)]
                rings = [pts[a:b] for a, b in zip(idx[:-1], idx[1:], strict=True) if b - a >= 3]
                props = dict(r.record(i).as_dict()) if has_dbf else {}
                parts = _group_rings(rings)
                if parts:
                    feats.append(_Feature(props, parts))
    except Exception as e:  # pyshp raises ShapefileException, struct.error, ... on a bad file
        msg = (str(e).splitlines() or [""])[0]
        raise ValueError(f"cannot read shapefile {p}: {type(e).__name__}: {msg}") from None
    if bad_type:
        raise ValueError(f"shapefile holds {bad_type} shapes, not polygons")
    return feats
