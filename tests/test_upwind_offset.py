"""The plan moved upwind by the pattern's own downwind shift (no flights: the pattern test)."""

import math

import numpy as np
import pytest
import shapely

from ag_uav.config import ConfigError
from ag_uav.config import load_config as _load_config
from ag_uav.world import pattern
from ag_uav.world.mission import build_field, build_plan

#: the plan made on the flown wind (the offset's law, not the forecast's error)
EXACT = {"forecast.speed_sigma_mps": 0.0, "forecast.direction_sigma_deg": 0.0}


def load_config(over=None):
    return _load_config(None, {**EXACT, **(over or {})})


def test_pattern_shift_is_the_centre_of_the_half_peak_width():
    y = np.arange(-10.0, 10.01, 0.25)
    bump = np.exp(-0.5 * ((y - 1.5) / 0.8) ** 2)
    # a symmetric pass lies at its centre; out and back averaged, then the masses averaged
    assert pattern.pattern_shift(y, ((bump, bump),)) == pytest.approx(1.5, abs=0.13)
    wide = np.exp(-0.5 * ((y + 0.5) / 2.0) ** 2)
    s = pattern.pattern_shift(y, ((bump, bump), (wide, wide)))
    assert s == pytest.approx(0.5 * (1.5 - 0.5), abs=0.13)
    # a long downwind tail below half the peak does not move it (the centroid would)
    tail = bump + 0.2 * np.where(y > 3.0, np.exp(-(y - 3.0) / 4.0), 0.0)
    assert pattern.pattern_shift(y, ((tail, tail),)) == pytest.approx(1.5, abs=0.13)
    assert (tail * y).sum() / tail.sum() > 2.2
    assert pattern.pattern_shift(y, ((0 * y, 0 * y),)) == 0.0


def test_the_shift_follows_the_crosswind_and_the_plan_moves_upwind():
    cfg = load_config()                                    # 3 m/s from 240°, legs at 120°
    lc = pattern.lane_choice(cfg)
    c = pattern.pattern_shift(lc.y, lc.profiles)
    # downwind of the track: the sign of the crosswind, a metre or so at 3 m/s
    assert np.sign(c) == np.sign(lc.case.wind_cross_mps) and 0.2 < abs(c) < 3.0
    strong = load_config({"wind.speed_mps": 5.0})
    ls = pattern.lane_choice(strong)
    assert abs(pattern.pattern_shift(ls.y, ls.profiles)) > abs(c)     # more wind, more shift
    dx, dy = pattern.mission_offset(cfg)
    assert math.hypot(dx, dy) == pytest.approx(abs(c))
    blowing = np.array([math.sin(math.radians(60.0)), math.cos(math.radians(60.0))])  # to 060°
    t = math.radians(lc.case.legs_deg)
    assert np.dot([dx, dy], blowing) == pytest.approx(-abs(c))           # upwind ...
    assert np.dot([dx, dy], [math.cos(t), math.sin(t)]) == pytest.approx(0.0, abs=1e-9)  # across
    plan = build_plan(cfg, build_field(cfg))
    base = build_plan(load_config({"mission.upwind_offset_m": 0.0}), build_field(cfg))
    assert "offset_m" not in base.meta and plan.meta["offset_m"] == (dx, dy)
    assert len(plan.segments) == len(base.segments) and plan.swath == base.swath
    for a, b in zip(plan.segments, base.segments, strict=True):
        assert a.kind == b.kind and a.spray == b.spray
        np.testing.assert_allclose(a.points, b.points + [dx, dy])


def test_a_number_moves_the_plan_that_far_and_calm_air_not_at_all():
    cfg = load_config({"mission.upwind_offset_m": 2.0})
    dx, dy = pattern.mission_offset(cfg)
    assert math.hypot(dx, dy) == pytest.approx(2.0)
    assert np.dot([dx, dy], [math.sin(math.radians(60.0)), math.cos(math.radians(60.0))]) < 0
    assert pattern.mission_offset(load_config({"wind.speed_mps": 0.0})) == (0.0, 0.0)
    with pytest.raises(ConfigError, match="upwind_offset_m"):
        load_config({"mission.upwind_offset_m": -1.0})


def test_spread_winds_are_the_forecast_one_sigma_off():
    from ag_uav.world.forecast import SIGMA_POINTS, spread_winds

    w = spread_winds(3.0, 0.0, SIGMA_POINTS, 1.5, 30.0)
    assert w[0] == pytest.approx((4.5, 0.0)) and w[1] == pytest.approx((1.5, 0.0))
    assert w[2] == pytest.approx((3.0 * math.cos(math.pi / 6), 1.5))
    assert w[3] == pytest.approx((3.0 * math.cos(math.pi / 6), -1.5))
    assert spread_winds(1.0, 0.0, [(-2.0, 0.0)], 1.5, 0.0) == [(0.0, 0.0)]   # clipped at 0


def test_lanes_that_hold_in_the_forecasts_spread_are_no_wider():
    over = {"forecast.speed_sigma_mps": 1.5, "forecast.direction_sigma_deg": 30.0,
            "forecast.speed_mps": 4.0, "forecast.direction_deg": 240.0}
    plain = pattern.lane_choice(_load_config(None, over))
    cfg = _load_config(None, {**over, "mission.swath_spread": True})
    case = pattern.pattern_case(cfg)
    assert len(case.spread) == 4 and pattern.pattern_case(_load_config(None, over)).spread == ()
    robust = pattern.lane_choice(cfg)
    assert robust.cv_spread is None or robust.cv_spread <= 0.15
    assert 0 < robust.swath_m <= plain.swath_m and robust.cv <= 0.15
    # the spread's direction error puts a wind along the legs: the passes out and back differ
    assert any(abs(a) > 1.0 for _, a in case.spread)
    assert "one sigma off the forecast" in robust.text()
    # no forecast error: no spread, the lanes of the forecast alone
    exact = load_config({"mission.swath_spread": True})
    assert pattern.pattern_case(exact).spread == ()


def test_the_offset_keeps_the_flight_over_the_field():
    # the wake law's pattern lies further downwind than half its lanes: the boundary lap goes
    # at most onto the boundary
    cfg = load_config({"spray.deposition_law": "wake"})
    lc = pattern.lane_choice(cfg)
    assert abs(pattern.pattern_shift(lc.y, lc.profiles)) > 0.5 * lc.swath_m
    assert math.hypot(*pattern.mission_offset(cfg)) == pytest.approx(0.5 * lc.swath_m)
    plan = build_plan(cfg, build_field(cfg))
    grown = build_field(cfg).polygon.buffer(0.3)
    for s in plan.segments:
        if s.kind in ("leg", "headland"):
            assert all(grown.contains(shapely.Point(p)) for p in s.points)


def test_the_move_is_said_where_the_user_looks():
    """The fly report and ``ag-uav plan`` print the upwind move in one line; none when 0."""
    from ag_uav.world.mission import offset_text
    assert offset_text((0.0, 0.0), "auto") == ""
    line = offset_text((-0.6495, -0.375), "auto")
    assert "0.75 m upwind" in line and "pattern test's crosswind shift" in line
    assert "set by hand" in offset_text((1.0, 0.0), 1.0)


def test_the_move_keeps_the_flight_over_the_field():
    """A move that would carry waypoints out of the field is shortened until none is farther
    outside than before; a move that stays over it is kept whole."""
    from ag_uav.world.mission import over_the_field
    cfg = _load_config(None, {"forecast.speed_sigma_mps": 0, "forecast.direction_sigma_deg": 0,
                              "mission.upwind_offset_m": 0})
    fld = build_field(cfg)
    plan = build_plan(cfg, fld)
    pts = shapely.points(np.vstack([s.points[:, :2] for s in plan.segments]))

    def worst(d):
        moved = shapely.points(shapely.get_coordinates(pts) + np.asarray(d))
        out = ~shapely.covers(fld.polygon, moved)
        return float(shapely.distance(fld.polygon.boundary, moved[out]).max()) if out.any() else 0
    assert over_the_field(plan, fld, 0.0, 0.0) == (0.0, 0.0)
    dx, dy = over_the_field(plan, fld, 20.0, 0.0)
    assert 0.0 <= dx < 20.0 and dy == 0.0
    assert worst((dx, dy)) <= worst((0.0, 0.0)) + 1e-6 < worst((20.0, 0.0))
