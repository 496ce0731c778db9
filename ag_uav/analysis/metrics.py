"""Per-run metrics from the recorded trajectory (numpy/shapely, after the loop).

Definitions (all horizontal errors in the ENU x–y plane):

- ``tracking_rmse_m``: RMS of |p_true − p_ref| (horizontal) over the mission, i.e. from the first
  to the last tick with the sprayer on (take-off and the final hover are not part of it).
- ``cross_track_rmse_m`` / ``cross_track_max_m``: distance of the true position to the planned
  polyline of the active *spraying* segment (sweep legs and headland laps), over ticks with the
  sprayer on. Turns and transits are not counted (the sprayer is off there).
- ``altitude_rmse_m``: RMS of z_true − z_ref over the mission ticks.
- ``coverage_fraction`` / ``overlap_fraction``: :func:`ag_uav.analysis.coverage.spray_coverage` of
the true
  track while spraying, with the swath footprint; where the plan was moved upwind by the
  pattern's crosswind shift (``plan.meta["offset_m"]``), the footprint is moved back by it.
- ``completed``: not crashed, the reference ran to its end, the vehicle ended within half a swath
  of the path's end, and every leg was flown: while the leg was active the true track came within
  one swath of both of its ends. (How *well* it was flown is what the errors and the coverage
  say; a biased GPS makes a drone fly every leg, offset.)
- ``off_target_m2`` (``off_target_outside_m2`` + ``off_target_holes_m2``): area of the sprayed
  footprint (the same swath footprints as the coverage) farther than ``spray.offtarget_buffer_m``
  outside the field's boundary, or farther than that inside a hole (an obstacle or a no-spray
  zone); ``sprayed_area_m2`` is the footprint's whole area. :func:`off_target`.
- With sorties (:mod:`ag_uav.world.spray_job`) the inserted transits, climbs, descents and the time
on the
  ground at the base (seg < 0) are left out of the tracking and altitude errors.
- ``gnss_loss`` / ``gnss_lost_s`` / ``gnss_loss_off_target_m2`` / ``gnss_losses``: every
  GNSS loss (no fix for 1 s) with its time and the off-target area sprayed while the fix was
  lost, whatever ``gps.failsafe`` is. :func:`gnss_loss_summary`.
- ``mission_time_s``: time at which the drone's own position (the one it flies on: truth or
  estimate) first came within 0.5 m of the path's end after the last leg started, as an
  autopilot's "waypoint reached" (None if never).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import shapely

from ..config import Config
from .coverage import footprints, spray_coverage

#: ticks per block of the per-tick metrics (bounds their temporaries)
BLOCK = 1 << 16


def _sumsq(mask: np.ndarray, fn: Any, block: int = BLOCK) -> tuple[float, int]:
    """``(Σ v², count)`` over the values ``v = fn(a, b, m)`` of the ticks ``m = mask[a:b]`` of
    every block [a, b): a block's temporaries only, the squares summed in float64 by blocks
    (equal to a whole-array sum to rounding, and the same for any batch)."""
    total, cnt = 0.0, 0
    for a in range(0, len(mask), block):
        b = min(len(mask), a + block)
        v = np.asarray(fn(a, b, mask[a:b]), dtype=np.float64)
        total += float(np.sum(v * v))
        cnt += v.size
    return total, cnt


def _root_mean(total: float, cnt: int) -> float | None:
    return math.sqrt(total / cnt) if cnt else None


def _rate_rms(f: np.ndarray, hz: float, block: int = BLOCK) -> float | None:
    """RMS over every column of ``f``'s first difference times ``hz``, its squares summed a
    block of rows at a time (a whole job's rotor-command differences would be 54 MB): equal to
    the whole-array formula to rounding (the sum's order differs), the same for any batch."""
    m = len(f) - 1
    if m < 1:
        return None
    total = 0.0
    for a in range(0, m, block):
        b = min(m, a + block)
        d = np.diff(f[a:b + 1], axis=0)
        d *= hz
        total += float(np.sum(np.multiply(d, d, out=d)))
    return math.sqrt(total / (m * f.shape[1]))


def _path_length(p: np.ndarray, block: int = BLOCK) -> float:
    """Σ |p[k+1] − p[k]| (m), the steps' lengths summed a block at a time (equal to a
    whole-array sum to rounding)."""
    n = len(p)
    total = 0.0
    for a in range(0, n - 1, block):
        b = min(n - 1, a + block)
        total += float(np.sum(np.linalg.norm(p[a + 1:b + 1] - p[a:b], axis=1)))
    return total


def contiguous_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index pairs of the True runs of a boolean array."""
    m = np.concatenate([[False], mask.astype(bool), [False]])
    d = np.flatnonzero(np.diff(m.astype(np.int8)))
    return list(zip(d[::2].tolist(), d[1::2].tolist(), strict=True))


def _cross_track_pieces(res, plan):
    """``(c0, c1, distances)`` of each stretch of spraying ticks [c0, c1) on one planned
    segment: each spraying run, cut where the segment changes."""
    xy = res.p_true[:, :2]
    for a, b in contiguous_runs(res.spray):
        cuts = [a, *(a + 1 + np.flatnonzero(np.diff(res.seg[a:b]))).tolist(), b]
        for c0, c1 in zip(cuts[:-1], cuts[1:], strict=True):
            s = int(res.seg[c0])
            if 0 <= s < len(plan.segments):
                yield c0, c1, polyline_distance(xy[c0:c1], plan.segments[s].points)


def polyline_distance(p: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance of each point of ``p`` (n, 2) to the polyline ``line`` (m, 2): the least over
    its edges of GEOS's point-to-segment distance (``Distance::pointToSegment``, the same
    operations in the same order, so equal to ``shapely.distance`` to the bit)."""
    px, py = p[:, 0], p[:, 1]
    line = np.asarray(line, float)
    out = None
    for (ax, ay), (bx, by) in zip(line[:-1].tolist(), line[1:].tolist(), strict=True):
        da = np.sqrt((px - ax) * (px - ax) + (py - ay) * (py - ay))
        if ax == bx and ay == by:
            d = da
        else:
            len2 = (bx - ax) * (bx - ax) + (by - ay) * (by - ay)
            r = ((px - ax) * (bx - ax) + (py - ay) * (by - ay)) / len2
            d = np.abs(((ay - py) * (bx - ax) - (ax - px) * (by - ay)) / len2) * math.sqrt(len2)
            d = np.where(r <= 0.0, da, np.where(
                r >= 1.0, np.sqrt((px - bx) * (px - bx) + (py - by) * (py - by)), d))
        out = d if out is None else np.minimum(out, d)
    return out if out is not None else np.sqrt(
        (px - line[0, 0]) ** 2 + (py - line[0, 1]) ** 2)


def cross_track(res, plan) -> np.ndarray:
    """Distance (m) of each spraying tick's true position to its planned segment (NaN elsewhere)."""
    out = np.full(len(res.t), np.nan)
    for c0, c1, d in _cross_track_pieces(res, plan):
        out[c0:c1] = d
    return out


def _cross_track_stats(res, plan) -> tuple[float | None, float | None]:
    """RMS and max of :func:`cross_track`'s finite values, stretch by stretch (no per-tick
    array; the RMS equal to the whole array's to rounding)."""
    total, cnt, mx = 0.0, 0, -math.inf
    for _, _, d in _cross_track_pieces(res, plan):
        d = d[np.isfinite(d)]
        if d.size:
            total += float(np.sum(d * d))
            cnt += d.size
            mx = max(mx, float(d.max()))
    return _root_mean(total, cnt), (mx if cnt else None)


def off_target(field, tracks, swath: float, buffer_m: float = 0.0) -> dict[str, float]:
    """Sprayed area off the target: ``outside`` = footprint − (field exterior grown by
    ``buffer_m``), ``holes`` = footprint ∩ (each hole shrunk by ``buffer_m``); plus ``sprayed``,
    the footprint's area (m²). Footprints as :func:`ag_uav.analysis.coverage.footprints`."""
    fps = footprints(tracks, swath) if tracks else []
    if not fps:
        return {"outside": 0.0, "holes": 0.0, "sprayed": 0.0}
    union = shapely.union_all(fps)
    parts = list(field.parts)   # a multi-part field: every part with its own holes
    outer = shapely.union_all([shapely.Polygon(p.exterior.coords) for p in parts])
    grown = outer.buffer(buffer_m, join_style="mitre") if buffer_m > 0 else outer
    outside = union.difference(grown).area
    holes = 0.0
    for ring in (r for p in parts for r in p.interiors):
        h = shapely.Polygon(ring.coords)
        h = h.buffer(-buffer_m, join_style="mitre") if buffer_m > 0 else h
        if not h.is_empty:
            holes += union.intersection(h).area
    return {"outside": float(outside), "holes": float(holes), "sprayed": float(union.area)}


def _legs_flown(res, plan, legs: list[int]) -> int:
    """The legs whose both ends the flight passed within a swath of."""
    flown = 0
    for i in legs:
        idx = np.flatnonzero(res.seg == i)
        if not idx.size:
            continue
        pts = plan.segments[i].points
        xy = res.p_true[idx, :2]
        d0 = np.min(np.hypot(*(xy - pts[0]).T))
        d1 = np.min(np.hypot(*(xy - pts[-1]).T))
        if d0 < plan.swath and d1 < plan.swath:
            flown += 1
    return flown


def _mission_time(res, legs: list[int], end: np.ndarray) -> float | None:
    """The sim time the fed-back position first came within 0.5 m of the plan's end after the
    last leg began (None: never)."""
    last_leg_ticks = np.flatnonzero(res.seg == legs[-1])
    if not last_leg_ticks.size:
        return None
    after = np.arange(last_leg_ticks[0], len(res.t))
    dist = np.hypot(*(res.p_fb[after, :2] - end).T)
    hit = np.flatnonzero(dist < 0.5)
    return float(res.t[after[hit[0]]]) if hit.size else None


def summarise(res, cfg: Config, *, crash_reason: str | None, crash_time: float | None,
              reference=None) -> dict[str, Any]:
    plan = res.plan
    crashed = crash_reason is not None
    n = len(res.t)
    spray_idx = np.flatnonzero(res.spray)
    if spray_idx.size:
        mission = slice(int(spray_idx[0]), int(spray_idx[-1]) + 1)
    else:
        mission = slice(0, n)
    on_plan = np.zeros(n, bool)
    on_plan[mission] = True
    on_plan &= res.seg >= 0  # sorties: not the base transits, climbs, descents, ground time
    # a block at a time: a whole job's per-tick copies are 13.5 MB apiece
    pt, pr = res.p_true, res.p_ref
    tracking = _root_mean(*_sumsq(on_plan, lambda a, b, m: np.hypot(
        pt[a:b, 0][m] - pr[a:b, 0][m], pt[a:b, 1][m] - pr[a:b, 1][m])))
    alt = _root_mean(*_sumsq(on_plan, lambda a, b, m: pt[a:b, 2][m] - pr[a:b, 2][m]))
    ct_rms, ct_max = _cross_track_stats(res, plan)
    # the footprint lies where the plan puts the pattern: a plan moved upwind by the pattern's
    # crosswind shift (plan.meta["offset_m"], ag_uav.world.mission.shifted) lays it back downwind
    back = plan_offset(plan)
    tracks = [res.p_true[a:b, :2] - back for a, b in contiguous_runs(res.spray) if b - a >= 2]
    cov, ovl = spray_coverage(res.field, tracks, plan.swath) if tracks else (0.0, 0.0)
    off = off_target(res.field, tracks, plan.swath, cfg.spray.offtarget_buffer_m)
    path_len = _path_length(res.p_true)
    # motor effort: RMS rate of the rotor-thrust commands over the spraying part (N/s per rotor)
    motor_rate = _rate_rms(np.asarray(res.motors, dtype=float)[mission], cfg.sim.control_hz)

    end = np.asarray(plan.end, dtype=float)
    dt = 1.0 / cfg.sim.control_hz
    ref_done = reference is not None and n and res.t[-1] >= reference.duration - 1.5 * dt
    final_err = float(np.hypot(*(res.p_true[-1, :2] - end))) if n else float("inf")
    legs = [i for i, s in enumerate(plan.segments) if s.kind == "leg"]
    legs_flown = _legs_flown(res, plan, legs)
    swath = plan.swath
    completed = bool(not crashed and ref_done and final_err < 0.5 * swath
                     and legs_flown == len(legs))
    mission_time = _mission_time(res, legs, end) if n and legs else None

    def r(x: float | None, nd: int = 4) -> float | None:
        return None if x is None else round(float(x), nd)

    return {
        "completed": completed,
        "crashed": crashed,
        "crash_reason": crash_reason,
        "crash_time_s": r(crash_time, 3),
        "mission_time_s": r(mission_time, 2),
        "tracking_rmse_m": r(tracking),
        "cross_track_rmse_m": r(ct_rms),
        "cross_track_max_m": r(ct_max),
        "altitude_rmse_m": r(alt),
        "motor_rate_rms_nps": r(motor_rate),
        "coverage_fraction": r(cov, 5),
        "overlap_fraction": r(ovl, 5),
        "sprayed_area_m2": r(off["sprayed"], 1),
        "off_target_m2": r(off["outside"] + off["holes"], 2),
        "off_target_outside_m2": r(off["outside"], 2),
        "off_target_holes_m2": r(off["holes"], 2),
        "path_length_m": r(path_len, 2),
        "planned_path_length_m": r(plan.length, 2),
        "legs": len(legs),
        "legs_flown": legs_flown,
        "final_position_error_m": r(final_err),
        "field_area_m2": r(res.field.area, 1),
        "sweep_direction_deg": r(plan.direction_deg, 2),
    }


def plan_offset(plan: Any) -> np.ndarray:
    """The plan's upwind move (east, north; m): a footprint is laid back downwind by it, where
    the crosswind's shift of the pattern puts the deposit (``ag_uav.world.mission.shifted``)."""
    return np.asarray(plan.meta.get("offset_m", (0.0, 0.0)), dtype=float)


def _off_target_in(res, cfg: Config, plan: Any, windows: list[tuple[float, float]]) -> float:
    """Off-target area (m², :func:`off_target`) of the swath sprayed in the time ``windows``,
    laid back by the plan's upwind move as the run's own off-target area is."""
    m = np.zeros(len(res.t), dtype=bool)
    for a, b in windows:
        m |= (res.t >= a) & (res.t < b)
    runs = contiguous_runs(res.spray & m)
    back, swath = plan_offset(plan), plan.swath
    tracks = [res.p_true[a:b, :2] - back for a, b in runs if b - a >= 2]
    off = off_target(res.field, tracks, swath, cfg.spray.offtarget_buffer_m)
    return round(off["outside"] + off["holes"], 1)


def gnss_loss_summary(res, cfg: Config, losses: list[dict[str, Any]], plan: Any
                      ) -> dict[str, Any]:
    """The summary's GNSS losses (``{}`` without one), whatever ``gps.failsafe`` is:
    ``gnss_losses`` (each episode of :class:`ag_uav.engine.stages.GnssLoss` with its
    ``off_target_m2``: the off-target area of the swath sprayed from its last fix to its next
    one, or the end), ``gnss_lost_s`` (the first loss's time), ``gnss_loss_off_target_m2``
    (over every loss) and ``gnss_loss``, one line naming the first loss."""
    if not losses:
        return {}
    end = math.inf

    def window(ep: dict[str, Any]) -> tuple[float, float]:
        return ep["last_fix_s"], end if ep["regained_s"] is None else ep["regained_s"]

    for ep in losses:
        ep["off_target_m2"] = _off_target_in(res, cfg, plan, [window(ep)])
    total = _off_target_in(res, cfg, plan, [window(ep) for ep in losses])
    ep = losses[0]
    back = ("not regained" if ep["regained_s"] is None
            else f"regained at t={ep['regained_s']}s")
    more = f" (and {len(losses) - 1} more)" if len(losses) > 1 else ""
    line = (f"GNSS lost at t={ep['lost_s']}s (no fix after t={ep['last_fix_s']}s), {back}"
            f"{more}: {total:.1f} m² sprayed off target while lost")
    return {"gnss_loss": line, "gnss_lost_s": ep["lost_s"], "gnss_loss_off_target_m2": total,
            "gnss_losses": losses}


#: a vehicle whose highest point is less than this above its start never left the ground (m)
TAKEOFF_MIN_CLIMB_M = 0.5


def incomplete_reason(summary: dict[str, Any], res, cfg: Config) -> str | None:
    """Why a flight that did not crash is not completed, in one line (None when it completed,
    crashed, or nothing more specific than a cut by ``sim.max_time_s`` is known): it never
    left the ground (its highest point under :data:`TAKEOFF_MIN_CLIMB_M` above the start: say,
    a take-off weight over the rotors' thrust), never reached the first leg, flew only some
    legs, or stopped short of the plan's end."""
    if summary.get("completed") or summary.get("crashed") or not len(res.t):
        return None
    z = np.asarray(res.p_true[:, 2], dtype=float)
    climb = float(np.max(z) - z[0])
    if climb < TAKEOFF_MIN_CLIMB_M:
        return (f"never took off: the highest point is {climb:.2f} m above the start (mission "
                f"altitude {cfg.mission.altitude_m:g} m; vehicle.thrust_to_weight = "
                f"{cfg.vehicle.thrust_to_weight:g})")
    legs, flown = summary.get("legs", 0), summary.get("legs_flown", 0)
    if legs and not flown:
        return "never reached the first leg"
    if flown < legs:
        return f"flew {flown} of {legs} legs"
    return (f"ended {summary.get('final_position_error_m', float('nan')):.2f} m from the "
            "plan's end")


def add_sortie_areas(summary: dict[str, Any], res, swath: float) -> None:
    """Add ``area_m2`` (the union of the swath footprints sprayed in that sortie, as the
    coverage computes them) to each row of ``summary["sortie_table"]``."""
    import shapely

    rows = summary.get("sortie_table") or []
    sortie = res.extra.get("spray", {}).get("sortie")
    if not rows or sortie is None:
        return
    runs = [(a, b) for a, b in contiguous_runs(res.spray) if b - a >= 2]
    for i, row in enumerate(rows):
        tracks = [res.p_true[a:b, :2] for a, b in runs if sortie[a] == i]
        fps = footprints(tracks, swath)
        row["area_m2"] = round(float(shapely.union_all(fps).area), 1) if fps else 0.0
