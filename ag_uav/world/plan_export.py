"""Coverage plans out of the simulator: GeoJSON, KML and QGroundControl ``.plan`` in lon/lat.

:func:`write_plan` writes a :class:`~ag_uav.world.plan.CoveragePlan` in the format its file
extension names (``.geojson``/``.json``, ``.kml``, ``.plan``). All three carry the same waypoints
(:func:`plan_waypoints`): the plan's polyline converted to WGS-84 lon/lat about the field's
geodetic origin (:func:`ag_uav.world.field.enu_to_lonlat`), sweep-leg ends exact, the densely
sampled U-turn arcs and transits thinned by Douglas–Peucker to ``simplify_m`` (default 0.2 m; an
autopilot rounds its own corners), and the points where the nozzles are commanded on and off:
``ag-uav plan`` puts each command ``v·d`` metres of path before the sprayed edge, d the
configured valve delay (``spray.nozzle_on_delay_s``; ``spray.nozzle_off_delay_s`` when a command
off is delayed too), so that the nozzles open and close where the plan sprays.

Formats:

* **GeoJSON** (RFC 7946): a FeatureCollection of the field (Polygon or MultiPolygon, property
  ``role = "field"`` plus the plan's swath, altitude, speed and lengths), one LineString per plan
  segment (``role = "path"``, ``kind``, ``spray``, ``index``; 2-D positions, the spray height is in
  ``altitude_m_agl``) and one Point per nozzle switch (``role = "spray_on"`` / ``"spray_off"``).
  :meth:`ag_uav.world.field.Field.from_geojson` reads the field back from it.  A polygon or a
  path across the antimeridian is cut there (RFC 7946 §3.1.9: two polygons, a MultiLineString).
* **KML** (OGC KML 2.2): a Document with the field Placemark (clamped to the ground), a ``path``
  Folder with one LineString Placemark per segment at the spray height
  (``altitudeMode = relativeToGround``; green when spraying, grey otherwise) and a ``nozzles``
  Folder of Points named ``spray on`` / ``spray off``.
* **QGroundControl plan** (JSON, ``fileType "Plan"``, version 1; mission version 2, ArduPilot
  (``firmwareType`` 3 = MAV_AUTOPILOT_ARDUPILOTMEGA), quadrotor (``vehicleType`` 2)). Mission items
  (``SimpleItem``, ``doJumpId`` 1, 2, …, ``autoContinue`` true):

  - ``MAV_CMD_NAV_TAKEOFF`` (22) to the spray height at the first waypoint;
  - ``MAV_CMD_DO_CHANGE_SPEED`` (178; param1 = 1 ground speed, param2 = the plan speed,
    param3 = −1 throttle unchanged);
  - one ``MAV_CMD_NAV_WAYPOINT`` (16) per waypoint, frame 3 (MAV_FRAME_GLOBAL_RELATIVE_ALT),
    params [hold 0, acceptance radius 0, pass radius 0, yaw NaN (written null: unchanged),
    lat, lon, spray height];
  - after the waypoint where the nozzles switch: ``MAV_CMD_DO_SPRAYER`` (216, MAVLink common:
    param1 = 1 spray on, 0 spray off; frame 2 = MAV_FRAME_MISSION). ArduPilot's Copter runs it
    with its sprayer library (``SPRAY_ENABLE``); PX4 ignores it.

  The mission ends at the last waypoint (what happens next is the autopilot's mission-end
  setting; no RTL item is added). ``plannedHomePosition`` = [lat, lon, origin height] of the
  first waypoint; ``geoFence`` and ``rallyPoints`` are empty.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from shapely.geometry import LineString

from numkit.axes import XY

from .geodesy import ORIGIN, enu_to_lonlat, origin_height, split_antimeridian, split_polygon_rings
from .plan import CoveragePlan

__all__ = [
    "PLAN_SUFFIXES",
    "Waypoint",
    "plan_to_geojson",
    "plan_to_kml",
    "plan_to_qgc",
    "nozzle_leads",
    "plan_waypoints",
    "write_plan",
]

#: file name endings :func:`write_plan` understands
PLAN_SUFFIXES = (".geojson", ".json", ".kml", ".plan")

MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_DO_SPRAYER = 216
MAV_FRAME_MISSION = 2
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_TYPE_QUADROTOR = 2

KML_NS = "http://www.opengis.net/kml/2.2"


@dataclass
class Waypoint:
    """One waypoint of an exported plan.

    Attributes:
        x, y: local ENU metres.
        lon, lat: WGS-84 degrees.
        spray: nozzles on while flying from this waypoint to the next (False at the last).
        kind: the kind of the plan segment that starts here ("end" at the last waypoint).
        event: "spray_on" / "spray_off" where the nozzles switch at this waypoint, else None.
    """

    x: float
    y: float
    lon: float
    lat: float
    spray: bool
    kind: str
    event: str | None


def _origin(plan: CoveragePlan, origin: Sequence[float] | None) -> tuple[float, float, float]:
    """The geodetic origin the plan's metres are exported about: ``origin`` for a field in local
    metres without one, else the field's own (an ``origin`` that differs from it would move
    every waypoint off the field, so it is refused)."""
    own = plan.field.origin
    if origin is not None and own is not None and not np.allclose(
            [float(origin[ORIGIN.LAT]), float(origin[ORIGIN.LON])],
            [own[ORIGIN.LAT], own[ORIGIN.LON]], rtol=0.0, atol=1e-12):
        raise ValueError(f"field {plan.field.name!r} is georeferenced about "
                         f"{own[ORIGIN.LAT]:.6f}, {own[ORIGIN.LON]:.6f}; another origin would move "
                         "every waypoint off the field "
                         "(project the field about a point instead: load_field(..., origin=))")
    o = origin if origin is not None else own
    if o is None:
        raise ValueError(f"field {plan.field.name!r} is in local metres with no geodetic origin; "
                         "give one (LAT,LON) to export lon/lat")
    lat, lon = float(o[ORIGIN.LAT]), float(o[ORIGIN.LON])
    if not (abs(lat) <= 90.0 and abs(lon) <= 180.0):
        raise ValueError(f"origin ({lat}, {lon}) is out of range; expected LAT,LON in degrees")
    return lat, lon, origin_height(o)


def _thin(points: np.ndarray, tol: float) -> np.ndarray:
    if len(points) <= 2 or tol <= 0:
        return np.asarray(points, float)
    return np.asarray(LineString(points).simplify(tol, preserve_topology=False).coords)[:, XY]


def plan_waypoints(plan: CoveragePlan, origin: Sequence[float] | None = None,
                   simplify_m: float = 0.2, lead_on_m: float = 0.0,
                   lead_off_m: float = 0.0) -> list[Waypoint]:
    """The plan's waypoints in order (shared segment joints once), in local metres and lon/lat.

    ``origin`` = (lat, lon[, h]): the geodetic origin of a field given in local metres without
    one; a field with its own origin is exported about it (another one raises ValueError).

    Each segment's polyline is thinned to ``simplify_m`` (its end points are kept, so every leg
    end and every nozzle switch is a waypoint).

    ``lead_on_m`` / ``lead_off_m``: the nozzle commands lead the sprayed edges by this much path
    (:func:`nozzle_leads`: v·d for a valve delay d at speed v), so that the nozzles open and close
    where the plan sprays: the command is a waypoint that many metres back along the path (not
    before the previous switch), and ``spray`` / ``event`` are the *commands*."""
    org = _origin(plan, origin)
    segs = plan.segments
    pts: list[np.ndarray] = []
    nxt: list[int] = []  # index of the segment that starts at each point (len(segs) = end)
    for k, s in enumerate(segs):
        q = _thin(s.points, simplify_m)
        for j in range(0 if k == 0 else 1, len(q)):
            if pts and float(np.hypot(*(q[j] - pts[-1]))) < 1e-6:
                nxt[-1] = k if j < len(q) - 1 else k + 1
                continue
            pts.append(q[j])
            nxt.append(k if j < len(q) - 1 else k + 1)
    kinds = [segs[k].kind if k < len(segs) else "end" for k in nxt]
    sprays = [bool(segs[k].spray) if k < len(segs) else False for k in nxt]
    if lead_on_m > 0 or lead_off_m > 0:
        _lead(pts, kinds, sprays, lead_on_m, lead_off_m)
    xy = np.asarray(pts)
    lon, lat = enu_to_lonlat(xy[:, 0], xy[:, 1], org)
    out: list[Waypoint] = []
    prev_spray = False
    for i, spray in enumerate(sprays):
        event = ("spray_on" if spray and not prev_spray else
                 "spray_off" if prev_spray and not spray else None)
        out.append(Waypoint(float(xy[i, 0]), float(xy[i, 1]), float(lon[i]), float(lat[i]),
                            spray, kinds[i], event))
        prev_spray = spray
    return out


def nozzle_leads(speed_mps: float, on_delay_s: float, off_delay_s: float,
                 cmd_off_immediate: bool = True) -> tuple[float, float]:
    """(on, off) lead in metres of path of the nozzle commands: v·d_on, and v·d_off unless a
    command off acts at once (ArduPilot ``AC_Sprayer::run(false)``; :mod:`ag_uav.world.
    deposition`)."""
    return speed_mps * on_delay_s, 0.0 if cmd_off_immediate else speed_mps * off_delay_s


def _lead(pts: list[np.ndarray], kinds: list[str], sprays: list[bool], lead_on: float,
          lead_off: float) -> None:
    """Move every switch of ``sprays`` back along the polyline ``pts`` by its lead, inserting a
    waypoint where the command falls inside a stretch (in place; last switch first)."""
    switches = [i for i in range(len(sprays)) if sprays[i] != (sprays[i - 1] if i else False)]
    for n in range(len(switches) - 1, -1, -1):
        i, lo = switches[n], (switches[n - 1] if n else 0)
        lead = lead_on if sprays[i] else lead_off
        if lead <= 0 or i <= lo:
            continue
        j, rest = i, lead
        while j > lo:
            d = float(np.hypot(*(pts[j] - pts[j - 1])))
            if d >= rest:
                break
            rest, j = rest - d, j - 1
        if j == lo:  # less path than the lead since the previous switch: just after it
            new = lo + 1 if n else 0
        elif rest < 1e-6:
            new = j
        else:
            d = float(np.hypot(*(pts[j] - pts[j - 1])))
            if d - rest < 1e-6:
                new = j - 1 if (j - 1 > lo or not n) else j
            else:
                q = pts[j] - (pts[j] - pts[j - 1]) * (rest / d)
                pts.insert(j, q)
                kinds.insert(j, kinds[j - 1])
                sprays.insert(j, sprays[j - 1])
                new, i = j, i + 1
        for m in range(new, i):
            sprays[m] = sprays[i]


def _plan_props(plan: CoveragePlan, altitude: float, speed: float) -> dict[str, Any]:
    lanes = plan.meta.get("lanes")
    out = {"swath_m": plan.swath, "leg_spacing_m": round(plan.spacing, 3),
           "altitude_m_agl": altitude, "speed_mps": speed,
           "legs": plan.legs, "path_length_m": round(plan.length, 2),
            "spray_length_m": round(plan.spray_length, 2),
            "parts": len(plan.field.parts)}
    if lanes is not None:
        out["lanes"] = lanes.text()
    return out


def _ll(x: np.ndarray, y: np.ndarray, org) -> list[list[float]]:
    lon, lat = enu_to_lonlat(x, y, org)
    return [[round(float(a), 9), round(float(b), 9)] for a, b in zip(lon, lat, strict=True)]


def _split_line(coords: list[list[float]]) -> dict[str, Any]:
    """A GeoJSON LineString, or a MultiLineString of its pieces where it crosses the
    antimeridian (RFC 7946 §3.1.9)."""
    line = LineString(coords)
    pieces = split_antimeridian(line)
    if len(pieces) == 1 and pieces[0] is line:
        return {"type": "LineString", "coordinates": coords}
    return {"type": "MultiLineString",
            "coordinates": [np.round(np.asarray(g.coords), 9).tolist() for g in pieces]}


def plan_to_geojson(plan: CoveragePlan, *, altitude: float, speed: float,
                    origin: Sequence[float] | None = None, simplify_m: float = 0.2,
                    leads: tuple[float, float] = (0.0, 0.0)) -> dict:
    """The plan as a GeoJSON FeatureCollection (see the module doc)."""
    org = _origin(plan, origin)
    polys = []
    for outer, holes in plan.field.rings():
        polys += split_polygon_rings([_ll(r[:, 0], r[:, 1], org) for r in [outer, *holes]])
    geom = ({"type": "Polygon", "coordinates": polys[0]} if len(polys) == 1
            else {"type": "MultiPolygon", "coordinates": polys})
    feats: list[dict] = [{"type": "Feature", "geometry": geom,
                          "properties": {"role": "field", "name": plan.field.name,
                                         "area_m2": round(plan.field.area, 1),
                                         **_plan_props(plan, altitude, speed)}}]
    for k, s in enumerate(plan.segments):
        q = _thin(s.points, simplify_m)
        feats.append({"type": "Feature", "geometry": _split_line(_ll(q[:, 0], q[:, 1], org)),
                      "properties": {"role": "path", "index": k, "kind": s.kind,
                                     "spray": bool(s.spray), "altitude_m_agl": altitude}})
    for i, w in enumerate(plan_waypoints(plan, org, simplify_m, *leads)):
        if w.event:
            feats.append({"type": "Feature",
                          "geometry": {"type": "Point",
                                       "coordinates": [round(w.lon, 9), round(w.lat, 9)]},
                          "properties": {"role": w.event, "waypoint": i,
                                         "altitude_m_agl": altitude}})
    return {"type": "FeatureCollection", "features": feats}


def _kml_el(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    e = ET.SubElement(parent, f"{{{KML_NS}}}{tag}", attrib)
    if text is not None:
        e.text = text
    return e


def _kml_coords(lonlat: Sequence[Sequence[float]], alt: float | None) -> str:
    if alt is None:
        return " ".join(f"{a:.9f},{b:.9f}" for a, b in lonlat)
    return " ".join(f"{a:.9f},{b:.9f},{alt:g}" for a, b in lonlat)


def plan_to_kml(plan: CoveragePlan, *, altitude: float, speed: float,
                origin: Sequence[float] | None = None, simplify_m: float = 0.2,
                leads: tuple[float, float] = (0.0, 0.0)) -> str:
    """The plan as an OGC KML 2.2 document (see the module doc)."""
    org = _origin(plan, origin)
    ET.register_namespace("", KML_NS)
    root = ET.Element(f"{{{KML_NS}}}kml")
    doc = _kml_el(root, "Document")
    _kml_el(doc, "name", f"{plan.field.name} coverage plan")
    props = _plan_props(plan, altitude, speed)
    _kml_el(doc, "description", ", ".join(f"{k} {v}" for k, v in props.items()))
    for sid, line, width, poly in (("spray", "ff33cc33", "3", None),
                                   ("off", "ff999999", "2", None),
                                   ("field", "ff3fa5d9", "2", "4d2f6fa5")):
        st = _kml_el(doc, "Style", id=sid)
        ls = _kml_el(st, "LineStyle")
        _kml_el(ls, "color", line)
        _kml_el(ls, "width", width)
        if poly:
            _kml_el(_kml_el(st, "PolyStyle"), "color", poly)
    pm = _kml_el(doc, "Placemark")
    _kml_el(pm, "name", plan.field.name)
    _kml_el(pm, "styleUrl", "#field")
    ext = _kml_el(pm, "ExtendedData")
    for k, v in {"role": "field", "area_m2": f"{plan.field.area:.1f}"}.items():
        _kml_el(_kml_el(ext, "Data", name=k), "value", str(v))
    polys = [q for outer, holes in plan.field.rings()   # cut at ±180° as the GeoJSON is
             for q in split_polygon_rings([_ll(r[:, 0], r[:, 1], org) for r in [outer, *holes]])]
    holder = _kml_el(pm, "MultiGeometry") if len(polys) > 1 else pm
    for rings in polys:
        pg = _kml_el(holder, "Polygon")
        _kml_el(pg, "altitudeMode", "clampToGround")
        for k, r in enumerate(rings):
            tag = "outerBoundaryIs" if k == 0 else "innerBoundaryIs"
            lr = _kml_el(_kml_el(pg, tag), "LinearRing")
            _kml_el(lr, "coordinates", _kml_coords(r, None))
    path = _kml_el(doc, "Folder")
    _kml_el(path, "name", "path")
    for k, s in enumerate(plan.segments):
        q = _thin(s.points, simplify_m)
        p = _kml_el(path, "Placemark")
        _kml_el(p, "name", f"{k} {s.kind}")
        _kml_el(p, "styleUrl", "#spray" if s.spray else "#off")
        ext = _kml_el(p, "ExtendedData")
        for key, v in (("kind", s.kind), ("spray", str(bool(s.spray)).lower()), ("index", k)):
            _kml_el(_kml_el(ext, "Data", name=key), "value", str(v))
        g = _split_line(_ll(q[:, 0], q[:, 1], org))
        lines = g["coordinates"] if g["type"] == "MultiLineString" else [g["coordinates"]]
        holder = _kml_el(p, "MultiGeometry") if len(lines) > 1 else p
        for coords in lines:
            ls = _kml_el(holder, "LineString")
            _kml_el(ls, "altitudeMode", "relativeToGround")
            _kml_el(ls, "coordinates", _kml_coords(coords, altitude))
    noz = _kml_el(doc, "Folder")
    _kml_el(noz, "name", "nozzles")
    for i, w in enumerate(plan_waypoints(plan, org, simplify_m, *leads)):
        if w.event:
            p = _kml_el(noz, "Placemark")
            _kml_el(p, "name", w.event.replace("_", " "))
            ext = _kml_el(p, "ExtendedData")
            _kml_el(_kml_el(ext, "Data", name="waypoint"), "value", str(i))
            pt = _kml_el(p, "Point")
            _kml_el(pt, "altitudeMode", "relativeToGround")
            _kml_el(pt, "coordinates", _kml_coords([(w.lon, w.lat)], altitude))
    ET.indent(root, space=" ")
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def _item(jump_id: int, command: int, frame: int, params: list[float | None]) -> dict:
    return {"autoContinue": True, "command": command, "doJumpId": jump_id, "frame": frame,
            "params": params, "type": "SimpleItem"}


def plan_to_qgc(plan: CoveragePlan, *, altitude: float, speed: float,
                origin: Sequence[float] | None = None, simplify_m: float = 0.2,
                leads: tuple[float, float] = (0.0, 0.0)) -> dict:
    """The plan as a QGroundControl ``.plan`` document (a dict; see the module doc)."""
    org = _origin(plan, origin)
    wps = plan_waypoints(plan, org, simplify_m, *leads)
    items: list[dict] = []

    def add(command: int, frame: int, params: list[float | None]) -> None:
        items.append(_item(len(items) + 1, command, frame, params))

    w0 = wps[0]
    r9 = 9
    add(MAV_CMD_NAV_TAKEOFF, MAV_FRAME_GLOBAL_RELATIVE_ALT,
        [0, 0, 0, None, round(w0.lat, r9), round(w0.lon, r9), altitude])
    add(MAV_CMD_DO_CHANGE_SPEED, MAV_FRAME_MISSION, [1, speed, -1, 0, 0, 0, 0])
    for w in wps:
        add(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT,
            [0, 0, 0, None, round(w.lat, r9), round(w.lon, r9), altitude])
        if w.event:
            add(MAV_CMD_DO_SPRAYER, MAV_FRAME_MISSION,
                [1 if w.event == "spray_on" else 0, 0, 0, 0, 0, 0, 0])
    return {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "QGroundControl",
        "mission": {
            "version": 2,
            "firmwareType": MAV_AUTOPILOT_ARDUPILOTMEGA,
            "vehicleType": MAV_TYPE_QUADROTOR,
            "cruiseSpeed": speed,
            "hoverSpeed": speed,
            "plannedHomePosition": [round(w0.lat, r9), round(w0.lon, r9), org[ORIGIN.H]],
            "items": items,
        },
        "geoFence": {"version": 2, "circles": [], "polygons": []},
        "rallyPoints": {"version": 2, "points": []},
    }


def write_plan(plan: CoveragePlan, path: str | Path, *, altitude: float, speed: float,
               origin: Sequence[float] | None = None, simplify_m: float = 0.2,
               leads: tuple[float, float] = (0.0, 0.0)) -> dict[str, Any]:
    """Write ``plan`` to ``path`` in the format its extension names (:data:`PLAN_SUFFIXES`).

    ``leads`` = (on, off) metres of path by which the nozzle commands lead the sprayed edges
    (:func:`nozzle_leads`; :func:`plan_waypoints`).
    Returns a summary: format, waypoints, nozzle switches, mission items (``.plan``), bytes.
    Raises ValueError for an unknown extension, a field without a geodetic origin or a
    negative ``simplify_m``; the file is written atomically (an OSError names it)."""
    p = Path(path)
    suf = p.suffix.lower()
    if suf not in PLAN_SUFFIXES:
        raise ValueError(f"unknown plan file type {suf or '(none)'!r}; allowed: "
                         f"{', '.join(PLAN_SUFFIXES)}")
    if not (math.isfinite(altitude) and altitude > 0 and math.isfinite(speed) and speed > 0):
        raise ValueError(f"altitude ({altitude}) and speed ({speed}) must be > 0")
    if not (math.isfinite(simplify_m) and simplify_m >= 0):
        raise ValueError(f"simplify_m ({simplify_m}) must be >= 0")
    kw = {"altitude": float(altitude), "speed": float(speed), "origin": origin,
          "simplify_m": simplify_m, "leads": leads}
    wps = plan_waypoints(plan, origin, simplify_m, *leads)
    info: dict[str, Any] = {"waypoints": len(wps),
                            "spray_switches": sum(1 for w in wps if w.event)}
    if suf == ".kml":
        text = plan_to_kml(plan, **kw)
        info["format"] = "KML"
    elif suf == ".plan":
        doc = plan_to_qgc(plan, **kw)
        text = json.dumps(doc, indent=2) + "\n"
        info["format"] = "QGroundControl plan"
        info["items"] = len(doc["mission"]["items"])
    else:
        text = json.dumps(plan_to_geojson(plan, **kw)) + "\n"
        info["format"] = "GeoJSON"
    from ..record.atomic import atomic_write_text  # no partial or 0-byte plan on a full disk

    atomic_write_text(p, text)
    info["bytes"] = p.stat().st_size
    return info
