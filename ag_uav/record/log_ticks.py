"""The per-tick channels of a :class:`~ag_uav.record.runlog.RunLog` (one of its writers): the tick
rows (``/tf``, ``/drone/pose*``, ``/drone/state``, ``/geo/true``, ``/geo/est``), ``/drone/spray``,
``/gps`` and ``/gps/error``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from .channels import Channels
from .log_geo import GeoWriter
from .wire import (
    INF,
    NAN,
    NO_BYTES,
    POSE_MID,
    POSE_SLOTS,
    POSE_TMPL,
    TF_TMPL,
    TICK_HEAD,
    TICK_P,
    TICK_PEST,
    TICK_PREF,
    TICK_Q,
    TICK_SPRAY,
    TICK_V,
    TICK_VEST,
    TICK_VREF,
    TICK_WIND,
    TICK_YAW,
    WORLD2,
    FlatRows,
    FlatSchema,
    Rows,
    as_floats,
    fit,
    str_field,
    template,
    tree_order,
)


class Tick(NamedTuple):
    """One control tick's values for :meth:`TickWriter.tick` (``p_est`` None: no estimate)."""

    p_true: Sequence[float]
    q_true_wxyz: Sequence[float]
    v_true: Sequence[float]
    p_ref: Sequence[float]
    v_ref: Sequence[float]
    yaw_ref: float
    p_est: Sequence[float] | None = None
    v_est: Sequence[float] | None = None
    ctrl: dict[str, float] | None = None
    motors: Sequence[float] = ()
    wind: Sequence[float] = (0.0, 0.0, 0.0)
    spray: bool = False


class TickWriter:
    """The per-tick groups (``tf``, ``pose``, ``state``, the tick rows of ``geo``), the spray
    state and the GNSS fixes of a run log, written through ``ch``; ``geo``: the log's
    geographic writer (the tick rows carry its ``/geo/true`` and ``/geo/est``)."""

    def __init__(self, ch: Channels, geo: GeoWriter) -> None:
        self._ch, self._geo = ch, geo
        self._next = ch.next  # the groups' clocks (shared: the camera's and geo's are others')
        pe = ch.period
        self._p_tf, self._p_pose, self._p_state = (pe["tf"] - 1e-9, pe["pose"] - 1e-9,
                                                   pe["state"] - 1e-9)
        self._p_gps, self._p_geo = pe["gps"] - 1e-9, pe["geo"] - 1e-9
        self._next_tick = INF
        self._next_spray = -INF if ch.on("state") and ch.enabled else INF
        self._n_tf = self._n_pose = self._n_pose_est = self._n_state = self._n_gps = 0
        self._n_geo = self._n_geo_est = self._n_geo_gnss = 0
        self._fix_codes: dict[str, int] = {}  # GNSS fix type -> its code in the gps rows
        self._ch_spray: FlatRows | None = None
        self._ch_gps_err: FlatRows | None = None
        self.tf_id = -1  #: the ``/tf`` channel (-1: off); camera poses go there too
        self._pose_ids = [-1] * 3
        self._gps_id = -1
        # (t, x, y, z, var e, n, u, fix type code, t_meas) of the fixes since the last flush
        self._gps_rows = Rows(9, cap=16)
        self._state_schema: FlatSchema | None = None
        self.ctrl_keys: tuple[str, ...] = ()  #: ``/drone/state``'s ctrl keys, in tree order
        self.n_motors = 0  #: rotor values in ``/drone/state``
        self._rows = Rows(TICK_HEAD)  # the tick rows to encode (re-made by the state schema)
        self._last_row: np.ndarray | None = None
        self._last_true: tuple[float, float, float] | None = (NAN, NAN, NAN)

    def open(self) -> None:
        """Declare the pose channels (``/tf``, ``/drone/pose``, ``/drone/pose_est``,
        ``/drone/pose_ref``, ``/gps``) and the pose format; start the tick clock (the ``geo``
        group's waits for :meth:`GeoWriter.start`)."""
        ch = self._ch
        M = ch.M
        pose = M.PoseInFrame
        self.tf_id = ch.declare("/tf", M.FrameTransforms) if ch.on("tf") else -1
        if ch.on("pose"):
            self._pose_ids = [ch.declare(tp, pose) for tp in
                              ("/drone/pose", "/drone/pose_est", "/drone/pose_ref")]
        self._gps_id = ch.declare("/gps", pose) if ch.on("gps") else -1
        ch.ops.append(("posefmt", POSE_TMPL, POSE_SLOTS,
                       np.frombuffer(POSE_MID, dtype=np.uint8).copy(),
                       np.frombuffer(WORLD2 + str_field(3, "base_link"), dtype=np.uint8).copy()))
        self._next["geo"] = INF  # on once the geographic writer has the origin
        self._next_tick = -INF if any(ch.on(g) for g in ("tf", "pose", "state")) else INF

    @property
    def has_spray(self) -> bool:
        """Whether ``/drone/spray`` is declared."""
        return self._ch_spray is not None

    def due(self, t: float) -> bool:
        """True when :meth:`tick` at sim time ``t`` would log something (no side effects)."""
        return t >= self._next_tick

    @property
    def next_tick(self) -> float:
        """The earliest sim time at which a tick row is due (``inf``: none will be)."""
        return self._next_tick

    def retime(self) -> None:
        """The groups' clocks changed (the ``geo`` group started): the tick clock follows."""
        self._next_tick = self._tick_clock()

    def stop(self) -> None:
        """Log nothing more (:class:`~ag_uav.record.channels.Source`)."""
        self._next_tick = INF
        self._next_spray = INF

    def take(self, partial: bool) -> list[tuple[Any, ...]]:
        """The GNSS and tick rows since the last hand-over (:class:`~ag_uav.record.channels.
        Source`); ``partial``: a tick row still being filled is dropped, uncounted."""
        rows = self._rows
        if rows.open and not partial:
            rows.commit()
        elif rows.open:  # dropped: uncounted
            m = int(rows.a[rows.n, 1])
            self._n_tf -= m & 1
            self._n_pose -= (m & 2) >> 1
            self._n_pose_est -= (m & 10) == 10
            self._n_state -= (m & 4) >> 2
            self._n_geo -= (m & 16) >> 4
            self._n_geo_est -= (m & 24) == 24
        rows.open = False
        ops: list[tuple[Any, ...]] = []
        if self._gps_rows.n:
            ops.append(("gps", self._gps_id, self._gps_rows.take()))
        if rows.n:
            ops.append(("ticks", rows.take()))
        return ops

    def counts_into(self, out: dict[str, int]) -> None:
        """Add the messages of its topics written so far to ``out`` (topic -> count)."""
        n_pose = self._n_pose  # the tick rows count when they are handed out
        for topic, n in (("/tf", self._n_tf), ("/drone/pose", n_pose),
                         ("/drone/pose_ref", n_pose), ("/drone/pose_est", self._n_pose_est),
                         ("/drone/state", self._n_state), ("/gps", self._n_gps),
                         ("/geo/true", self._n_geo), ("/geo/est", self._n_geo_est),
                         ("/geo/gnss", self._n_geo_gnss)):
            if n:
                out[topic] = out.get(topic, 0) + n
        if self._ch_spray is not None and self._ch_spray.count:
            out["/drone/spray"] = self._ch_spray.count
        if self._ch_gps_err is not None and self._ch_gps_err.count:
            out["/gps/error"] = self._ch_gps_err.count

    def set_truth(self, p_true: Sequence[float]) -> None:
        """The true position at the time of the next estimator rows (their ``err``)."""
        self._last_true = (float(p_true[0]), float(p_true[1]), float(p_true[2]))

    def truth(self) -> tuple[float, float, float]:
        """The last true position given to :meth:`set_truth` or a tick row."""
        lt = self._last_true
        if lt is None:
            r = self._last_row
            lt = self._last_true = (float(r[TICK_P]), float(r[TICK_P + 1]), float(r[TICK_P + 2]))
        return lt

    def _make_state_schema(self, ctrl_keys: Sequence[str], n_motors: int,
                           ctrl_src: Sequence[int] | None = None, extra: int | None = None,
                           ) -> None:
        """Fix ``/drone/state``'s schema (ctrl keys in tree order, ``n_motors`` rotor values)
        and the tick rows' layout: :data:`TICK_HEAD` columns, the motors, then ``extra`` raw
        columns of which ``ctrl_src[j]`` holds the j-th ctrl key of ``ctrl_keys`` as given
        (default: the ctrl values themselves, in the order given)."""
        fields: list[tuple[str, int]] = [("t", 0)]
        fields += [(f"pos.{a}", 0) for a in "xyz"]
        fields += [(f"vel.{a}", 0) for a in "xyz"]
        fields += [("rpy.roll", 0), ("rpy.pitch", 0), ("rpy.yaw", 0)]
        fields += [(f"ref.{a}", 0) for a in ("x", "y", "z", "vx", "vy", "vz", "yaw")]
        fields += [(f"est.{a}", 0) for a in ("x", "y", "z", "vx", "vy", "vz")]
        fields += [(f"err.{a}", 0) for a in ("x", "y", "z", "horiz", "norm")]
        fields += [(f"est_err.{a}", 0) for a in ("x", "y", "z", "horiz")]
        fields += [("speed", 0), ("spray", 0)]
        fields += [(f"wind.{a}", 0) for a in "xyz"]
        if n_motors:
            fields.append(("motors", n_motors))
        given = list(ctrl_keys)
        # ctrl keys: dots make nested groups (kept contiguous, first-appearance order)
        self.ctrl_keys = tuple(tree_order(given))
        try:
            schema = FlatSchema("ag_uav.DroneState",
                                fields + [(f"ctrl.{k}", 0) for k in self.ctrl_keys])
        except ValueError:  # e.g. "a" and "a.b" both given: flatten the names
            schema = FlatSchema("ag_uav.DroneState",
                                fields + [(f"ctrl.{k.replace('.', '_')}", 0)
                                          for k in self.ctrl_keys])
        self.n_motors = n_motors
        self._state_schema = schema
        src = list(range(len(given))) if ctrl_src is None else [int(c) for c in ctrl_src]
        pos = {k: src[j] for j, k in enumerate(given)}
        base = TICK_HEAD + n_motors
        ctrl_cols = np.array([base + pos[k] for k in self.ctrl_keys], dtype=np.intp)
        self._rows = Rows(base + (len(given) if extra is None else int(extra)))
        ch = self._ch
        on = ch.on("state")
        state_id = ch.declare("/drone/state", "ag_uav.DroneState", schema.schema_data) if on else -1
        st = template(schema.prefixes) if on else (NO_BYTES, np.zeros(0, dtype=np.int64))
        pose_on = ch.on("pose")
        pose_ids = self._pose_ids if pose_on else [-1] * 3
        # kinds (encode.TF, POSE, REF, EST, STATE) -> channels
        kind_ids = [self.tf_id, pose_ids[0], pose_ids[2], pose_ids[1], state_id]
        ch.ops.append(("tickfmt", n_motors, ctrl_cols, st[0], st[1],
                       POSE_TMPL if pose_on else NO_BYTES,
                       TF_TMPL if self.tf_id >= 0 else NO_BYTES, kind_ids))

    def bind_ticks(self, n_motors: int, ctrl_keys: Sequence[str], ctrl_src: Sequence[int],
                   extra: int) -> None:
        """The row layout :meth:`tick_slot` hands out (once, before the first slot): the
        :data:`TICK_HEAD` columns, ``n_motors`` rotor commands, then ``extra`` raw columns;
        ``ctrl_keys[j]`` is logged from raw column ``ctrl_src[j]``."""
        if self._state_schema is None and not self._ch.closed:
            self._make_state_schema(ctrl_keys, n_motors, ctrl_src, extra)

    def tick_slot(self, t: float, est: bool = False) -> np.ndarray | None:
        """The row to fill for a tick at sim time ``t`` (None when nothing is due), from its
        true position on: the columns from :data:`TICK_P` to :data:`TICK_HEAD`, the motors,
        then the raw columns bound by :meth:`bind_ticks` (which must come first).  ``est``: the
        estimate's columns hold one (else they are ignored).  The row is encoded at the next
        flush, so the caller fills it now; :meth:`tick` does the same from one call's
        arguments."""
        if t < self._next_tick:
            return None
        ch = self._ch
        ch.t_last = t
        rows = self._rows
        if rows.open:
            rows.commit()
        ch.maybe_flush(t)
        nx = self._next
        mask = 0
        if t >= nx["tf"]:
            nx["tf"] = t + self._p_tf
            mask = 1
            self._n_tf += 1
        if t >= nx["pose"]:
            nx["pose"] = t + self._p_pose
            mask |= 2
            self._n_pose += 1
            if est:
                self._n_pose_est += 1
        if t >= nx["state"]:
            nx["state"] = t + self._p_state
            mask |= 4
            self._n_state += 1
        if t >= nx["geo"]:
            nx["geo"] = t + self._p_geo
            mask |= 16
            self._n_geo += 1
            if est:
                self._n_geo_est += 1
                self._geo.est_seen()
        self._next_tick = self._tick_clock()
        row = rows.open_row()
        row[0] = t
        row[1] = mask | 8 if est else mask
        self._last_row = row
        self._last_true = None
        return row[TICK_P:]

    def _tick_clock(self) -> float:
        """The next sim time a tick row is due: the earliest of the per-tick groups' clocks."""
        nx = self._next
        nt = nx["tf"]
        if nx["pose"] < nt:
            nt = nx["pose"]
        if nx["state"] < nt:
            nt = nx["state"]
        if nx["geo"] < nt:
            nt = nx["geo"]
        return nt

    def tick(self, t: float, v: Tick) -> None:
        """Call every control tick; decimates internally (cheap when nothing is due).  One
        row of :meth:`tick_slot`, filled from ``v`` (``v.p_est`` None: no estimate)."""
        if t < self._next_tick:
            return
        if self._state_schema is None:
            self._make_state_schema(list(v.ctrl or {}), len(v.motors))
        self.tick_slot(t, est=v.p_est is not None)
        row = self._last_row
        row[TICK_P:TICK_Q] = fit(as_floats(v.p_true), 3)
        row[TICK_Q:TICK_V] = fit(as_floats(v.q_true_wxyz), 4)
        row[TICK_V:TICK_PREF] = fit(as_floats(v.v_true), 3)
        row[TICK_PREF:TICK_VREF] = fit(as_floats(v.p_ref), 3)
        row[TICK_VREF:TICK_YAW] = fit(as_floats(v.v_ref), 3)
        row[TICK_YAW] = v.yaw_ref
        if v.p_est is None:
            row[TICK_PEST:TICK_WIND] = NAN
        else:
            row[TICK_PEST:TICK_VEST] = fit(as_floats(v.p_est), 3)
            row[TICK_VEST:TICK_WIND] = NAN if v.v_est is None else fit(as_floats(v.v_est), 3)
        row[TICK_WIND:TICK_SPRAY] = fit(as_floats(v.wind), 3)
        row[TICK_SPRAY] = 1.0 if v.spray else 0.0
        nm = self.n_motors
        row[TICK_HEAD:TICK_HEAD + nm] = fit(as_floats(v.motors), nm)
        g = (v.ctrl or {}).get
        row[TICK_HEAD + nm:] = [g(k, NAN) for k in self.ctrl_keys]
        self._rows.commit()

    SPRAY_FIELDS = ("t", "tank_l", "mass_kg", "flow_lps", "nozzles", "power_w", "energy_wh",
                    "battery_frac", "sortie", "ground")

    def spray_state(self, t: float, *, tank_l: float, mass_kg: float, flow_lps: float,
                    nozzles: bool, power_w: float, energy_wh: float, soc: float, sortie: int,
                    ground: bool) -> None:
        """Spray job state (ag_uav.world.spray_job) -> ``/drone/spray`` (``ag_uav.SprayState``:
        tank, vehicle mass, flow, nozzles on, electrical power, energy used, battery fraction left,
        sortie number, on the ground at the base). Logged at the ``state`` group's rate."""
        self.spray_row(t, (tank_l, mass_kg, flow_lps, 1.0 if nozzles else 0.0, power_w,
                           energy_wh, soc, sortie, 1.0 if ground else 0.0))

    def spray_row(self, t: float, values: Sequence[float]) -> None:
        """:meth:`spray_state` with its values as one sequence in :data:`SPRAY_FIELDS` order
        after ``t`` (nozzles and ground as 1.0 / 0.0)."""
        row = self.spray_slot(t)
        if row is not None:
            row[1:] = values
            self.spray_commit()

    def spray_slot(self, t: float) -> np.ndarray | None:
        """The ``/drone/spray`` row to fill at sim time ``t`` (None when none is due): column 0
        holds ``t``, the caller fills the :data:`SPRAY_FIELDS` after it and calls
        :meth:`spray_commit` (the engine's way)."""
        if t < self._next_spray:  # inf when off or closed
            return None
        self._next_spray = t + self._p_state
        if self._ch_spray is None:
            ch = self._ch
            schema = FlatSchema("ag_uav.SprayState", [(k, 0) for k in self.SPRAY_FIELDS])
            self._ch_spray = ch.register_flat(FlatRows(schema, ch.declare(
                "/drone/spray", "ag_uav.SprayState", schema.schema_data)))
            ch.on_layout()
        row = self._ch_spray.rows.open_row()
        row[0] = t
        return row

    def spray_commit(self) -> None:
        """The row of the last :meth:`spray_slot` is complete."""
        self._ch_spray.rows.commit()
        self._ch_spray.count += 1

    def spray_due(self, t: float) -> bool:
        """Would :meth:`spray_state` log at sim time ``t``? (no side effects)"""
        return t >= self._next_spray


    #: ``/gps/error``'s fields (:meth:`gps`)
    GPS_ERROR_FIELDS = ("t", "t_meas", "age", "truth.x", "truth.y", "truth.z", "err.x", "err.y",
                        "err.z", "err.horiz")

    def gps(self, t: float, fix_xyz: Sequence[float], var: Sequence[float] | None = None,
            fix_type: str | None = None, *, t_meas: float | None = None,
            truth: Sequence[float] | None = None) -> None:
        """A GPS fix (local ENU metres) arriving at ``t`` -> ``/gps`` PoseInFrame (log time
        ``t``, ``timestamp`` ``t_meas``: the time it was measured, default ``t``) and, once
        :meth:`geo` gave the origin, ``/geo/gnss`` LocationFix with the receiver's reported
        variances ``var`` (east, north, up, m²) and its ``fix_type`` (a colour and metadata
        ``fix_type``). With ``truth`` (the true position of the point the receiver measured,
        at ``t_meas``) also ``/gps/error``: the fix's own error, like with like."""
        if t < self._next["gps"]:  # inf when off or closed
            return
        self._next["gps"] = t + self._p_gps
        tm = t if t_meas is None else t_meas
        if truth is not None:
            self._gps_error(t, tm, fix_xyz, truth)
        row = self._gps_rows.open_row()
        row[0] = t
        row[8] = tm
        row[1], row[2] = fix_xyz[0], fix_xyz[1]
        row[3] = fix_xyz[2] if len(fix_xyz) > 2 else 0.0
        if var is None:
            row[4:7] = NAN
        else:
            row[4], row[5], row[6] = var[0], var[1], var[2]
        code = 0
        if fix_type is not None:
            code = self._fix_codes.get(fix_type, 0)
            if not code:
                code = self._fix_code(fix_type)
        row[7] = code
        self._gps_rows.commit()
        self._n_gps += 1
        if self._geo.frame is not None and self._geo.has("gnss"):
            self._n_geo_gnss += 1

    def _gps_error(self, t: float, tm: float, fix: Sequence[float], tr: Sequence[float]
                   ) -> None:
        """One ``/gps/error`` row (its channel declared at the first)."""
        if self._ch_gps_err is None:
            ch = self._ch
            schema = FlatSchema("ag_uav.GnssError", [(k, 0) for k in self.GPS_ERROR_FIELDS])
            self._ch_gps_err = ch.register_flat(FlatRows(schema, ch.declare(
                "/gps/error", "ag_uav.GnssError", schema.schema_data)))
        ex, ey = float(fix[0]) - float(tr[0]), float(fix[1]) - float(tr[1])
        ez = float(fix[2]) - float(tr[2]) if len(fix) > 2 else NAN
        self._ch_gps_err.put((t, tm, t - tm, float(tr[0]), float(tr[1]), float(tr[2]), ex, ey,
                              ez, (ex * ex + ey * ey) ** 0.5))

    def _fix_code(self, fix_type: str) -> int:
        """The code of a GNSS fix type in the gps rows (declared to the writer once)."""
        code = self._fix_codes[fix_type] = len(self._fix_codes) + 1
        self._ch.ops.append(("fixtype", code, str(fix_type)))
        return code
