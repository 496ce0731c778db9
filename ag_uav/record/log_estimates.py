"""The estimator and geographic channels of a :class:`~ag_uav.record.runlog.RunLog` (a part of
it): ``/estimator/<name>`` (one filter or a bank), and the origin that turns on the ``/geo/*``
topics (:mod:`ag_uav.record.geo`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .wire import (
    INF,
    NAN,
    TICK_P,
    EstBank,
    EstChan,
    FlatRows,
    FlatSchema,
    as_floats,
    fit,
    ns,
    sanitize_name,
    str_field,
)


class EstimateLog:
    """The estimator and geographic part of :class:`~ag_uav.record.runlog.RunLog`."""

    def geo(self, origin: Sequence[float], *, dose_target_l_per_ha: float | None = None) -> None:
        """The run's geodetic origin (lat °, lon °, WGS-84 height m of the local frame's
        origin): turns on the geographic topics (:mod:`ag_uav.record.geo`; group ``geo``):
        LocationFix of the true position, the estimate and the GNSS fixes, and GeoJSON of the
        field, plan, sprayed area and dose (in bands of ``dose_target_l_per_ha``) that
        :meth:`scene`, :meth:`sprayed` and :meth:`dose` log from now on.  Also the metadata
        record ``geo``.  Call once, before :meth:`scene`."""
        if self.closed or self._period["geo"] == INF or self._geo is not None:
            return
        from .geo import GeoFrame

        self._geo = frame = GeoFrame(origin)
        self._dose_target = float(dose_target_l_per_ha or 0.0)
        M = self._M
        ids = self._geo_ids
        ids["true"] = self._chan("/geo/true", M.LocationFix)
        if self._period["gps"] < INF:
            ids["gnss"] = self._chan("/geo/gnss", M.LocationFix)
        self._ops.append(("geofmt", frame.origin, ids["true"], -1, ids.get("gnss", -1)))
        lat, lon, h = frame.origin
        self._ops.append(("meta", "geo", {
            "origin_lat_deg": repr(lat), "origin_lon_deg": repr(lon), "origin_alt_m": repr(h),
            "frame": "local ENU metres (x east, y north, z up) about the origin, WGS-84"}))
        self._next["geo"] = -INF
        self._next_tick = self._tick_clock()

    def _geo_est(self) -> None:
        """``/geo/est``: declared at the first tick row with an estimate (a run without one
        has no such topic)."""
        self._n_geo_est += 1
        if "est" not in self._geo_ids:
            ids = self._geo_ids
            ids["est"] = self._chan("/geo/est", self._M.LocationFix)
            self._ops.append(("geofmt", self._geo.origin, ids["true"], ids["est"],
                              ids.get("gnss", -1)))

    def _geo_json(self, key: str, t: float, text: str) -> None:
        """A GeoJSON message on ``/geo/<key>`` (declared at its first), sent with the next
        hand-over."""
        lid = self._geo_ids.get(key)
        if lid is None:
            from .geo import GEO_TOPICS

            lid = self._geo_ids[key] = self._chan(GEO_TOPICS[key], self._M.GeoJson)
        tn = ns(t)
        self._pending.append((lid, str_field(1, text), tn))  # foxglove.GeoJSON.geojson
        self._count(f"/geo/{key}")

    def set_truth(self, p_true: Sequence[float]) -> None:
        """The true position at the time of the next ``estimator`` calls (their ``err``): the
        estimator bank calls it before logging a fix's update, so that ``err`` is not measured
        against a pose up to one state period old (at 5 m/s, 50 ms is 0.25 m)."""
        self._last_true = (float(p_true[0]), float(p_true[1]), float(p_true[2]))

    def _truth(self) -> tuple[float, float, float]:
        """The last true position given to :meth:`set_truth` or a tick row."""
        lt = self._last_true
        if lt is None:
            r = self._last_row
            lt = self._last_true = (float(r[TICK_P]), float(r[TICK_P + 1]), float(r[TICK_P + 2]))
        return lt

    def estimator(
        self,
        t: float,
        name: str,
        x: Sequence[float],
        p_diag: Sequence[float],
        innovation: Sequence[float] | None = None,
        extra: dict[str, float] | None = None,
        *,
        pos: Sequence[float] | None = None,
    ) -> None:
        """One estimator's state after an update -> ``/estimator/<name>``.

        ``pos`` is the estimator's position estimate (2 or 3 values); default ``x[:3]`` (pass it
        when the state is not ordered position-first).  ``err`` = pos - the last true position
        given to :meth:`tick`.  The schema is fixed at the first call per name (vector lengths,
        ``extra`` keys); later missing values are written as NaN.  float64 numpy vectors are
        copied into the message as they are (a packed ``repeated double`` is their raw bytes).
        """
        ec = self._est.get(name)
        if ec is None:
            if self.closed or self._period["estimator"] == INF:
                return
            xs = as_floats(x)
            ec = self._est[name] = self._make_est(name, len(xs), innovation, extra)
        elif t < ec.next_t:  # inf once closed
            return
        ec.next_t = t + self._p_est
        n = ec.n
        xa = type(x) is np.ndarray and x.ndim == 1 and x.size == n
        if pos is None:
            pl = x[:3].tolist() if xa else as_floats(x)[:3]
        else:
            pl = pos if len(pos) == 3 else as_floats(pos)
        tx, ty, tz = self._truth()
        if len(pl) == 3:
            px, py, pz = pl
        else:
            pf = fit(list(pl), 2)
            px, py, pz = pf[0], pf[1], (tz if len(pl) == 2 else NAN)
        row = ec.rows.open_row()
        row[0] = t
        row[ec.ix:ec.ip] = x if xa else fit(as_floats(x), n)
        if type(p_diag) is np.ndarray and p_diag.ndim == 1 and p_diag.size <= n:
            k = ec.ip + p_diag.size  # shorter (an error-state covariance): NaN-padded
            row[ec.ip:k] = p_diag
            row[k:ec.ii] = NAN
        else:
            row[ec.ip:ec.ii] = fit(as_floats(p_diag), n)
        if ec.m:
            row[ec.ii:ec.it] = NAN if innovation is None else fit(as_floats(innovation), ec.m)
        row[ec.it:ec.it + 7] = (px, py, pz, tx, ty, tz, NAN)  # err: at the flush (EstChan)
        if ec.keys:
            g = (extra or {}).get
            row[ec.it + 7:] = [g(k, NAN) for k in ec.keys]
        ec.rows.commit()
        ec.count += 1

    def estimator_bank(self, t: float, names: Sequence[str], x: np.ndarray,
                       p_diag: np.ndarray, p_true: Sequence[float]) -> None:
        """:meth:`estimator` for a bank of filters of one vehicle at once (no innovation, no
        extras; position first in the state): row j of ``x`` (k, n) and of ``p_diag`` (k, m ≤ n,
        NaN-padded to n; the shapes of the bank's first call) is filter ``names[j]`` on
        ``/estimator/<name>``, ``err`` against ``p_true``.  A fix is one compact row of the
        bank (:class:`EstBank`); the writer makes the messages of a flush's rows in one call."""
        key = tuple(names)
        bank = self._banks.get(key)
        if bank is None:
            if self.closed or self._period["estimator"] == INF:
                return
            bank = self._banks[key] = self._make_bank(key, x.shape[1], p_diag.shape[1])
        if t < bank.next_t:  # inf once closed
            return
        bank.next_t = t + self._p_est
        bank.put_fix(t, x, p_diag, p_true)

    def _make_bank(self, names: tuple[str, ...], n: int, m: int) -> EstBank:
        schema = FlatSchema("ag_uav.EstimatorState", [("t", 0), ("x", n), ("p_diag", n)]
                            + [(f"pos.{a}", 0) for a in "xyz"]
                            + [(f"err.{a}", 0) for a in ("x", "y", "z", "horiz")])
        topics = [f"/estimator/{sanitize_name(nm)}" for nm in names]
        lids = [self._chan(tp, "ag_uav.EstimatorState", schema.schema_data) for tp in topics]
        return self._register_flat(EstBank(schema, lids, topics, n, m))

    def _make_est(self, name: str, n: int, innovation: Any, extra: Any) -> EstChan:
        m = len(as_floats(innovation)) if innovation is not None else 0
        keys = tuple(extra or {})
        fields = [("t", 0), ("x", n), ("p_diag", n)]
        if m:
            fields.append(("innovation", m))
        fields += [(f"pos.{a}", 0) for a in "xyz"]
        fields += [(f"err.{a}", 0) for a in ("x", "y", "z", "horiz")]
        fields += [(f"extra.{k}", 0) for k in keys]
        try:
            schema = FlatSchema("ag_uav.EstimatorState", fields)
        except ValueError:
            keys = ()
            schema = FlatSchema("ag_uav.EstimatorState", [f for f in fields
                                                           if not f[0].startswith("extra.")])
        topic = f"/estimator/{sanitize_name(name)}"
        lid = self._chan(topic, "ag_uav.EstimatorState", schema.schema_data)
        return self._register_flat(EstChan(schema, lid, topic, n, m, keys))

    def _register_flat(self, fr: FlatRows) -> Any:
        """Register a flat-schema channel's row block with the writer (its encoding)."""
        fr.fid = len(self._flat_rows)
        bank = ((fr.k, fr.n, fr.m, fr.lids.astype(int).tolist()) if isinstance(fr, EstBank)
                else None)
        self._ops.append(("flat", fr.fid, fr.tmpl, fr.slots, fr.lid, fr.it, bank))
        self._flat_rows.append(fr)
        return fr
