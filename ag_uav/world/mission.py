"""The mission's world from the config: the field (``mission.field``), the coverage plan over it
(lanes from :func:`ag_uav.world.pattern.lane_choice`) and the field's outline. (The reference
flown along the plan, which needs the vehicle for the spray job's landing height, is built by
:func:`ag_uav.engine.missions.build_reference`.)"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
import shapely
from shapely import affinity

from numkit.axes import XY

from ..config import Config, ConfigError
from .field import DEFAULT_ORIGIN, Field, load_field
from .geodesy import ORIGIN
from .pattern import lane_choice, mission_direction, mission_headland, mission_offset
from .plan import CoveragePlan, Segment, plan_coverage

#: how far (m) a field may reach from the origin a config names: the local tangent plane's
#: length error is ~d²/6R² (1e-7 at 5 km; :mod:`ag_uav.world.field`)
ORIGIN_REACH_M = 20_000.0


def build_field(cfg: Config) -> Field:
    """The field of ``mission.field`` with the run's geodetic origin (:attr:`Field.origin`):
    ``mission.origin_*`` where given (a lon/lat field is then projected about it), else a
    lon/lat field's own origin, else :data:`~ag_uav.world.field.DEFAULT_ORIGIN`."""
    m = cfg.mission
    given = None
    if m.origin_lat_deg != "auto":
        given = (float(m.origin_lat_deg), float(m.origin_lon_deg))
    try:
        fld = load_field(m.field)
        if fld.origin is None or given is not None or m.origin_alt_m != "auto":
            o = fld.origin or DEFAULT_ORIGIN
            org = (given or (o[ORIGIN.LAT], o[ORIGIN.LON]))
            alt = float(m.origin_alt_m) if m.origin_alt_m != "auto" else o[ORIGIN.H]
            fld = load_field(m.field, origin=(*org, alt))
    except ValueError as e:
        raise ConfigError(f'mission.field = "{m.field}": {e}') from None
    reach = max(abs(v) for v in fld.bounds)
    if reach > ORIGIN_REACH_M:
        key, v = (("origin_lat_deg", m.origin_lat_deg) if given else
                  ("origin_alt_m", m.origin_alt_m))
        raise ConfigError(f"mission.{key} = {v}: the field reaches {reach / 1000:.1f} km from "
                          f"the origin {fld.origin[0]:.6f}, {fld.origin[1]:.6f}; an origin must "
                          f"lie within {ORIGIN_REACH_M / 1000:g} km of the field (a local "
                          "tangent plane)")
    return fld


def build_plan(cfg: Config, fld: Field) -> CoveragePlan:
    """The coverage plan of ``cfg``'s mission over ``fld`` with the mission's lanes
    (``plan.swath``; ``plan.meta["lanes"]`` is the :class:`~ag_uav.world.pattern.LaneChoice`)."""
    m = cfg.mission
    direction = mission_direction(cfg)
    lanes = lane_choice(cfg)
    if lanes.swath_m <= 0:
        raise ConfigError(f'mission.swath_m = "auto": {lanes.text()}; set mission.swath_m to a '
                          "number or raise mission.swath_cv_max")
    try:
        plan = plan_coverage(fld, swath=lanes.swath_m, headland=mission_headland(cfg),
                             direction_deg=direction)
    except ValueError as e:
        what = m.swath_m if lanes.source == "config" else f'"auto" ({lanes.swath_m:g} m)'
        raise ConfigError(f"mission.swath_m = {what}: {e}") from None
    plan.meta["lanes"] = lanes
    return shifted(plan, *over_the_field(plan, fld, *mission_offset(cfg)))


def over_the_field(plan: CoveragePlan, fld: Field, dx: float, dy: float,
                   steps: int = 12) -> tuple[float, float]:
    """The largest share of the move (dx, dy) that takes no waypoint of ``plan`` farther outside
    ``fld`` than it was (bisection over the share, ``steps`` halvings): the flight stays over
    the field where a turn or a lap near a slanted edge would carry it out."""
    if dx == 0.0 and dy == 0.0:
        return dx, dy
    pts = np.vstack([sg.points[:, XY] for sg in plan.segments])
    edge = fld.polygon.boundary

    def outside(share: float) -> float:
        moved = shapely.points(pts + share * np.array([dx, dy]))
        out = ~shapely.covers(fld.polygon, moved)
        return float(shapely.distance(edge, moved[out]).max()) if out.any() else 0.0

    limit = outside(0.0) + 1e-6
    if outside(1.0) <= limit:
        return dx, dy
    lo, hi = 0.0, 1.0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if outside(mid) <= limit else (lo, mid)
    return round(lo * dx, 9), round(lo * dy, 9)


def shifted(plan: CoveragePlan, dx: float, dy: float) -> CoveragePlan:
    """``plan`` moved by (dx, dy) m (:func:`~ag_uav.world.pattern.mission_offset`: upwind, so
    that the crosswind's shift of the pattern puts the deposit where the plan's lanes are);
    ``meta["offset_m"]`` is the move. The plan itself when there is none."""
    if dx == 0.0 and dy == 0.0:
        return plan
    d = np.array([dx, dy])
    segs = [Segment(s.kind, s.points + d, s.spray) for s in plan.segments]
    return dataclasses.replace(plan, segments=segs,
                               interior=affinity.translate(plan.interior, dx, dy),
                               meta={**plan.meta, "offset_m": (float(dx), float(dy))})


def offset_text(offset_m: Sequence[float], setting: Any) -> str:
    """One line for the plan's upwind move (:func:`shifted`), or "" when it was not moved."""
    d = float(np.hypot(*offset_m)) if len(offset_m) == 2 else 0.0
    if d == 0.0:
        return ""
    why = ("the pattern test's crosswind shift, at most half the lanes" if setting == "auto"
           else "set by hand")
    return (f"plan moved {d:.2f} m upwind across the legs ({why}; mission.upwind_offset_m = "
            f"{setting!r}, 0 turns it off)")


def field_outline(fld: Field) -> list[np.ndarray]:
    """Closed rings of the field: every part's boundary and its holes (local metres)."""
    return [np.asarray(r) for outer, holes in fld.rings() for r in (outer, *holes)]
