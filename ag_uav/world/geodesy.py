"""WGS-84 geodesy for a field's local frame: geodetic <-> ECEF <-> local ENU (east, north, up)
about an origin, as :mod:`ag_uav.world.field` projects lon/lat polygons and the run log's
geographic topics invert it (:mod:`ag_uav.record.geo`).  The equations and their error are in
:mod:`ag_uav.world.field`'s docstring (NIMA TR8350.2 for the ellipsoid; Bowring's iteration for
ECEF -> geodetic)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["WGS84_A", "WGS84_F", "WGS84_E2", "WGS84_B", "geodetic_to_ecef", "lonlat_to_enu",
           "enu_to_geodetic", "enu_frame", "ecef_to_geodetic", "enu_to_lonlat"]

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
