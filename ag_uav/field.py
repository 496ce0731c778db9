"""Field geometry: a polygon in local ENU metres, with optional holes (obstacles).

A :class:`Field` wraps a :class:`shapely.geometry.Polygon` whose coordinates are east/north metres
in a local tangent plane. Fields are built from local coordinates (:meth:`Field.from_coords`), from
a GeoJSON polygon in WGS-84 lon/lat (:meth:`Field.from_geojson`) or by name
(:func:`load_field` / :meth:`Field.builtin`).

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
100 m apart bows by < 1 mm). The inverse (:func:`enu_to_lonlat`) uses ECEF → geodetic with
Bowring's iteration, accurate to < 1e-9 deg here.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient
from shapely.validation import explain_validity

__all__ = [
    "BUILTIN_FIELDS",
    "Field",
    "enu_to_lonlat",
    "geodetic_to_ecef",
    "load_field",
    "lonlat_to_enu",
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


def enu_to_lonlat(e, n, origin: Sequence[float], u=0.0) -> tuple[np.ndarray, np.ndarray]:
    """Local ENU metres → (lon, lat) degrees; inverse of :func:`lonlat_to_enu`.

    ENU → ECEF by the transposed rotation, then ECEF → geodetic with Bowring's parametric-latitude
    iteration (3 rounds; converged to ~1e-12 rad for terrestrial heights)."""
    lat0, lon0 = float(origin[0]), float(origin[1])
    h0 = float(origin[2]) if len(origin) > 2 else 0.0
    enu = np.stack(np.broadcast_arrays(np.asarray(e, float), np.asarray(n, float),
                                       np.asarray(u, float)), axis=-1)
    xyz = enu @ _enu_rotation(lat0, lon0) + geodetic_to_ecef(lat0, lon0, h0)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    ep2 = (WGS84_A**2 - WGS84_B**2) / WGS84_B**2
    beta = np.arctan2(z, (1.0 - WGS84_F) * p)
    for _ in range(3):
        lat = np.arctan2(z + ep2 * WGS84_B * np.sin(beta) ** 3,
                         p - WGS84_E2 * WGS84_A * np.cos(beta) ** 3)
        beta = np.arctan2((1.0 - WGS84_F) * np.sin(lat), np.cos(lat))
    return np.degrees(lon), np.degrees(lat)


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


@dataclass
class Field:
    """A field polygon in local ENU metres (x = east, y = north), with optional holes.

    Attributes:
        polygon: the shapely polygon (exterior = boundary, interiors = obstacles / no-spray holes).
        name: a label.
        origin: (lat, lon, h) of the local frame's origin when built from geodetic data, else None.
    """

    polygon: Polygon
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
        closing point optional). Raises ValueError on a degenerate or invalid polygon."""
        shell = _as_ring(outer, "outer boundary")
        rings = [_as_ring(h, f"hole {i}") for i, h in enumerate(holes)]
        shell_poly = Polygon(shell)
        c = shell - shell.mean(axis=0)
        if np.linalg.svd(c, compute_uv=False)[-1] <= 1e-9 * max(1.0, float(np.abs(c).max())):
            raise ValueError("outer boundary has zero area (collinear or repeated points)")
        if not shell_poly.is_valid:
            raise ValueError(
                f"outer boundary is not a valid simple polygon: {explain_validity(shell_poly)}"
                " (self-intersecting? check the vertex order)"
            )
        for i, h in enumerate(rings):
            hp = Polygon(h)
            if hp.area <= 1e-9:
                raise ValueError(f"hole {i} has zero area")
            if not hp.is_valid:
                raise ValueError(f"hole {i} is not a valid simple polygon: {explain_validity(hp)}")
            if not shell_poly.contains(hp):
                raise ValueError(f"hole {i} is not inside the outer boundary")
            for j in range(i):
                if hp.intersects(Polygon(rings[j])):
                    raise ValueError(f"holes {j} and {i} overlap or touch; merge them into one")
        poly = Polygon(shell, rings)
        if not poly.is_valid:
            raise ValueError(f"field polygon is invalid: {explain_validity(poly)}")
        if poly.area <= 1e-9:
            raise ValueError("field has zero area")
        poly = Polygon(poly.exterior.coords, [r.coords for r in poly.interiors])

        return cls(orient(poly, 1.0), name=name, origin=origin)

    @classmethod
    def from_geojson(
        cls,
        src: str | Path | dict,
        origin: Sequence[float] | None = None,
        name: str | None = None,
    ) -> Field:
        """Build from a GeoJSON Polygon (lon/lat, WGS-84), or a Feature / FeatureCollection holding
        exactly one Polygon (a one-part MultiPolygon is accepted). ``src`` is a path, a JSON
        string or a parsed dict. Coordinates are converted to local ENU about ``origin`` =
        (lat, lon[, h]); by default the mean of the outer ring's vertices. The first ring is the
        boundary, further rings are holes."""
        if isinstance(src, dict):
            gj = src
        else:
            s = str(src)
            if s.lstrip().startswith("{"):
                gj = json.loads(s)
            else:
                p = Path(s)
                if not p.exists():
                    raise ValueError(f"GeoJSON file not found: {p}")
                gj = json.loads(p.read_text())
                name = name or p.stem
        geom, props = _extract_polygon(gj)
        rings = geom["coordinates"]
        if not rings:
            raise ValueError("GeoJSON Polygon has no rings")
        lonlat = [np.asarray(r, dtype=float) for r in rings]
        for i, r in enumerate(lonlat):
            if r.ndim != 2 or r.shape[1] < 2:
                raise ValueError(f"GeoJSON ring {i}: expected [[lon, lat], ...]")
            if np.any(np.abs(r[:, 1]) > 90.0) or np.any(np.abs(r[:, 0]) > 180.0):
                raise ValueError(
                    f"GeoJSON ring {i}: coordinates out of range; GeoJSON order is [lon, lat]"
                )
        if origin is None:
            outer = lonlat[0]
            if len(outer) > 1 and np.allclose(outer[0], outer[-1]):
                outer = outer[:-1]
            lat0, lon0 = float(outer[:, 1].mean()), float(outer[:, 0].mean())
            org = (lat0, lon0, 0.0)
        else:
            org = (float(origin[0]), float(origin[1]),
                   float(origin[2]) if len(origin) > 2 else 0.0)
        local = [lonlat_to_enu(r[:, 0], r[:, 1], org)[:, :2] for r in lonlat]
        nm = name or props.get("name") or "field"
        f = cls.from_coords(local[0], local[1:], name=nm, origin=org)
        f.meta.update({k: v for k, v in props.items() if k != "name"})
        return f

    @classmethod
    def builtin(cls, name: str) -> Field:
        """A built-in field by name; see :data:`BUILTIN_FIELDS`."""
        return load_field(name)

    # --- properties ---------------------------------------------------------------------------
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
        """Outer ring (closed) as an (N, 2) array."""
        return np.asarray(self.polygon.exterior.coords)[:, :2]

    @property
    def holes(self) -> list[np.ndarray]:
        """Hole rings (closed) as (N, 2) arrays."""
        return [np.asarray(r.coords)[:, :2] for r in self.polygon.interiors]

    def to_geojson(self) -> dict:
        """GeoJSON Feature in lon/lat (needs ``origin``)."""
        if self.origin is None:
            raise ValueError("field has no geodetic origin; cannot export lon/lat")
        rings = []
        for r in [self.exterior, *self.holes]:
            lon, lat = enu_to_lonlat(r[:, 0], r[:, 1], self.origin)
            rings.append([[round(float(a), 9), round(float(b), 9)]
                          for a, b in zip(lon, lat, strict=True)])
        return {
            "type": "Feature",
            "properties": {"name": self.name},
            "geometry": {"type": "Polygon", "coordinates": rings},
        }

    def __repr__(self) -> str:
        return (f"Field(name={self.name!r}, area={self.area:.1f} m², "
                f"holes={len(self.polygon.interiors)})")


def _extract_polygon(gj: dict) -> tuple[dict, dict]:
    t = gj.get("type")
    if t == "FeatureCollection":
        feats = [f for f in gj.get("features", []) if f.get("geometry")]
        polys = [f for f in feats if f["geometry"].get("type") in ("Polygon", "MultiPolygon")]
        if len(polys) != 1:
            raise ValueError(
                f"GeoJSON FeatureCollection must hold exactly one Polygon feature, "
                f"found {len(polys)}"
            )
        return _extract_polygon(polys[0])
    if t == "Feature":
        geom = gj.get("geometry") or {}
        g, _ = _extract_polygon(geom)
        return g, dict(gj.get("properties") or {})
    if t == "Polygon":
        return gj, {}
    if t == "MultiPolygon":
        parts = gj.get("coordinates", [])
        if len(parts) != 1:
            raise ValueError(f"GeoJSON MultiPolygon must have exactly one part, has {len(parts)}")
        return {"type": "Polygon", "coordinates": parts[0]}, {}
    raise ValueError(f"GeoJSON: expected a Polygon, Feature or FeatureCollection, got {t!r}")


# --- built-in fields ------------------------------------------------------------------------
#: "default": a slightly skewed quadrilateral farm field in local metres (~1.05 ha);
#: "l-shape" and "hole": GeoJSON lon/lat files in ag_uav/data/ near Moscow, Idaho.
BUILTIN_FIELDS = ("default", "l-shape", "hole")

_DEFAULT_OUTER = [(0.0, 0.0), (112.0, 5.0), (116.0, 96.0), (-3.0, 90.0)]


def load_field(name: str) -> Field:
    """Load a built-in field ("default", "l-shape", "hole"), or a GeoJSON file path."""
    key = name.strip().lower().replace("_", "-")
    if key == "default":
        return Field.from_coords(_DEFAULT_OUTER, name="default")
    if key in ("l-shape", "hole"):
        ref = resources.files("ag_uav") / "data" / f"{key}.geojson"
        return Field.from_geojson(json.loads(ref.read_text()), name=key)
    if key.endswith((".geojson", ".json")) and Path(name).exists():
        return Field.from_geojson(name)
    raise ValueError(f"unknown field {name!r}; built-in fields are {', '.join(BUILTIN_FIELDS)}"
                     " (or give a path to a .geojson file)")
