"""The geographic channels of a :class:`~ag_uav.record.runlog.RunLog` (one of its writers): the
run's geodetic origin turns on ``/geo/true``, ``/geo/est``, ``/geo/gnss`` (LocationFix, made by
the writer from the tick and GNSS rows) and the GeoJSON topics ``/geo/field``, ``/geo/plan``,
``/geo/sprayed`` and ``/geo/dose`` (:mod:`ag_uav.record.geo`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .channels import Channels
from .wire import INF, ns, str_field


class GeoWriter:
    """The ``geo`` group of a run log, written through ``ch``."""

    def __init__(self, ch: Channels) -> None:
        self._ch = ch
        self.frame: Any = None  #: the :class:`~ag_uav.record.geo.GeoFrame` once :meth:`start`
        self.dose_target = 0.0  #: the target rate the ``/geo/dose`` bands are drawn against
        self._ids: dict[str, int] = {}  # geo topic key -> channel index

    def start(self, origin: Sequence[float], dose_target_l_per_ha: float | None = None) -> bool:
        """The run's geodetic origin (lat °, lon °, WGS-84 height m): declares ``/geo/true``
        (and ``/geo/gnss`` with the ``gps`` group), the writer's LocationFix format and the
        metadata record ``geo``, and starts the group's clock; False (nothing done) when the
        log is closed, the group is off or the origin was given before."""
        ch = self._ch
        if ch.closed or not ch.on("geo") or self.frame is not None:
            return False
        from .geo import GeoFrame

        self.frame = frame = GeoFrame(origin)
        self.dose_target = float(dose_target_l_per_ha or 0.0)
        M = ch.M
        ids = self._ids
        ids["true"] = ch.declare("/geo/true", M.LocationFix)
        if ch.on("gps"):
            ids["gnss"] = ch.declare("/geo/gnss", M.LocationFix)
        ch.ops.append(("geofmt", frame.origin, ids["true"], -1, ids.get("gnss", -1)))
        lat, lon, h = frame.origin
        ch.ops.append(("meta", "geo", {
            "origin_lat_deg": repr(lat), "origin_lon_deg": repr(lon), "origin_alt_m": repr(h),
            "frame": "local ENU metres (x east, y north, z up) about the origin, WGS-84"}))
        ch.next["geo"] = -INF
        return True

    def has(self, key: str) -> bool:
        """Whether ``/geo/<key>`` is declared."""
        return key in self._ids

    def est_seen(self) -> None:
        """A tick row carries an estimate: ``/geo/est`` is declared at the first (a run without
        one has no such topic)."""
        ids = self._ids
        if "est" not in ids:
            ids["est"] = self._ch.declare("/geo/est", self._ch.M.LocationFix)
            self._ch.ops.append(("geofmt", self.frame.origin, ids["true"], ids["est"],
                                 ids.get("gnss", -1)))

    def json(self, key: str, t: float, text: str) -> None:
        """A GeoJSON message on ``/geo/<key>`` (declared at its first), sent with the next
        hand-over."""
        lid = self._ids.get(key)
        if lid is None:
            from .geo import GEO_TOPICS

            lid = self._ids[key] = self._ch.declare(GEO_TOPICS[key], self._ch.M.GeoJson)
        self._ch.post(lid, str_field(1, text), ns(t))  # foxglove.GeoJSON.geojson
        self._ch.count(f"/geo/{key}")

    def dose_bands(self, t_ns: int, x0: float, y0: float, cell: float, l_per_ha: Any) -> None:
        """A dose map (:meth:`~ag_uav.record.log_scene.SceneWriter.dose`'s) on ``/geo/dose``
        as GeoJSON bands of :attr:`dose_target`, contoured by the writer."""
        lid = self._ids.get("dose")
        if lid is None:
            lid = self._ids["dose"] = self._ch.declare("/geo/dose", self._ch.M.GeoJson)
        self._ch.ops.append(("geodose", lid, t_ns, float(x0), float(y0), float(cell),
                             self.dose_target, np.ascontiguousarray(l_per_ha, dtype=np.float64)))
        self._ch.count("/geo/dose")

    def topics(self) -> tuple[str, ...]:
        """The geographic topics declared so far (what the layout's Map panel names)."""
        from .geo import GEO_TOPICS

        return tuple(GEO_TOPICS[k] for k in GEO_TOPICS if k in self._ids)
