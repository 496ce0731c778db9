"""Geographic topics of the run log, for Foxglove's Map panel: where on the farm the drone flew.

Every run has a geodetic origin (:attr:`ag_uav.world.field.Field.origin`: a lon/lat field's own,
``mission.origin_*``, or :data:`ag_uav.world.field.DEFAULT_ORIGIN`); the local ENU metres the
simulation flies in are turned into WGS-84 latitude, longitude and ellipsoidal height by
:func:`ag_uav.world.field.enu_to_geodetic`, the exact inverse of the projection a lon/lat field
file was read with (so lon/lat → ENU → lon/lat round-trips to well under a millimetre).

Topics (the schemas the Foxglove SDK defines, ``foxglove.messages.LocationFix`` and
``foxglove.messages.GeoJson``; ``group`` is the run log's channel group):

==============  =====================  ======================================================
topic           schema                 what
==============  =====================  ======================================================
/geo/true       foxglove.LocationFix   the true position (group ``geo``: 5 Hz, light 1 Hz)
/geo/est        foxglove.LocationFix   the estimate that is flown (same rate; with one only)
/geo/gnss       foxglove.LocationFix   each GNSS fix as received (group ``gps``'s rate, needs
                                       ``geo`` on too): the receiver's reported variances as a
                                       diagonal ENU covariance (``DIAGONAL_KNOWN``; ``UNKNOWN``
                                       where none is finite), its fix type as ``color``
                                       (:data:`FIX_COLORS`) and as metadata ``fix_type``
/geo/field      foxglove.GeoJSON       the field: every part with its holes (at the start)
/geo/plan       foxglove.GeoJSON       the planned path: spray legs and transits
/geo/sprayed    foxglove.GeoJSON       the sprayed area (at the end)
/geo/dose       foxglove.GeoJSON       the dose on the ground in bands of the target rate
                                       (:data:`DOSE_BANDS`), at the ``/dose`` cadence
==============  =====================  ======================================================

GeoJSON is RFC 7946: positions ``[lon, lat]``, a geometry across the antimeridian cut in two
there (§3.1.9: a field at ±180° is two polygons on the map), rings closed, exterior rings
counter-clockwise and holes clockwise (in lon/lat, as shapely's ``orient_polygons`` leaves
them).  Each feature carries ``properties.name`` (Foxglove shows it as a tooltip) and
``properties.style`` (Leaflet path options: ``color``, ``weight``, ``opacity``, ``fillColor``,
``fillOpacity``, ``dashArray``), which the Map panel applies to the feature.

The LocationFix messages are hand-encoded (protobuf wire format, field numbers of the SDK's
``foxglove.LocationFix``; checked in the tests by decoding with the SDK's schema and with
Foxglove's TypeScript reader): fixed-layout ``struct`` records after each timestamp.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..world.geodesy import ecef_to_geodetic, enu_frame, split_antimeridian

__all__ = [
    "DOSE_BANDS",
    "FIX_COLORS",
    "GEO_TOPICS",
    "GeoFrame",
    "dose_geojson",
    "field_geojson",
    "fix_color",
    "location_fixes",
    "plan_geojson",
    "sprayed_geojson",
]

GEO_TOPICS = {"true": "/geo/true", "est": "/geo/est", "gnss": "/geo/gnss",
              "field": "/geo/field", "plan": "/geo/plan", "sprayed": "/geo/sprayed",
              "dose": "/geo/dose"}

#: RGBA of a GNSS fix on the map by its fix type (a name containing the key; first match):
#: RTK fixed green, RTK float amber, differential (DGPS, SBAS) orange, a stand-alone fix red
FIX_COLORS: tuple[tuple[str, tuple[float, float, float, float]], ...] = (
    ("fixed", (0.10, 0.75, 0.25, 1.0)),
    ("float", (1.00, 0.75, 0.00, 1.0)),
    ("dgps", (1.00, 0.45, 0.00, 1.0)),
    ("sbas", (1.00, 0.45, 0.00, 1.0)),
    ("single", (0.90, 0.10, 0.10, 1.0)),
    ("spp", (0.90, 0.10, 0.10, 1.0)),
)
#: a receiver that reports no fix type
NO_TYPE_COLOR = (0.25, 0.55, 1.00, 1.0)

#: the dose bands of ``/geo/dose``, as shares of the target rate: (low, high, name, colour);
#: 0.8 and 1.2 are the under- and over-dose bounds of the dose metrics
#: (:func:`ag_uav.world.deposition.dose_metrics`); below 5 % nothing is drawn
DOSE_BANDS: tuple[tuple[float, float, str, str], ...] = (
    (0.05, 0.8, "under-dosed (5-80 % of target)", "#ff8c00"),
    (0.8, 1.2, "on target (80-120 %)", "#22aa44"),
    (1.2, math.inf, "over-dosed (> 120 %)", "#8b00c8"),
)

#: decimal places of GeoJSON degrees: 1e-8 deg is ~1 mm
_DP = 8


def fix_color(fix_type: str | None) -> tuple[float, float, float, float]:
    """The map colour of a GNSS fix of ``fix_type`` (:data:`FIX_COLORS`)."""
    if not fix_type:
        return NO_TYPE_COLOR
    low = fix_type.lower()
    for key, rgba in FIX_COLORS:
        if key in low:
            return rgba
    return NO_TYPE_COLOR


class GeoFrame:
    """The run's local ENU frame on the WGS-84 ellipsoid: ``origin`` = (lat °, lon °, h m).
    Converts with :mod:`ag_uav.world.field`'s law (:func:`~ag_uav.world.field.enu_frame`,
    :func:`~ag_uav.world.geodesy.ecef_to_geodetic`), the frame's constants computed once."""

    def __init__(self, origin: Sequence[float]):
        lat, lon = float(origin[0]), float(origin[1])
        h = float(origin[2]) if len(origin) > 2 else 0.0
        if not (abs(lat) < 90.0 and abs(lon) <= 180.0 and math.isfinite(h)):
            raise ValueError(f"origin ({lat}, {lon}, {h}) is out of range; expected lat, lon in "
                             "degrees and a finite height")
        self.origin = (lat, lon, h)
        self._rot, self._p0 = enu_frame(self.origin)

    def lla(self, xyz: np.ndarray) -> np.ndarray:
        """(n, 3) ENU metres → (n, 3) latitude °, longitude °, ellipsoidal height m."""
        lon, lat, h = ecef_to_geodetic(np.asarray(xyz, dtype=float) @ self._rot + self._p0)
        return np.stack([lat, lon, h], axis=1)

    def lonlat_array(self, xy: np.ndarray) -> np.ndarray:
        """(n, 2) ENU metres on the ground plane (u = 0) → (n, 2) lon, lat (°)."""
        a = np.asarray(xy, dtype=float).reshape(-1, 2)
        lon, lat, _ = ecef_to_geodetic(a @ self._rot[:2] + self._p0)
        return np.stack([lon, lat], axis=1)

    def lonlat(self, xy: Any) -> list[list[float]]:
        """(n, 2) ENU metres on the ground plane → ``[[lon, lat], ...]`` (GeoJSON positions)."""
        return np.round(self.lonlat_array(xy), _DP).tolist()


# --------------------------------------------------------------------------------------------
# foxglove.LocationFix
# --------------------------------------------------------------------------------------------

def _varint(v: int) -> bytes:
    """Protobuf base-128 varint of a non-negative int."""
    out = bytearray()
    while v >= 0x80:
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v)
    return bytes(out)


def _str_field(num: int, s: str) -> bytes:
    """A protobuf string field ``num``."""
    b = s.encode()
    return _varint((num << 3) | 2) + _varint(len(b)) + b


def _stamp6(tn: int) -> bytes:
    """LocationFix's ``timestamp`` (field 6): a google.protobuf.Timestamp of ``tn`` ns (zero
    halves omitted)."""
    sec, nsec = divmod(tn, 1_000_000_000)
    body = (b"\x08" + _varint(sec) if sec else b"") + (b"\x10" + _varint(nsec) if nsec else b"")
    return b"\x32" + bytes((len(body),)) + body


def geojson_message(text: str) -> bytes:
    """A ``foxglove.GeoJSON`` message (its one field, ``geojson``)."""
    return _str_field(1, text)


_FIX = struct.Struct("<BdBdBd")  # latitude (1), longitude (2), altitude (3)
_COV = struct.Struct("<BB9dBB")  # position_covariance (4, packed), its type (5)
_COLOR = struct.Struct("<BBBdBdBdBd")  # color (8): r, g, b, a


def location_fixes(tns: Sequence[int], lla: np.ndarray, *, head: bytes = b"",
                   var_enu: np.ndarray | None = None, rgba: np.ndarray | None = None,
                   tails: Sequence[bytes] | None = None) -> list[bytes]:
    """``foxglove.LocationFix`` messages, one per row of ``lla`` ((n, 3): latitude, longitude,
    altitude) at log times ``tns`` (ns).  ``head``: bytes written after the timestamp (the
    ``frame_id`` field); ``var_enu`` (n, 3): the position variances east, north, up (m²) as a
    diagonal covariance, ``DIAGONAL_KNOWN`` where all three are finite, else ``UNKNOWN`` with
    zeros; ``rgba`` (n, 4): the ``color``; ``tails[j]``: bytes after message j (metadata)."""
    rows = np.asarray(lla, dtype=float).tolist()
    var = None if var_enu is None else np.asarray(var_enu, dtype=float).tolist()
    col = None if rgba is None else np.asarray(rgba, dtype=float).tolist()
    out = []
    for j, tn in enumerate(tns):
        lat, lon, alt = rows[j]
        msg = _stamp6(int(tn)) + head + _FIX.pack(0x09, lat, 0x11, lon, 0x19, alt)
        if var is not None:
            e, n, u = var[j]
            if math.isfinite(e) and math.isfinite(n) and math.isfinite(u):
                msg += _COV.pack(0x22, 72, e, 0.0, 0.0, 0.0, n, 0.0, 0.0, 0.0, u, 0x28, 2)
            else:
                msg += _COV.pack(0x22, 72, *([0.0] * 9), 0x28, 0)
        if col is not None:
            r, g, b, a = col[j]
            msg += _COLOR.pack(0x42, 36, 0x09, r, 0x11, g, 0x19, b, 0x21, a)
        out.append(msg + tails[j] if tails is not None else msg)
    return out


def kv_metadata(key: str, value: str) -> bytes:
    """``metadata`` (field 9) entry ``key = value`` of a LocationFix (a KeyValuePair)."""
    body = _str_field(1, key) + _str_field(2, value)
    return b"\x4a" + _varint(len(body)) + body


# --------------------------------------------------------------------------------------------
# foxglove.GeoJSON
# --------------------------------------------------------------------------------------------

def _style(**kw: Any) -> dict[str, Any]:
    """Leaflet path options from snake_case keywords (``fill_color`` → ``fillColor``)."""
    return {k.split("_")[0] + "".join(w.capitalize() for w in k.split("_")[1:]): v
            for k, v in kw.items()}


def _valid_ll(shell: Any, holes: list[Any]) -> list[list[list[list[float]]]]:
    """A polygon of lon/lat rings (rounded to :data:`_DP` places) → GeoJSON polygons: valid
    (a sliver the rounding made self-touching is repaired by ``make_valid``, which may split
    it), cut at the antimeridian (:func:`~ag_uav.world.geodesy.split_antimeridian`: a field
    across ±180° becomes two polygons, not one that jumps across the map), oriented the RFC 7946
    way (exterior counter-clockwise, holes clockwise), closed."""
    import shapely

    parts = []
    for p in split_antimeridian(shapely.Polygon(shell, holes)):  # RFC 7946 §3.1.9
        parts += [p] if p.is_valid else _polys(shapely.make_valid(p))
    out = []
    for p in parts:
        p = shapely.orient_polygons(p, exterior_cw=False)
        if p.is_valid and p.area > 0:
            out.append([np.round(np.asarray(r.coords), _DP).tolist()
                        for r in (p.exterior, *p.interiors)])
    return out


def _polygon_coords(frame: GeoFrame, poly: Any) -> list[list[list[list[float]]]]:
    """A shapely polygon in ENU metres → GeoJSON polygons in lon/lat (:func:`_valid_ll`)."""
    return _valid_ll(frame.lonlat(np.asarray(poly.exterior.coords)[:, :2]),
                     [frame.lonlat(np.asarray(r.coords)[:, :2]) for r in poly.interiors])


def _polys(geom: Any) -> list[Any]:
    """The polygons of a shapely geometry (a Polygon, MultiPolygon or collection)."""
    if geom is None or geom.is_empty:
        return []
    if geom.geom_type == "Polygon":
        return [geom]
    return [g for part in getattr(geom, "geoms", []) for g in _polys(part)]


def _multipolygon(frame: GeoFrame, polys: list[Any]) -> dict[str, Any] | None:
    coords = [c for p in polys if not p.is_empty and p.area > 0
              for c in _polygon_coords(frame, p)]
    if not coords:
        return None
    if len(coords) == 1:
        return {"type": "Polygon", "coordinates": coords[0]}
    return {"type": "MultiPolygon", "coordinates": coords}


def _collection(features: list[dict[str, Any]]) -> str:
    return json.dumps({"type": "FeatureCollection", "features": features},
                      separators=(",", ":"), ensure_ascii=False)


def field_geojson(frame: GeoFrame, parts: list[tuple[Any, list[Any]]], name: str = "field",
                  ) -> str:
    """The field (``parts`` = ``[(outer, [hole, ...]), ...]``, rings in ENU metres) as one
    feature: a Polygon, or a MultiPolygon of several parts, holes kept."""
    import shapely

    polys = [shapely.Polygon(np.asarray(o, float)[:, :2], [np.asarray(h, float)[:, :2]
                                                           for h in hs]) for o, hs in parts]
    geom = _multipolygon(frame, polys)
    feats = [] if geom is None else [{
        "type": "Feature", "geometry": geom,
        "properties": {"name": f"field {name}: {sum(p.area for p in polys) / 1e4:.2f} ha",
                       "style": _style(color="#e0c040", weight=3, fill_color="#8c7340",
                                       fill_opacity=0.25)}}]
    return _collection(feats)


def _line(ll: list[list[float]]) -> dict[str, Any]:
    """A GeoJSON LineString of lon/lat positions, or a MultiLineString of its pieces where it
    crosses the antimeridian (RFC 7946 §3.1.9)."""
    import shapely

    line = shapely.LineString(ll)
    pieces = split_antimeridian(line)
    if len(pieces) == 1 and pieces[0] is line:
        return {"type": "LineString", "coordinates": ll}
    return {"type": "MultiLineString",
            "coordinates": [np.round(np.asarray(g.coords), _DP).tolist() for g in pieces]}


def plan_geojson(frame: GeoFrame, segments: list[tuple[str, Any, bool]]) -> str:
    """The planned path: one LineString feature per segment (spray legs green, transits grey
    and dashed), in flight order."""
    feats = []
    for k, (kind, pts, spray) in enumerate(segments):
        p = np.asarray(pts, dtype=float)
        if len(p) < 2:
            continue
        st = (_style(color="#22cc44", weight=2, opacity=0.9) if spray else
              _style(color="#909090", weight=2, opacity=0.8, dash_array="4 4"))
        feats.append({"type": "Feature", "geometry": _line(frame.lonlat(p[:, :2])),
                      "properties": {"name": f"{k + 1}: {kind}" + (" (spray)" if spray else ""),
                                     "style": st}})
    return _collection(feats)


def sprayed_geojson(frame: GeoFrame, geoms: list[Any]) -> str:
    """The sprayed area (shapely polygons in ENU metres) as one (Multi)Polygon feature."""
    polys = [p for g in geoms for p in _polys(g)]
    geom = _multipolygon(frame, polys)
    feats = [] if geom is None else [{
        "type": "Feature", "geometry": geom,
        "properties": {"name": f"sprayed: {sum(p.area for p in polys) / 1e4:.2f} ha",
                       "style": _style(color="#1ab2ff", weight=1, fill_color="#1ab2ff",
                                       fill_opacity=0.35)}}]
    return _collection(feats)


#: the most contour vertices a ``/geo/dose`` message holds: a finer map is block-averaged
#: (cells doubled) until its bands fit, which bounds the message (~30 bytes a vertex) and the
#: writer's time on it, however ragged the dose
DOSE_MAX_POINTS = 10_000


def _coarsen(a: np.ndarray) -> np.ndarray:
    """Block means of 2 × 2 cells (a last odd row or column padded with its edge)."""
    a = np.pad(a, ((0, a.shape[0] % 2), (0, a.shape[1] % 2)), mode="edge")
    return 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])


def _band_polygons(points: list[np.ndarray], offsets: list[np.ndarray], tol: float) -> list[Any]:
    """contourpy's filled polygons of one band (OuterOffset) → shapely polygons simplified to
    ``tol`` (Douglas-Peucker; a polygon the simplification would make invalid or empty is kept
    as it was), exteriors counter-clockwise, holes clockwise."""
    import shapely

    polys = np.array([shapely.Polygon(pts[offs[0]:offs[1]],
                                      [pts[offs[k]:offs[k + 1]] for k in range(1, len(offs) - 1)])
                      for pts, offs in zip(points, offsets, strict=True)], dtype=object)
    if not len(polys):
        return []
    simp = shapely.simplify(polys, tol, preserve_topology=False) if tol > 0 else polys
    ok = shapely.is_valid(simp) & ~shapely.is_empty(simp) & (shapely.get_type_id(simp) == 3)
    polys = np.where(ok, simp, polys)
    polys = polys[shapely.is_valid(polys) & (shapely.area(polys) > 0)]
    return list(shapely.orient_polygons(polys, exterior_cw=False))


def dose_bands(x0: float, y0: float, cell: float, l_per_ha: np.ndarray, target: float,
               max_points: int = DOSE_MAX_POINTS, simplify: float = 0.5,
               ) -> tuple[float, list[tuple[Any, ...]]]:
    """The dose map ((ny, nx) L/ha, cell (j, i) centred at (x0 + (i + ½)·cell, y0 +
    (j + ½)·cell)) cut into :data:`DOSE_BANDS` of ``target`` L/ha by filled contours
    (contourpy, marching squares between cell centres; the polygons of one band are disjoint),
    simplified to ``simplify`` cells (below the map's own resolution: the contours' staircase).
    Returns ``(cell used, [(name, colour, polygons, area m²), ...])`` of the bands that hold
    any area, each polygon a list of closed (k, 2) rings in ENU metres, its exterior
    counter-clockwise and its holes clockwise.  A map whose bands would still exceed
    ``max_points`` vertices is block-averaged (cells doubled) until they fit."""
    import contourpy

    a = np.nan_to_num(np.asarray(l_per_ha, dtype=float) / target) if target > 0 else None
    while a is not None and a.ndim == 2 and min(a.shape) >= 2:
        ny, nx = a.shape
        gen = contourpy.contour_generator(x0 + (np.arange(nx) + 0.5) * cell,
                                          y0 + (np.arange(ny) + 0.5) * cell, a,
                                          fill_type=contourpy.FillType.OuterOffset)
        out, n = [], 0
        for lo, hi, name, col in DOSE_BANDS:
            polys = _band_polygons(*gen.filled(lo, hi if math.isfinite(hi) else 1e30),
                                   simplify * cell)
            if polys:
                rings = [[np.asarray(p.exterior.coords), *(np.asarray(r.coords)
                                                           for r in p.interiors)]
                         for p in polys]
                n += sum(len(r) for p in rings for r in p)
                out.append((name, col, rings, float(sum(p.area for p in polys))))
        if n <= max_points:
            return cell, out
        a, cell = _coarsen(a), 2.0 * cell
    return cell, []


def dose_geojson(frame: GeoFrame, x0: float, y0: float, cell: float, l_per_ha: np.ndarray,
                 target: float) -> str:
    """The dose map as one (Multi)Polygon feature per :data:`DOSE_BANDS` band (filled in the
    band's colour; the name gives the band and its area), all vertices converted to lon/lat in
    one call."""
    used, bands = dose_bands(x0, y0, cell, l_per_ha, target)
    rings = [r for _, _, polys, _ in bands for p in polys for r in p]
    if not rings:
        return _collection([])
    ll = np.round(frame.lonlat_array(np.concatenate(rings)), _DP)
    ends = np.cumsum([len(r) for r in rings])
    it = iter(np.split(ll, ends[:-1]))
    feats = []
    for name, col, polys, area in bands:
        coords = []
        for p in polys:
            ring = [next(it) for _ in p]
            coords += _valid_ll(ring[0], ring[1:])
        if not coords:
            continue
        geom = ({"type": "Polygon", "coordinates": coords[0]} if len(coords) == 1
                else {"type": "MultiPolygon", "coordinates": coords})
        feats.append({"type": "Feature", "geometry": geom, "properties": {
            "name": f"dose {name}: {area:.0f} m² (contours of {used:g} m cells, simplified)",
            "style": _style(color=col, weight=0, fill_color=col, fill_opacity=0.45)}})
    return _collection(feats)
