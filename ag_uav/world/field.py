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
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.polygon import orient
from shapely.validation import explain_validity

from numkit.axes import XY

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
    "write_rect_field",
    "WGS84_A",
    "WGS84_B",
    "WGS84_E2",
    "WGS84_F",
]

from .field_files import (
    FIELD_FILE_SUFFIXES,
    from_features,
    geojson_features,
    json_loads,
    kml_features,
    kmz_doc,
    read_bytes,
    shp_features,
)
from .geodesy import (
    ORIGIN,
    WGS84_A,
    WGS84_B,
    WGS84_E2,
    WGS84_F,
    ecef_to_geodetic,
    enu_frame,
    enu_to_geodetic,
    enu_to_lonlat,
    geodetic_to_ecef,
    lonlat_centre,
    lonlat_to_enu,
    origin_height,
    pole_winding,
    split_polygon_rings,
)

#: the widest a lon/lat field may be (m): its projection about one origin stays a good plane
#: (:mod:`ag_uav.world.mission` also asks every vertex to lie within 20 km of the origin)
MAX_FIELD_SPAN_M = 40_000.0
_METRES = ("; a file in local metres (x, y) must be converted to lon/lat (RFC 7946 §3.1.1: "
           "positions are longitude, latitude in degrees)")


def _extent(r: np.ndarray) -> str:
    return (f"x/lon {r[:, 0].min():g} to {r[:, 0].max():g}, y/lat {r[:, 1].min():g} to "
            f"{r[:, 1].max():g}")


def _check_span(local: list[list[np.ndarray]], ll: list[list[np.ndarray]]) -> None:
    """Refuse a lon/lat field wider than :data:`MAX_FIELD_SPAN_M` on the ground: no sprayed
    field is, and numbers that read as degrees 100 km apart are most often a file written in
    local metres (the message says so, with the numbers' extent)."""
    xy = np.concatenate([r for rings in local for r in rings])
    span = float(max(np.ptp(xy[:, 0]), np.ptp(xy[:, 1])))
    if span > MAX_FIELD_SPAN_M:
        allv = np.concatenate([r[:, XY] for rings in ll for r in rings])
        raise ValueError(f"read as lon/lat degrees ({_extent(allv)}) the field spans "
                         f"{span / 1000:.1f} km, more than the {MAX_FIELD_SPAN_M / 1000:g} km "
                         f"a field may span{_METRES}")


def _check_lonlat_ring(r: np.ndarray, where: str) -> None:
    """One lon/lat ring: (N, 2+) finite degrees in range, not around a pole."""
    if r.ndim != 2 or r.shape[1] < 2 or len(r) == 0:
        raise ValueError(f"{where}: expected [[lon, lat], ...]")
    if not np.all(np.isfinite(r[:, XY])):
        raise ValueError(f"{where}: non-finite coordinates")
    if np.any(np.abs(r[:, 1]) > 90.0) or np.any(np.abs(r[:, 0]) > 180.0):
        raise ValueError(f"{where}: coordinates out of range ({_extent(r)}); expected WGS-84 "
                         f"longitude, latitude in degrees (GeoJSON and KML order is lon, lat)"
                         f"{_METRES}")
    turns = abs(pole_winding(r[:, 0])) if len(r) >= 3 else 0
    if turns:
        pole = "North" if r[:, 1].mean() > 0 else "South"
        raise ValueError(f"{where} runs {turns} time(s) around the {pole} pole (its longitudes "
                         "go all the way round); a lon/lat ring cannot describe a polygon that "
                         "encloses a pole: split the field into parts beside it")


def _as_ring(pts: Iterable[Sequence[float]], what: str) -> np.ndarray:
    a = np.asarray(list(pts), dtype=float)
    if a.ndim != 2 or a.shape[0] == 0 or a.shape[1] < 2:
        raise ValueError(f"{what}: expected a sequence of (x, y) points, got shape {a.shape}")
    a = a[:, XY]
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
        default the centre of the parts' outer-ring vertices (:func:`lonlat_centre`: their mean,
        taken on the sphere for a field across ±180°).  Refused (ValueError, one line): a ring
        out of range or around a pole, and a field wider than :data:`MAX_FIELD_SPAN_M` (most
        often a file in local metres read as degrees; the message says so)."""
        ll = [[np.asarray(r, dtype=float) for r in rings] for rings in parts]
        for k, rings in enumerate(ll):
            for i, r in enumerate(rings):
                _check_lonlat_ring(r, f"ring {i} of part {k + 1}")
        if origin is None:
            outers = []
            for rings in ll:
                o = rings[0][:, XY]
                if len(o) > 1 and np.allclose(o[0], o[-1]):
                    o = o[:-1]
                outers.append(o)
            allv = np.concatenate(outers)
            org = (*lonlat_centre(allv[:, 0], allv[:, 1]), 0.0)
        else:
            org = (float(origin[ORIGIN.LAT]), float(origin[ORIGIN.LON]), origin_height(origin))
        # vertices at the origin's height: the ground the field lies on
        local = [[lonlat_to_enu(r[:, 0], r[:, 1], org, org[ORIGIN.H])[:, XY] for r in rings]
                 for rings in ll]
        _check_span(local, ll)
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
                gj = json_loads(s)
            else:
                p = Path(s)
                gj = json_loads(read_bytes(p, "GeoJSON"))
                fallback = p.stem
        if not isinstance(gj, dict):
            raise ValueError("GeoJSON: the top level must be an object")
        return from_features(cls, geojson_features(gj), select, "GeoJSON", origin, name,
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
            data = read_bytes(p, "KML")
            if p.suffix.lower() == ".kmz" or data.startswith(b"PK"):  # a zip
                data = kmz_doc(p)
        return from_features(cls, kml_features(data), select, "KML", origin, name, fallback)

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
        return from_features(cls, shp_features(p), select, "shapefile", origin, name, p.stem)

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
        return np.asarray(self.parts[0].exterior.coords)[:, XY]

    @property
    def holes(self) -> list[np.ndarray]:
        """Hole rings (closed) as (N, 2) arrays; of the first part for a multi-part field (see
        :meth:`rings` for all)."""
        return [np.asarray(r.coords)[:, XY] for r in self.parts[0].interiors]

    def rings(self) -> list[tuple[np.ndarray, list[np.ndarray]]]:
        """``[(outer, [hole, ...]), ...]``: closed (N, 2) rings of every part."""
        return [(np.asarray(p.exterior.coords)[:, XY],
                 [np.asarray(r.coords)[:, XY] for r in p.interiors]) for p in self.parts]

    def to_geojson(self) -> dict:
        """GeoJSON Feature in lon/lat (needs ``origin``): a Polygon, or a MultiPolygon for a
        multi-part field or one cut at the antimeridian (RFC 7946 §3.1.9; its winding:
        counter-clockwise boundaries, clockwise holes)."""
        if self.origin is None:
            raise ValueError("field has no geodetic origin; cannot export lon/lat")
        polys = []
        for outer, holes in self.rings():
            rings = []
            for r in [outer, *holes]:
                lon, lat = enu_to_lonlat(r[:, 0], r[:, 1], self.origin)
                rings.append([[round(float(a), 9), round(float(b), 9)]
                              for a, b in zip(lon, lat, strict=True)])
            polys += split_polygon_rings(rings)   # cut at ±180° (RFC 7946 §3.1.9)
        geom = ({"type": "Polygon", "coordinates": polys[0]} if len(polys) == 1
                else {"type": "MultiPolygon", "coordinates": polys})
        return {"type": "Feature", "properties": {"name": self.name}, "geometry": geom}

    def __repr__(self) -> str:
        n_holes = sum(len(p.interiors) for p in self.parts)
        extra = f", parts={len(self.parts)}" if len(self.parts) > 1 else ""
        return f"Field(name={self.name!r}, area={self.area:.1f} m², holes={n_holes}{extra})"



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
        full = None if org is None else (org[ORIGIN.LAT], org[ORIGIN.LON], origin_height(org))
        return Field.from_coords(_DEFAULT_OUTER, name="default", origin=full)
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


def write_rect_field(path: str | Path, width_m: float, height_m: float,
                     lat0: float = 46.7300, lon0: float = -117.0000, name: str = "rect") -> Path:
    """Write a ``width_m × height_m`` rectangular field (east × north) as a GeoJSON polygon about
    (lat0, lon0): short missions for tests, benchmarks and quick experiments."""
    e = [0.0, width_m, width_m, 0.0, 0.0]
    n = [0.0, 0.0, height_m, height_m, 0.0]
    lon, lat = enu_to_lonlat(e, n, (lat0, lon0, 0.0))
    ring = [[round(float(a), 10), round(float(b), 10)] for a, b in zip(lon, lat, strict=True)]
    gj = {"type": "Feature", "properties": {"name": name},
          "geometry": {"type": "Polygon", "coordinates": [ring]}}
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(gj))
    return p
