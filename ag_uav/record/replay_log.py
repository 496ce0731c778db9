"""The MCAP of a replayed flight (``ag-uav replay``), for Foxglove: every rule's estimate, the
reference and the autopilot's own estimate side by side, and the fixes with the gate's verdicts.

Topics (JSON messages with a JSON schema, which Foxglove plots by field; the geographic ones in
the well-known ``foxglove.LocationFix`` schema of the run log, :mod:`ag_uav.record.geo`, for the
Map panel, when the log has a geodetic origin):

==========================  ==========================================================
``/replay/<rule>``          t, p (ENU m), v (m/s), roll/pitch/yaw (°) of each rule's
                            output (≤ 20 Hz); the flown rule adds its 1σ position
``/replay/reference``       the reference track on the same grid (where it exists)
``/replay/autopilot``       the autopilot's estimate (PX4 EKF2, ArduPilot EKF1)
``/replay/gnss``            each fix handed to the INS: p, its reported σ, the flown rule's
                            gate verdict (0 fused, 1 rejected, 2 reset, 3 held by the latch)
``/geo/<rule>``,            LocationFix of the same (Map panel)
``/geo/reference``, ...
==========================  ==========================================================
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from numkit.geometry import quats_to_rots, rots_to_euler

from ..navigation.replay.data import DEG
from ..navigation.replay.runner import ReplayResult
from .geo import GeoFrame, location_fixes

__all__ = ["write_replay_mcap"]

_SCHEMA = json.dumps({"type": "object", "properties": {
    "t": {"type": "number"}, "p": {"type": "array"}, "v": {"type": "array"},
    "rpy_deg": {"type": "array"}}}).encode()
RATE_HZ = 20.0


def _ns(t: float, t0: float) -> int:
    return int(round((t - t0) * 1e9)) + 1


def _rows(t: np.ndarray, p: np.ndarray, v: np.ndarray | None, R: np.ndarray | None,
          extra: dict[str, np.ndarray] | None = None) -> list[dict]:
    rpy = rots_to_euler(R) / DEG if R is not None else None
    out = []
    for k in range(t.size):
        if not np.all(np.isfinite(p[k])):
            continue
        m = {"t": float(t[k]), "p": p[k].round(4).tolist()}
        if v is not None and np.all(np.isfinite(v[k])):
            m["v"] = v[k].round(4).tolist()
        if rpy is not None and np.all(np.isfinite(rpy[k])):
            m["rpy_deg"] = rpy[k].round(3).tolist()
        for key, a in (extra or {}).items():
            m[key] = np.round(a[k], 4).tolist()
        out.append(m)
    return out


def write_replay_mcap(path: Path, res: ReplayResult, summary: dict) -> dict[str, int]:
    """Write the MCAP (module docstring); returns the messages per topic."""
    import foxglove
    from mcap.writer import Writer

    every = max(1, int(round(1.0 / (RATE_HZ * float(res.t[1] - res.t[0])))))
    sel = np.arange(0, res.t.size, every)
    t = res.t[sel]
    t0 = min(float(res.t[0]), float(res.fix_t.min()) if res.fix_t.size else np.inf) - 1.0
    topics: dict[str, list[dict]] = {}
    for i, rule in enumerate(res.rules):
        x = res.x[sel, i]
        extra = ({"sd_p": np.sqrt(np.maximum(res.pdiag[sel, :3], 0.0))} if i == 0 else None)
        topics[f"/replay/{rule}"] = _rows(t, x[:, :3], x[:, 3:6], quats_to_rots(x[:, 6:10]),
                                          extra)
    for name, track in (("reference", res.log.reference), ("autopilot", res.log.autopilot)):
        if track is not None:
            p, R = track.at(t)
            topics[f"/replay/{name}"] = _rows(t, p, None, R)
    ev = res.fix_events[res.rules[0]]
    verdict = np.full(res.fix_t.size, np.nan)
    for row in ev:   # the verdict of the fix nearest in time (the core's tick)
        if res.fix_t.size:
            verdict[int(np.argmin(np.abs(res.fix_t - row[0])))] = row[1]
    topics["/replay/gnss"] = [
        {"t": float(res.fix_t[j]), "p": res.fix_p[j].round(4).tolist(),
         "sd": np.sqrt(res.fix_var[j]).round(4).tolist(),
         "gate": None if not np.isfinite(verdict[j]) else int(verdict[j])}
        for j in range(res.fix_t.size)]
    counts: dict[str, int] = {}
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="ag-uav replay")
        sid = w.register_schema(name="ag_uav.ReplayState", encoding="jsonschema", data=_SCHEMA)
        for topic, msgs in topics.items():
            cid = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
            for m in msgs:
                tn = _ns(m["t"], t0)
                w.add_message(cid, log_time=tn, publish_time=tn, data=json.dumps(m).encode())
            counts[topic] = len(msgs)
        if res.log.origin is not None:
            counts.update(_geo(w, foxglove.messages.LocationFix.get_schema(), res.log.origin,
                               topics, t0))
        w.add_metadata("replay", {k: json.dumps(v) for k, v in summary.items()
                                  if k in ("info", "against", "against_label")})
        w.finish()
    return counts


def _geo(w, sc, origin, topics: dict[str, list[dict]], t0: float) -> dict[str, int]:
    """``/geo/...`` LocationFix of every track (Map panel)."""
    sid = w.register_schema(name=sc.name, encoding=sc.encoding, data=bytes(sc.data))
    frame = GeoFrame(origin)
    counts = {}
    for topic, msgs in topics.items():
        if not msgs:
            continue
        geo = "/geo/" + topic.split("/")[-1]
        cid = w.register_channel(topic=geo, message_encoding="protobuf", schema_id=sid)
        tns = [_ns(m["t"], t0) for m in msgs]
        lla = frame.lla(np.array([m["p"] for m in msgs]))
        for tn, data in zip(tns, location_fixes(tns, lla), strict=True):
            w.add_message(cid, log_time=tn, publish_time=tn, data=data)
        counts[geo] = len(msgs)
    return counts
