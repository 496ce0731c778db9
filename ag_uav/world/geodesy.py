"""WGS-84 geodesy for a field's local frame: geodetic <-> ECEF <-> local ENU (east, north, up)
about an origin, as :mod:`ag_uav.world.field` projects lon/lat polygons and the run log's
geographic topics invert it (:mod:`ag_uav.record.geo`).  The equations and their error are in
:mod:`ag_uav.world.field`'s docstring (NIMA TR8350.2 for the ellipsoid; Bowring's iteration for
ECEF -> geodetic).

Longitude wraps at ±180°: a field across the antimeridian or close to a pole has vertices whose
longitudes are far apart though the ground between them is not.  :func:`lonlat_centre` is the
automatic origin of such a field (the point under the mean of its vertices in ECEF, a mean on
the sphere rather than of the degrees), :func:`pole_winding` finds a ring that encloses a pole
(which no lon/lat ring can describe as a simple polygon), and :func:`split_antimeridian` cuts a
lon/lat geometry at ±180° as GeoJSON asks (RFC 7946 §3.1.9)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from numkit import Layout
from numkit.axes import XY, X, Y, Z

__all__ = ["WGS84_A", "WGS84_F", "WGS84_E2", "WGS84_B", "geodetic_to_ecef", "lonlat_to_enu",
           "enu_to_geodetic", "enu_frame", "ecef_to_geodetic", "enu_to_lonlat", "lonlat_centre",
           "pole_winding", "split_antimeridian", "ORIGIN", "origin_height"]

# WGS-84 ellipsoid
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
WGS84_B = WGS84_A * (1.0 - WGS84_F)

#: a geodetic origin ``(lat °, lon °[, h m])``, by name: ``origin[ORIGIN.LAT]``
ORIGIN = Layout("lat lon h").at


def origin_height(origin: Sequence[float]) -> float:
    """The height h (m) of ``origin`` = (lat, lon[, h]); 0 where it gives none."""
    return float(origin[ORIGIN.H]) if len(origin) > ORIGIN.H else 0.0


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
    lat0, lon0 = float(origin[ORIGIN.LAT]), float(origin[ORIGIN.LON])
    h0 = origin_height(origin)
    p = geodetic_to_ecef(lat_deg, lon_deg, h)
    p0 = geodetic_to_ecef(lat0, lon0, h0)
    return (p - p0) @ _enu_rotation(lat0, lon0).T


def enu_to_geodetic(e, n, origin: Sequence[float], u=0.0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local ENU metres → (lon, lat, h): degrees and WGS-84 ellipsoidal height (m); the exact
    inverse of :func:`lonlat_to_enu` (with its ``h``): ENU → ECEF by the transposed rotation,
    then :func:`ecef_to_geodetic`."""
    lat0, lon0 = float(origin[ORIGIN.LAT]), float(origin[ORIGIN.LON])
    h0 = origin_height(origin)
    enu = np.stack(np.broadcast_arrays(np.asarray(e, float), np.asarray(n, float),
                                       np.asarray(u, float)), axis=-1)
    xyz = enu @ _enu_rotation(lat0, lon0) + geodetic_to_ecef(lat0, lon0, h0)
    return ecef_to_geodetic(xyz)


def enu_frame(origin: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """(R, p0) of the ENU frame about ``origin`` = (lat, lon[, h]): ECEF = ENU @ R + p0 (what
    :func:`enu_to_geodetic` computes per call, for a caller converting many batches)."""
    lat0, lon0 = float(origin[ORIGIN.LAT]), float(origin[ORIGIN.LON])
    h0 = origin_height(origin)
    return _enu_rotation(lat0, lon0), geodetic_to_ecef(lat0, lon0, h0)


def ecef_to_geodetic(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF metres (..., 3) → (lon °, lat °, h m) on WGS-84: Bowring's parametric-latitude
    iteration (3 rounds; converged to ~1e-12 rad for terrestrial heights) and the height
    ``h = p cosφ + z sinφ − a sqrt(1 − e² sin²φ)`` (valid at every latitude)."""
    x, y, z = xyz[..., X], xyz[..., Y], xyz[..., Z]
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


def _wrap180(d: np.ndarray) -> np.ndarray:
    """Longitude differences into [-180, 180)."""
    return (np.asarray(d, dtype=float) + 180.0) % 360.0 - 180.0


def lonlat_centre(lon_deg: np.ndarray, lat_deg: np.ndarray) -> tuple[float, float]:
    """(lat, lon) of the vertices' centre: the plain means of the degrees where the longitudes
    span less than 180° (every field away from the antimeridian: the rule the field files have
    always been read with), else the geodetic point under the mean of the vertices in ECEF
    (:func:`geodetic_to_ecef` at h = 0, then :func:`ecef_to_geodetic`), which neither the
    antimeridian nor a pole can mislead."""
    lon, lat = np.asarray(lon_deg, float), np.asarray(lat_deg, float)
    if float(np.ptp(lon)) < 180.0:
        return float(lat.mean()), float(lon.mean())
    c = geodetic_to_ecef(lat, lon).mean(axis=0)
    lo, la, _ = ecef_to_geodetic(c)
    return float(la), float(lo)


def pole_winding(lon_deg: np.ndarray) -> int:
    """How many times a closed lon/lat ring winds around the pole: the sum of its steps in
    longitude, each taken the short way round (within ±180°), over 360° (0 for a ring that does
    not enclose a pole)."""
    lon = np.asarray(lon_deg, float)
    steps = _wrap180(np.diff(np.append(lon, lon[:1])))
    return int(round(float(steps.sum()) / 360.0))


def split_antimeridian(geom):
    """A shapely geometry in lon/lat degrees (a Polygon or a LineString) whose edges may jump
    across ±180° (a step of more than 180° in longitude is taken as the short way round, across
    the antimeridian) → a list of geometries of the same kind, none crossing it: the geometry
    is unwrapped to continuous longitudes, cut at ±180° and the pieces shifted back by 360°
    (RFC 7946 §3.1.9: "any geometry that crosses the antimeridian SHOULD be represented by
    cutting it in two").  A geometry that does not cross comes back alone, unchanged."""
    import shapely
    from shapely.affinity import translate

    rings = ([geom.exterior, *geom.interiors] if geom.geom_type == "Polygon" else [geom])
    if not any(np.any(np.abs(np.diff(np.asarray(r.coords)[:, 0])) > 180.0) for r in rings):
        return [geom]
    ref = float(np.asarray(rings[0].coords)[0, 0])

    def unwrap(r):
        a = np.asarray(r.coords, dtype=float)[:, XY].copy()
        a[:, 0] = a[0, 0] + np.concatenate([[0.0], np.cumsum(_wrap180(np.diff(a[:, 0])))])
        a[:, 0] += 360.0 * round((ref - a[0, 0]) / 360.0)  # every ring beside the first
        return a

    whole = (shapely.Polygon(unwrap(rings[0]), [unwrap(r) for r in rings[1:]])
             if geom.geom_type == "Polygon" else shapely.LineString(unwrap(rings[0])))
    if not whole.is_valid:  # a sliver that rounding made self-touching
        whole = shapely.make_valid(whole)
    out = []
    for k in (-1, 0, 1):
        part = whole.intersection(shapely.box(-180.0 + 360.0 * k, -90.0, 180.0 + 360.0 * k,
                                              90.0))
        for g in shapely.get_parts(part):  # the parts, a collection's members flattened
            for q in (shapely.get_parts(g) if hasattr(g, "geoms") else [g]):
                if q.geom_type == geom.geom_type and not q.is_empty:
                    out.append(translate(q, xoff=-360.0 * k))
    return out


def split_polygon_rings(rings: list[list[list[float]]]) -> list[list[list[list[float]]]]:
    """A GeoJSON polygon's lon/lat rings → the polygons it is, cut at the antimeridian where it
    crosses it (:func:`split_antimeridian`, RFC 7946 §3.1.9; the pieces
    oriented the RFC's way); a polygon that does not cross is returned as it is."""
    import shapely

    poly = shapely.Polygon(rings[0], rings[1:])
    pieces = split_antimeridian(poly)
    if len(pieces) == 1 and pieces[0] is poly:
        return [rings]
    return [[np.round(np.asarray(r.coords), 9).tolist() for r in (q.exterior, *q.interiors)]
            for q in (shapely.orient_polygons(p, exterior_cw=False) for p in pieces)]
