"""Field geometry: a polygon (or several parts) in local ENU metres, with optional holes.

A :class:`Field` wraps a :class:`shapely.geometry.Polygon` (or a ``MultiPolygon`` for a field
kept as several parts) whose coordinates are east/north metres in a local tangent plane. Fields
are built from local coordinates (:meth:`Field.from_coords`, :meth:`Field.from_parts`), from WGS-84
lon/lat files (:meth:`Field.from_file`) or by name (:func:`load_field` / :meth:`Field.builtin`).

Files accepted (the format follows the extension):

* **GeoJSON** (RFC 7946; ``.geojson``/``.json``): a Polygon, MultiPolygon, GeometryCollection of
  them, Feature or FeatureCollection. Positions are ``[lon, lat(, alt)]``; the first ring of a
  polygon is its boundary, further rings are holes.
* **KML** (OGC KML 2.2; ``.kml``, or zipped ``.kmz``): every ``Placemark`` with a ``Polygon``
  (``outerBoundaryIs`` / ``innerBoundaryIs``), also inside ``MultiGeometry``. Properties of a
  placemark: its ``<name>`` and its ``ExtendedData`` (``Data``/``value`` and ``SimpleData``).
* **ESRI shapefile** (``.shp`` with its ``.shx``/``.dbf``; read with pyshp, pure Python): Polygon
  shapes (Z/M too) in geographic lon/lat; a ``.prj`` naming a projected CRS is refused. Rings are
  sorted into boundaries and holes by containment, not by winding.

Ring winding is never trusted (RFC 7946 asks for counter-clockwise boundaries, the shapefile spec
for clockwise ones, KML says nothing): holes may be wound either way; the polygon is normalised
to a counter-clockwise boundary with clockwise holes. A feature with several polygons (a
MultiPolygon, a KML MultiGeometry, a multi-part shapefile record) becomes one Field with several
parts; :mod:`ag_uav.world.plan` plans each part and joins them with transits (nozzles off). Parts
must not overlap (touching at a point is allowed).

**Picking one feature** out of a file with several (a FeatureCollection, a KML with several
placemarks, a shapefile with several records): append ``#KEY=VALUE`` to the path (the feature
whose property ``KEY`` equals ``VALUE``), or ``#VALUE`` for ``#name=VALUE``, e.g.
``mission.field = "farm.geojson#name=North"``. Without a selector the file must hold exactly one
polygon feature.

Geodetic conversion (no pyproj): WGS-84 geodetic (lat φ, lon λ, h) → ECEF → local ENU about an
origin (φ0, λ0, h0), from the textbook formulas::

    N(φ) = a / sqrt(1 - e² sin²φ)                      (prime-vertical radius of curvature)
    X = (N + h) cosφ cosλ,  Y = (N + h) cosφ sinλ,  Z = (N (1 - e²) + h) sinφ
    [e]   [ -sinλ0          cosλ0         0    ] [X - X0]
    [n] = [ -sinφ0 cosλ0   -sinφ0 sinλ0   cosφ0] [Y - Y0]
    [u]   [  cosφ0 cosλ0    cosφ0 sinλ0   sinφ0] [Z - Z0]

with a = 6 378 137 m, f = 1/298.257223563, e² = f (2 - f). The field polygon is the orthographic
projection (e, n) of its vertices onto the tangent plane; ``u`` is dropped. Error of that
projection: a point at ground distance d from the origin lands at R·sin(d/R) ≈ d (1 - d²/6R²), a
relative length error of ~1e-9 at d = 500 m and ~1e-7 at 5 km (area error twice that); the
dropped ``u`` (Earth curvature, ≈ -d²/2R) is 2 cm at 500 m and irrelevant to a planar plan. Edges
of a lon/lat polygon are taken as straight lines in the plane (a parallel between two vertices
100 m apart bows by < 1 mm). A lon/lat field's vertices are projected at the origin's height
``h0`` (the ground it lies on). The inverse (:func:`enu_to_geodetic`, :func:`enu_to_lonlat`) uses
ECEF → geodetic with Bowring's iteration, accurate to < 1e-9 deg here; it is what the run log's
geographic topics use (:mod:`ag_uav.record.geo`), so lon/lat → ENU → lon/lat round-trips.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.polygon import orient
from shapely.validation import explain_validity

__all__ = [
    "BUILTIN_FIELDS",
    "DEFAULT_ORIGIN",
    "FIELD_FILE_SUFFIXES",
    "Field",
    "ecef_to_geodetic",
    "enu_frame",
    "enu_to_geodetic",
    "enu_to_lonlat",
    "geodetic_to_ecef",
    "load_field",
    "lonlat_to_enu",
    "split_field_spec",
]

# WGS-84 ellipsoid
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
WGS84_B = WGS84_A * (1.0 - WGS84_F)


def geodetic_to_ecef(lat_deg, lon_deg, h=0.0) -> np.ndarray:
    """WGS-84 geodetic (degrees, metres) → ECEF metres; broadcasts; returns (..., 3)."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    h = np.asarray(h, dtype=float)
    s, c = np.sin(lat), np.cos(lat)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * s * s)
    x = (n + h) * c * np.cos(lon)
    y = (n + h) * c * np.sin(lon)
    z = (n * (1.0 - WGS84_E2) + h) * s
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def _enu_rotation(lat0_deg: float, lon0_deg: float) -> np.ndarray:
    """Rows are the east, north, up unit vectors at (lat0, lon0) in ECEF."""
    la, lo = math.radians(lat0_deg), math.radians(lon0_deg)
    sla, cla, slo, clo = math.sin(la), math.cos(la), math.sin(lo), math.cos(lo)
    return np.array(
        [
            [-slo, clo, 0.0],
            [-sla * clo, -sla * slo, cla],
            [cla * clo, cla * slo, sla],
        ]
    )


def lonlat_to_enu(lon_deg, lat_deg, origin: Sequence[float], h=0.0) -> np.ndarray:
    """Geodetic lon/lat (degrees) → local ENU (..., 3) metres about ``origin`` = (lat0, lon0[, h0]).

    Exact WGS-84 geodetic → ECEF → ENU (see module docstring)."""
    lat0, lon0 = float(origin[0]), float(origin[1])
    h0 = float(origin[2]) if len(origin) > 2 else 0.0
    p = geodetic_to_ecef(lat_deg, lon_deg, h)
    p0 = geodetic_to_ecef(lat0, lon0, h0)
    return (p - p0) @ _enu_rotation(lat0, lon0).T


def enu_to_geodetic(e, n, origin: Sequence[float], u=0.0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local ENU metres → (lon, lat, h): degrees and WGS-84 ellipsoidal height (m); the exact
    inverse of :func:`lonlat_to_enu` (with its ``h``): ENU → ECEF by the transposed rotation,
    then :func:`ecef_to_geodetic`."""
    lat0, lon0 = float(origin[0]), float(origin[1])
    h0 = float(origin[2]) if len(origin) > 2 else 0.0
    enu = np.stack(np.broadcast_arrays(np.asarray(e, float), np.asarray(n, float),
                                       np.asarray(u, float)), axis=-1)
    xyz = enu @ _enu_rotation(lat0, lon0) + geodetic_to_ecef(lat0, lon0, h0)
    return ecef_to_geodetic(xyz)


def enu_frame(origin: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """(R, p0) of the ENU frame about ``origin`` = (lat, lon[, h]): ECEF = ENU @ R + p0 (what
    :func:`enu_to_geodetic` computes per call, for a caller converting many batches)."""
    lat0, lon0 = float(origin[0]), float(origin[1])
    h0 = float(origin[2]) if len(origin) > 2 else 0.0
    return _enu_rotation(lat0, lon0), geodetic_to_ecef(lat0, lon0, h0)


def ecef_to_geodetic(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF metres (..., 3) → (lon °, lat °, h m) on WGS-84: Bowring's parametric-latitude
    iteration (3 rounds; converged to ~1e-12 rad for terrestrial heights) and the height
    ``h = p cosφ + z sinφ − a sqrt(1 − e² sin²φ)`` (valid at every latitude)."""
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    ep2 = (WGS84_A**2 - WGS84_B**2) / WGS84_B**2
    beta = np.arctan2(z, (1.0 - WGS84_F) * p)
    for _ in range(3):
        lat = np.arctan2(z + ep2 * WGS84_B * np.sin(beta) ** 3,
                         p - WGS84_E2 * WGS84_A * np.cos(beta) ** 3)
        beta = np.arctan2((1.0 - WGS84_F) * np.sin(lat), np.cos(lat))
    s = np.sin(lat)
    h = p * np.cos(lat) + z * s - WGS84_A * np.sqrt(1.0 - WGS84_E2 * s * s)
    return np.degrees(lon), np.degrees(lat), h


def enu_to_lonlat(e, n, origin: Sequence[float], u=0.0) -> tuple[np.ndarray, np.ndarray]:
    """Local ENU metres → (lon, lat) degrees; inverse of :func:`lonlat_to_enu`
    (:func:`enu_to_geodetic` without the height)."""
    lon, lat, _ = enu_to_geodetic(e, n, origin, u)
    return lon, lat


def _as_ring(pts: Iterable[Sequence[float]], what: str) -> np.ndarray:
    a = np.asarray(list(pts), dtype=float)
    if a.ndim != 2 or a.shape[0] == 0 or a.shape[1] < 2:
        raise ValueError(f"{what}: expected a sequence of (x, y) points, got shape {a.shape}")
    a = a[:, :2]
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: contains non-finite coordinates")
    # drop the closing point and consecutive duplicates
    keep = np.ones(len(a), bool)
    keep[1:] = np.any(np.abs(np.diff(a, axis=0)) > 1e-9, axis=1)
    a = a[keep]
    if len(a) > 1 and np.allclose(a[0], a[-1], atol=1e-9):
        a = a[:-1]
    if len(a) < 3:
        raise ValueError(f"{what}: a polygon ring needs at least 3 distinct points, got {len(a)}")
    return a


def _make_polygon(outer: Iterable[Sequence[float]], holes: Iterable[Iterable[Sequence[float]]],
                  pre: str = "") -> Polygon:
    """A validated, oriented (CCW boundary, CW holes) polygon; ``pre`` prefixes error messages."""
    shell = _as_ring(outer, f"{pre}outer boundary")
    rings = [_as_ring(h, f"{pre}hole {i}") for i, h in enumerate(holes)]
    shell_poly = Polygon(shell)
    c = shell - shell.mean(axis=0)
    if np.linalg.svd(c, compute_uv=False)[-1] <= 1e-9 * max(1.0, float(np.abs(c).max())):
        raise ValueError(f"{pre}outer boundary has zero area (collinear or repeated points)")
    if not shell_poly.is_valid:
        raise ValueError(
            f"{pre}outer boundary is not a valid simple polygon: {explain_validity(shell_poly)}"
            " (self-intersecting? check the vertex order)"
        )
    for i, h in enumerate(rings):
        hp = Polygon(h)
        if hp.area <= 1e-9:
            raise ValueError(f"{pre}hole {i} has zero area")
        if not hp.is_valid:
            raise ValueError(f"{pre}hole {i} is not a valid simple polygon: {explain_validity(hp)}")
        if not shell_poly.contains(hp):
            raise ValueError(f"{pre}hole {i} is not inside the outer boundary")
        for j in range(i):
            if hp.intersects(Polygon(rings[j])):
                raise ValueError(f"{pre}holes {j} and {i} overlap or touch; merge them into one")
    poly = Polygon(shell, rings)
    if not poly.is_valid:
        raise ValueError(f"{pre}field polygon is invalid: {explain_validity(poly)}")
    if poly.area <= 1e-9:
        raise ValueError(f"{pre}field has zero area")
    poly = Polygon(poly.exterior.coords, [r.coords for r in poly.interiors])
    return orient(poly, 1.0)


@dataclass
class Field:
    """A field in local ENU metres (x = east, y = north): one polygon or several parts, with
    optional holes.

    Attributes:
        polygon: the shapely ``Polygon`` (exterior = boundary, interiors = obstacles / no-spray
            holes), or a ``MultiPolygon`` when the field has several parts (see :attr:`parts`).
        name: a label.
        origin: (lat, lon, h) of the local frame's origin when built from geodetic data, else None.
        meta: the source feature's other properties.
    """

    polygon: Polygon | MultiPolygon
    name: str = "field"
    origin: tuple[float, float, float] | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    # --- constructors -------------------------------------------------------------------------
    @classmethod
    def from_coords(
        cls,
        outer: Iterable[Sequence[float]],
        holes: Iterable[Iterable[Sequence[float]]] = (),
        name: str = "field",
        origin: tuple[float, float, float] | None = None,
    ) -> Field:
        """Build from local metres: ``outer`` ring and optional ``holes`` rings ((x, y) points;
        closing point optional; either winding). Raises ValueError on a degenerate or invalid
        polygon."""
        return cls(_make_polygon(outer, holes), name=name, origin=origin)

    @classmethod
    def from_parts(
        cls,
        parts: Sequence[Sequence[Iterable[Sequence[float]]]],
        name: str = "field",
        origin: tuple[float, float, float] | None = None,
    ) -> Field:
        """Build from local metres: ``parts`` = ``[[outer, hole, ...], ...]``, one entry per part.
        One part gives the same Field as :meth:`from_coords`; several give a MultiPolygon.
        Raises ValueError on an invalid part or on parts that overlap."""
        if not parts:
            raise ValueError("no polygon parts")
        multi = len(parts) > 1
        polys = []
        for k, rings in enumerate(parts):
            if not rings:
                raise ValueError(f"part {k + 1} has no rings")
            polys.append(_make_polygon(rings[0], rings[1:], f"part {k + 1}: " if multi else ""))
        if not multi:
            return cls(polys[0], name=name, origin=origin)
        for i in range(len(polys)):
            for j in range(i):
                ov = polys[i].intersection(polys[j]).area
                if ov > 1e-6:
                    raise ValueError(f"parts {j + 1} and {i + 1} overlap ({ov:.1f} m²); a field's "
                                     "parts must be disjoint (merge them into one polygon)")
        return cls(MultiPolygon(polys), name=name, origin=origin)

    @classmethod
    def from_lonlat_parts(
        cls,
        parts: Sequence[Sequence[np.ndarray]],
        origin: Sequence[float] | None = None,
        name: str = "field",
        meta: dict[str, Any] | None = None,
    ) -> Field:
        """Build from WGS-84 rings: ``parts`` = ``[[outer, hole, ...], ...]`` of (N, 2+) arrays of
        (lon, lat[, alt]) degrees. Converted to local ENU about ``origin`` = (lat, lon[, h]); by
        default the mean of the parts' outer-ring vertices."""
        ll = [[np.asarray(r, dtype=float) for r in rings] for rings in parts]
        for k, rings in enumerate(ll):
            for i, r in enumerate(rings):
                if r.ndim != 2 or r.shape[1] < 2 or len(r) == 0:
                    raise ValueError(f"ring {i} of part {k + 1}: expected [[lon, lat], ...]")
                if not np.all(np.isfinite(r[:, :2])):
                    raise ValueError(f"ring {i} of part {k + 1}: non-finite coordinates")
                if np.any(np.abs(r[:, 1]) > 90.0) or np.any(np.abs(r[:, 0]) > 180.0):
                    raise ValueError(f"ring {i} of part {k + 1}: coordinates out of range; "
                                     "expected WGS-84 longitude, latitude in degrees (GeoJSON "
                                     "and KML order is lon, lat)")
        if origin is None:
            outers = []
            for rings in ll:
                o = rings[0][:, :2]
                if len(o) > 1 and np.allclose(o[0], o[-1]):
                    o = o[:-1]
                outers.append(o)
            allv = np.concatenate(outers)
            org = (float(allv[:, 1].mean()), float(allv[:, 0].mean()), 0.0)
        else:
            org = (float(origin[0]), float(origin[1]),
                   float(origin[2]) if len(origin) > 2 else 0.0)
        # vertices at the origin's height: the ground the field lies on
        local = [[lonlat_to_enu(r[:, 0], r[:, 1], org, org[2])[:, :2] for r in rings]
                 for rings in ll]
        f = cls.from_parts(local, name=name, origin=org)
        f.meta.update(meta or {})
        return f

    @classmethod
    def from_geojson(
        cls,
        src: str | Path | dict,
        origin: Sequence[float] | None = None,
        name: str | None = None,
        select: str | None = None,
    ) -> Field:
        """Build from GeoJSON (RFC 7946, lon/lat WGS-84): a Polygon, MultiPolygon (every part is
        kept), GeometryCollection, Feature or FeatureCollection. ``src`` is a path, a JSON string
        or a parsed dict; ``select`` (``"KEY=VALUE"`` or ``"VALUE"`` for ``name=VALUE``) picks
        one feature of a collection. Coordinates are converted to local ENU about ``origin`` =
        (lat, lon[, h]); by default the mean of the outer rings' vertices."""
        fallback = "field"
        if isinstance(src, dict):
            gj = src
        else:
            s = str(src)
            if s.lstrip().startswith("{"):
                gj = _json_loads(s)
            else:
                p = Path(s)
                gj = _json_loads(_read_bytes(p, "GeoJSON"))
                fallback = p.stem
        if not isinstance(gj, dict):
            raise ValueError("GeoJSON: the top level must be an object")
        return _from_features(cls, _geojson_features(gj), select, "GeoJSON", origin, name,
                              fallback)

    @classmethod
    def from_kml(
        cls,
        src: str | Path | bytes,
        origin: Sequence[float] | None = None,
        name: str | None = None,
        select: str | None = None,
    ) -> Field:
        """Build from OGC KML 2.2 (a ``.kml`` path, a zipped ``.kmz`` path, or the KML bytes):
        the Placemark with a Polygon (or a MultiGeometry of them); ``select`` as in
        :meth:`from_geojson`, matched against the placemark's ``<name>`` and ExtendedData."""
        fallback = "field"
        if isinstance(src, bytes):
            data = src
        else:
            p = Path(src)
            fallback = p.stem
            data = _read_bytes(p, "KML")
            if p.suffix.lower() == ".kmz" or data[:2] == b"PK":
                data = _kmz_doc(p)
        return _from_features(cls, _kml_features(data), select, "KML", origin, name, fallback)

    @classmethod
    def from_shapefile(
        cls,
        path: str | Path,
        origin: Sequence[float] | None = None,
        name: str | None = None,
        select: str | None = None,
    ) -> Field:
        """Build from an ESRI shapefile (``.shp`` + ``.shx`` + ``.dbf``) of Polygon records in
        geographic lon/lat (read with pyshp); ``select`` as in :meth:`from_geojson`, matched
        against the record's attributes."""
        p = Path(path)
        return _from_features(cls, _shp_features(p), select, "shapefile", origin, name, p.stem)

    @classmethod
    def from_file(
        cls,
        path: str | Path,
        select: str | None = None,
        origin: Sequence[float] | None = None,
    ) -> Field:
        """Any supported file, by extension (:data:`FIELD_FILE_SUFFIXES`); see the module doc."""
        p = Path(path)
        suf = p.suffix.lower()
        if suf in (".geojson", ".json"):
            return cls.from_geojson(p, origin=origin, select=select)
        if suf in (".kml", ".kmz"):
            return cls.from_kml(p, origin=origin, select=select)
        if suf == ".shp":
            return cls.from_shapefile(p, origin=origin, select=select)
        raise ValueError(f"unknown field file type {suf or '(none)'!r}; allowed: "
                         f"{', '.join(FIELD_FILE_SUFFIXES)}")

    @classmethod
    def builtin(cls, name: str) -> Field:
        """A built-in field by name; see :data:`BUILTIN_FIELDS`."""
        return load_field(name)

    # --- properties ---------------------------------------------------------------------------
    @property
    def parts(self) -> list[Polygon]:
        """The field's parts (one polygon for a single-part field)."""
        if isinstance(self.polygon, MultiPolygon):
            return list(self.polygon.geoms)
        return [self.polygon]

    @property
    def area(self) -> float:
        """Area in m² (holes excluded)."""
        return float(self.polygon.area)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) in metres."""
        return tuple(float(v) for v in self.polygon.bounds)  # type: ignore[return-value]

    @property
    def exterior(self) -> np.ndarray:
        """Outer ring (closed) as an (N, 2) array; of the first part for a multi-part field (see
        :meth:`rings` for all)."""
        return np.asarray(self.parts[0].exterior.coords)[:, :2]

    @property
    def holes(self) -> list[np.ndarray]:
        """Hole rings (closed) as (N, 2) arrays; of the first part for a multi-part field (see
        :meth:`rings` for all)."""
        return [np.asarray(r.coords)[:, :2] for r in self.parts[0].interiors]

    def rings(self) -> list[tuple[np.ndarray, list[np.ndarray]]]:
        """``[(outer, [hole, ...]), ...]``: closed (N, 2) rings of every part."""
        return [(np.asarray(p.exterior.coords)[:, :2],
                 [np.asarray(r.coords)[:, :2] for r in p.interiors]) for p in self.parts]

    def to_geojson(self) -> dict:
        """GeoJSON Feature in lon/lat (needs ``origin``): a Polygon, or a MultiPolygon for a
        multi-part field (RFC 7946 winding: counter-clockwise boundaries, clockwise holes)."""
        if self.origin is None:
            raise ValueError("field has no geodetic origin; cannot export lon/lat")
        polys = []
        for outer, holes in self.rings():
            rings = []
            for r in [outer, *holes]:
                lon, lat = enu_to_lonlat(r[:, 0], r[:, 1], self.origin)
                rings.append([[round(float(a), 9), round(float(b), 9)]
                              for a, b in zip(lon, lat, strict=True)])
            polys.append(rings)
        geom = ({"type": "Polygon", "coordinates": polys[0]} if len(polys) == 1
                else {"type": "MultiPolygon", "coordinates": polys})
        return {"type": "Feature", "properties": {"name": self.name}, "geometry": geom}

    def __repr__(self) -> str:
        n_holes = sum(len(p.interiors) for p in self.parts)
        extra = f", parts={len(self.parts)}" if len(self.parts) > 1 else ""
        return f"Field(name={self.name!r}, area={self.area:.1f} m², holes={n_holes}{extra})"


# --- reading files ----------------------------------------------------------------------------
#: file name endings :func:`load_field` and :meth:`Field.from_file` accept
FIELD_FILE_SUFFIXES = (".geojson", ".json", ".kml", ".kmz", ".shp")


@dataclass
class _Feature:
    """One polygonal feature read from a file: its properties and its parts in lon/lat."""

    props: dict[str, Any]
    parts: list[list[np.ndarray]]


def _read_bytes(p: Path, what: str) -> bytes:
    try:
        return p.read_bytes()
    except FileNotFoundError:
        raise ValueError(f"{what} file not found: {p}") from None
    except OSError as e:
        raise ValueError(f"cannot read {what} file {p}: {e.strerror or e}") from None


def _json_loads(s: str | bytes) -> Any:
    try:
        return json.loads(s)
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"not valid JSON: {e}") from None


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


def _from_features(cls, feats: list[_Feature], select: str | None, what: str,
                   origin: Sequence[float] | None, name: str | None,
                   fallback: str = "field") -> Field:
    """Pick one feature (by ``select``) and build the Field; its name is ``name``, else the
    feature's ``name`` property, else ``fallback`` (the file's stem)."""
    if not feats:
        raise ValueError(f"{what}: no polygon found (need a Polygon or MultiPolygon)")
    if select is not None:
        key, val = _parse_selector(select)
        hits = [f for f in feats if _fmt_val(_prop_get(f.props, key)) == val
                and _prop_get(f.props, key) is not None]
        if len(hits) != 1:
            have = [_fmt_val(v) for f in feats if (v := _prop_get(f.props, key)) is not None]
            allowed = (", ".join(f'"{h}"' for h in have[:12]) + (" …" if len(have) > 12 else "")
                       if have else f"none of the {len(feats)} polygon features has a {key!r}")
            if len(hits) > 1:
                raise ValueError(f"{what}: {len(hits)} polygon features have {key} = \"{val}\"; "
                                 "pick by a property that is unique")
            raise ValueError(f"{what}: no polygon feature with {key} = \"{val}\"; "
                             f"{key} values: {allowed}")
        feat = hits[0]
    elif len(feats) > 1:
        names = [_fmt_val(v) for f in feats if (v := _prop_get(f.props, "name")) is not None]
        hint = (" (names: " + ", ".join(f'"{n}"' for n in names[:12]) + ")") if names else ""
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


def _geojson_features(gj: dict) -> list[_Feature]:
    t = gj.get("type")
    if t == "FeatureCollection":
        feats = gj.get("features")
        if not isinstance(feats, list):
            raise ValueError("GeoJSON FeatureCollection has no \"features\" list")
        out = []
        for f in feats:
            if isinstance(f, dict):
                out += _geojson_features(f) if f.get("type") == "Feature" else []
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


def _kml_features(data: bytes) -> list[_Feature]:
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


def _kmz_doc(p: Path) -> bytes:
    """The KML document inside a KMZ (``doc.kml``, else the first ``.kml`` entry)."""
    import zipfile

    try:
        with zipfile.ZipFile(p) as z:
            names = [n for n in z.namelist() if n.lower().endswith(".kml")]
            if not names:
                raise ValueError(f"KMZ {p} holds no .kml document")
            name = "doc.kml" if "doc.kml" in names else names[0]
            return z.read(name)
    except zipfile.BadZipFile as e:
        raise ValueError(f"KMZ {p} is not a valid zip archive: {e}") from None


# shapefile ------------------------------------------------------------------------------------
def _group_rings(rings: list[np.ndarray]) -> list[list[np.ndarray]]:
    """Sort rings into parts by containment (even nesting depth = boundary, odd = hole of the
    smallest boundary around it); winding is ignored."""
    polys = [Polygon(r[:, :2]) for r in rings]  # callers pass rings of >= 3 points
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


def _shp_features(p: Path) -> list[_Feature]:
    import shapefile  # pyshp

    if not p.exists():
        raise ValueError(f"shapefile not found: {p}")
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
                pts = np.asarray(shp.points, dtype=float)[:, :2]
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


# --- built-in fields ------------------------------------------------------------------------
#: "default": a slightly skewed quadrilateral farm field in local metres (~1.05 ha);
#: "l-shape" and "hole": GeoJSON lon/lat files in ag_uav/data/ near Moscow, Idaho;
#: "two-part": a two-part MultiPolygon there (a 40 m × 24 m rectangle and a 36 m × 30 m
#: quadrilateral 30 m apart, 0.20 ha).
BUILTIN_FIELDS = ("default", "l-shape", "hole", "two-part")

_DEFAULT_OUTER = [(0.0, 0.0), (112.0, 5.0), (116.0, 96.0), (-3.0, 90.0)]

#: The geodetic origin (lat °, lon °, WGS-84 ellipsoidal height m) given to the fields in local
#: metres (the built-in ``"default"``) unless the config names one: a point in the Palouse
#: wheat country about 1 km south-west of the lon/lat built-in fields, west of Moscow, Idaho, USA.
#: The ground there lies about 780 m above sea level; 760 m is an approximate ellipsoidal
#: height (the geoid lies some 15-20 m below the ellipsoid in the region), used only for the
#: altitude the log's geographic topics report.
DEFAULT_ORIGIN = (46.7250, -117.0200, 760.0)


def _h(origin: Sequence[float]) -> float:
    return float(origin[2]) if len(origin) > 2 else 0.0


def split_field_spec(spec: str) -> tuple[str, str | None]:
    """``"path.geojson#name=North"`` → ``("path.geojson", "name=North")``; no ``#`` (or a file
    whose name holds one) → ``(spec, None)``."""
    if "#" in spec and not Path(spec).exists():
        path, _, sel = spec.partition("#")
        return path, sel
    return spec, None


def load_field(name: str, origin: Sequence[float] | None = None) -> Field:
    """Load a built-in field (:data:`BUILTIN_FIELDS`) or a field file
    (:data:`FIELD_FILE_SUFFIXES`), optionally with a feature selector: ``PATH#KEY=VALUE`` or
    ``PATH#VALUE`` (= ``#name=VALUE``). Raises ValueError with a one-line reason.

    ``origin`` = (lat, lon[, h]): a lon/lat field is projected about it instead of its own
    origin (the mean of its vertices, height 0); the local ``"default"`` field only takes it as
    its :attr:`Field.origin` (its metres stay as they are)."""
    path, select = split_field_spec(name)
    key = path.strip().lower().replace("_", "-")
    org = None if origin is None else tuple(float(v) for v in origin)
    if select is None and key == "default":
        return Field.from_coords(_DEFAULT_OUTER, name="default",
                                 origin=None if org is None else (*org[:2], _h(org)))
    if select is None and key in BUILTIN_FIELDS:
        ref = resources.files("ag_uav") / "data" / f"{key}.geojson"
        return Field.from_geojson(json.loads(ref.read_text()), name=key, origin=org)
    if key.endswith(FIELD_FILE_SUFFIXES):
        if not Path(path).exists():
            raise ValueError(f"file not found: {path}")
        return Field.from_file(path, select=select, origin=org)
    raise ValueError(f"unknown field {name!r}; built-in fields are {', '.join(BUILTIN_FIELDS)}"
                     f", or give a path to a {'/'.join(FIELD_FILE_SUFFIXES)} file "
                     "(optionally PATH#name=VALUE to pick one feature)")
