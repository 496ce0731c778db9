"""The scene, dose-map and camera channels of a :class:`~ag_uav.record.runlog.RunLog` (one of its
writers): ``/field``, ``/sprayed``, ``/dose``, ``/camera/<name>`` (and the GeoJSON of the field,
plan, sprayed area and dose through the geographic writer)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .channels import Channels
from .log_geo import GeoWriter
from .wire import INF, enc_grid, enc_transform, ns, sanitize_name, str_field, ts_pb

#: channel set: a map sums the whole fine dose grid, the light set's budget takes one in six
DOSE_PERIOD_S = {"full": 5.0, "light": 30.0}
#: bytes of dose maps after which their period doubles (and again after each as many more): a
#: long job over a big field logs O(log duration) quotas of maps instead of one map every period
#: (the 38 ha job's 3,377 whole maps were 1.36 GB of its log); the final map is always logged
DOSE_QUOTA_B = 8_000_000
#: sim seconds between two of those maps that also go to ``/geo/dose`` as GeoJSON bands (and
#: the one at the end): contouring a map costs the writer ~10 ms, three times ``/dose``'s grid
GEO_DOSE_PERIOD_S = {"full": 15.0, "light": 60.0}



class SceneWriter:
    """The ``scene`` and ``camera`` groups of a run log, written through ``ch``; ``geo``: the
    log's geographic writer (the GeoJSON of what the scene draws).

    :param preset: the channel set's name (``"full"``, ``"light"``; ``""`` for a list of
        groups): the dose maps' periods (:data:`DOSE_PERIOD_S`, :data:`GEO_DOSE_PERIOD_S`).
    """

    def __init__(self, ch: Channels, geo: GeoWriter, preset: str) -> None:
        self._ch, self._geo = ch, geo
        self.tf_id = -1  #: the ``/tf`` channel for camera poses (set once it is declared)
        self._dose_period = DOSE_PERIOD_S.get(preset, DOSE_PERIOD_S["full"])
        self._geo_dose_period = GEO_DOSE_PERIOD_S.get(preset, GEO_DOSE_PERIOD_S["full"])
        self._next_dose = -INF
        self._next_geo_dose = -INF
        self._ch_dose: Any = None
        self._dose_bytes = 0  # bytes of dose maps logged (their period doubles per quota)
        self._scene_ch: dict[str, int] = {}
        #: camera name -> (image channel, calibration channel, topic)
        self._cam: dict[str, tuple[int, int, str]] = {}
        self._next_cam: dict[str, float] = {}  # per-camera clocks

    def cameras(self) -> tuple[str, ...]:
        """The cameras logged so far."""
        return tuple(self._cam)

    def _off(self) -> bool:
        return self._ch.closed or not self._ch.on("scene")

    def _scene_entities(self, t: float, entities: list[Any], topic: str) -> None:
        if self._off():
            return
        ch = self._ch
        lid = self._scene_ch.get(topic)
        if lid is None:
            lid = self._scene_ch[topic] = ch.declare(topic, ch.M.SceneUpdate)
        ch.drain()
        ch.send([("log", lid, ch.M.SceneUpdate(entities=entities).encode(), ns(t)), ("flush",)])
        ch.count(topic)

    def _triangles(self, polys: list[Any], z: float, rgba: tuple[float, ...]) -> list[Any]:
        """Fill shapely polygons with a TriangleListPrimitive (constrained Delaunay)."""
        import shapely

        M = self._ch.M
        pts: list[Any] = []
        for poly in polys:
            if poly.is_empty:
                continue
            tris = shapely.constrained_delaunay_triangles(poly)
            for tri in getattr(tris, "geoms", [tris]):
                if tri.is_empty:
                    continue
                c = list(tri.exterior.coords)[:3]
                pts += [M.Point3(x=float(a), y=float(b), z=z) for a, b in c]
        if not pts:
            return []
        return [M.TriangleListPrimitive(points=pts, color=M.Color(r=rgba[0], g=rgba[1],
                                                                  b=rgba[2], a=rgba[3]))]

    def _loops(self, rings: list[np.ndarray], z: float, rgba: tuple[float, ...],
               thickness: float = 3.0) -> list[Any]:
        M = self._ch.M
        out = []
        for ring in rings:
            ring = np.asarray(ring, dtype=float)
            if len(ring) < 2:
                continue
            out.append(M.LinePrimitive(
                type=M.LinePrimitiveLineType.LineLoop, thickness=thickness, scale_invariant=True,
                points=[M.Point3(x=float(a), y=float(b), z=z) for a, b in ring[:, :2]],
                color=M.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])))
        return out

    def scene(
        self,
        t: float,
        field_outer_xy: Any,
        field_holes_xy: list[Any],
        plan_segments: list[tuple[str, Any, bool]],
        swath: float,
        altitude: float,
        parts: list[tuple[Any, list[Any]]] | None = None,
    ) -> None:
        """Field polygon (filled + outline, holes as obstacles) and planned path -> ``/field``.

        ``plan_segments``: ``(kind, Nx2|Nx3 points, spray)``; spraying segments are drawn green,
        the others (transits) grey.  ``parts``: ``[(outer, holes), ...]`` of a multi-part field
        (replaces ``field_outer_xy`` / ``field_holes_xy``).  Call once at the start.
        """
        if self._off():
            return
        import shapely

        M = self._ch.M
        if parts is None:
            parts = [(field_outer_xy, field_holes_xy or [])]
        outers = [np.asarray(o, dtype=float)[:, :2] for o, _ in parts]
        holes = [np.asarray(h, dtype=float)[:, :2] for _, hs in parts for h in hs]
        polys = [shapely.Polygon(o, [np.asarray(h, dtype=float)[:, :2] for h in hs])
                 for o, (_, hs) in zip(outers, parts, strict=True)]
        poly = shapely.union_all(polys)
        ts = self._ch.ts(ns(t))
        field = M.SceneEntity(
            timestamp=ts, frame_id="world", id="field",
            triangles=self._triangles(polys, -0.02, (0.55, 0.45, 0.25, 0.6)),
            lines=self._loops(outers, 0.0, (0.9, 0.8, 0.3, 1.0))
            + self._loops(holes, 0.0, (0.9, 0.2, 0.2, 1.0)),
            metadata=[M.KeyValuePair(key="swath_m", value=str(swath)),
                      M.KeyValuePair(key="altitude_m", value=str(altitude)),
                      M.KeyValuePair(key="area_m2", value=f"{poly.area:.1f}")],
        )
        lines = []
        for _kind, pts, spray in plan_segments:
            pts = np.asarray(pts, dtype=float)
            if len(pts) < 2:
                continue
            z = pts[:, 2] if pts.shape[1] > 2 else np.full(len(pts), float(altitude))
            col = (0.1, 0.85, 0.2, 1.0) if spray else (0.6, 0.6, 0.6, 0.8)
            lines.append(M.LinePrimitive(
                type=M.LinePrimitiveLineType.LineStrip, thickness=2.0, scale_invariant=True,
                points=[M.Point3(x=float(a), y=float(b), z=float(c))
                        for (a, b), c in zip(pts[:, :2], z, strict=True)],
                color=M.Color(r=col[0], g=col[1], b=col[2], a=col[3])))
        plan = M.SceneEntity(timestamp=ts, frame_id="world", id="plan", lines=lines)
        frame = self._geo.frame
        if frame is not None:
            from .geo import field_geojson, plan_geojson

            rings = [(o, [np.asarray(h, float) for h in hs])
                     for o, (_, hs) in zip(outers, parts, strict=True)]
            self._geo.json("field", t, field_geojson(frame, rings))
            self._geo.json("plan", t, plan_geojson(frame, plan_segments))
        self._scene_entities(t, [field, plan], "/field")
        if frame is not None:
            self._ch.on_layout()  # with its Map panel, should the run be cut short

    def sprayed(self, t: float, polygons_xy: list[Any]) -> None:
        """Sprayed area (shapely Polygon/MultiPolygon or Nx2 rings) -> ``/sprayed``."""
        if self._off():
            return
        import shapely

        polys: list[Any] = []
        for p in polygons_xy:
            if isinstance(p, shapely.MultiPolygon):
                polys += list(p.geoms)
            elif isinstance(p, shapely.Polygon):
                polys.append(p)
            else:
                polys.append(shapely.Polygon(np.asarray(p, dtype=float)[:, :2]))
        ent = self._ch.M.SceneEntity(
            timestamp=self._ch.ts(ns(t)), frame_id="world", id="sprayed",
            triangles=self._triangles(polys, 0.0, (0.1, 0.7, 1.0, 0.45)),
            lines=self._loops([np.asarray(p.exterior.coords) for p in polys], 0.01,
                              (0.1, 0.7, 1.0, 1.0), 1.0),
        )
        if self._geo.frame is not None:
            from .geo import sprayed_geojson

            self._geo.json("sprayed", t, sprayed_geojson(self._geo.frame, polys))
        self._scene_entities(t, [ent], "/sprayed")

    # ---------------------------------------------------------------- dose map
    def want_dose(self, t: float) -> bool:
        """Would :meth:`dose` log a map at sim time ``t``? (no side effects)"""
        return not self._off() and t >= self._next_dose

    def dose(self, t: float, x0: float, y0: float, cell: float, l_per_ha: Any, *,
             final: bool = False) -> None:
        """The dose map on the ground (L/ha, (ny, nx), row j at y0 + j·cell) -> ``/dose``
        foxglove.Grid (one float32 field ``l_per_ha``, lower-left corner at (x0, y0), 2 cm above
        the ground), at most every :data:`DOSE_PERIOD_S` of sim time, doubled after each
        :data:`DOSE_QUOTA_B` of maps (``final``: always). Part of the ``scene`` group.  With
        :meth:`geo`, a logged map at least :data:`GEO_DOSE_PERIOD_S` after the last (and the
        final one) also goes to ``/geo/dose``: the map in bands of the target rate, made by the
        writer."""
        if self._off():
            return
        if not final and t < self._next_dose:
            return
        ch = self._ch
        if self._ch_dose is None:
            self._ch_dose = ch.declare("/dose", ch.M.Grid)
        tn = ns(t)
        msg = enc_grid(ts_pb(tn), float(x0), float(y0), 0.02, float(cell), l_per_ha)
        ch.post(self._ch_dose, msg, tn)
        ch.count("/dose")
        self._dose_bytes += len(msg)
        self._next_dose = t + self._dose_period * 2 ** (self._dose_bytes // DOSE_QUOTA_B) - 1e-9
        if (self._geo.frame is not None and self._geo.dose_target > 0
                and (final or t >= self._next_geo_dose)):  # the bands: in the writer
            self._next_geo_dose = t + self._geo_dose_period - 1e-9
            self._geo.dose_bands(tn, x0, y0, cell, l_per_ha)

    # ---------------------------------------------------------------- camera
    def frame(
        self,
        t: float,
        camera: str,
        jpeg: bytes,
        width: int,
        height: int,
        fovy_deg: float,
        pose: tuple[Sequence[float], Sequence[float]] | None = None,
    ) -> None:
        """A JPEG frame -> ``/camera/<camera>`` (+ its CameraCalibration each frame, so a seek
        always finds one).  ``pose`` = (position, quaternion wxyz) of the camera's optical frame
        (z forward, x right, y down; :meth:`ag_uav.record.render.Renderer.camera_pose`) ->
        ``/tf``."""
        ch = self._ch
        if ch.closed or not self._due_cam(camera, t):
            return
        M = ch.M
        tn = ns(t)
        ts = ch.ts(tn)
        frame_id = f"cam_{sanitize_name(camera)}"
        cam = self._cam.get(camera)
        if cam is None:
            base = f"/camera/{sanitize_name(camera)}"
            cam = self._cam[camera] = (ch.declare(base, M.CompressedImage),
                                       ch.declare(base + "/calibration", M.CameraCalibration),
                                       base)
        img, cal, base = cam
        ch.drain()
        fy = 0.5 * height / math.tan(math.radians(fovy_deg) / 2.0)
        fx = fy
        cx, cy = 0.5 * width, 0.5 * height
        ops = [("log", img, M.CompressedImage(timestamp=ts, frame_id=frame_id, data=bytes(jpeg),
                                               format="jpeg").encode(), tn),
               ("log", cal, M.CameraCalibration(
                   timestamp=ts, frame_id=frame_id, width=int(width), height=int(height),
                   distortion_model="plumb_bob", D=[0.0] * 5,
                   K=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
                   R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                   P=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]).encode(), tn)]
        ch.count(base)
        ch.count(base + "/calibration")
        if pose is not None and self.tf_id >= 0:
            ops.append(("log", self.tf_id, enc_transform(ts_pb(tn), str_field(3, frame_id),
                                                         pose[0], pose[1]), tn))
            ch.count("/tf")
        ch.send(ops)
        ch.maybe_flush(t)

    def _due_cam(self, camera: str, t: float) -> bool:
        """Camera rate is per camera; ``want_frame`` checks the group clock."""
        p = self._ch.period["camera"]
        if p == INF:
            return False
        clocks = self._next_cam
        if t < clocks.get(camera, -INF):
            return False
        clocks[camera] = t + p - 1e-9
        # the group clock is the earliest of the cameras' clocks
        self._ch.next["camera"] = min(clocks.values())
        return True
