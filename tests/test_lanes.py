"""Lanes from the pattern: ``mission.swath_m = "auto"`` gives the plan, the sortie planner, the
nozzles and the exports the pattern test's effective swath (ag_uav.world.pattern)."""

import json

import numpy as np
import pytest

from ag_uav.cli import main
from ag_uav.config import ConfigError
from ag_uav.config import load_config as _load_config
from ag_uav.world import pattern
from ag_uav.world.deposition import DepositionConfig
from ag_uav.world.mission import build_field, build_plan
from ag_uav.world.spray_job import liquid_l_per_m

#: the plan made on the flown wind (no forecast error): these tests are about the lanes' law
EXACT = {"forecast.speed_sigma_mps": 0.0, "forecast.direction_sigma_deg": 0.0}


def load_config(path, over=None):
    return _load_config(path, {**EXACT, **(over or {})})


@pytest.fixture(scope="module")
def calm():
    return load_config(None, {"wind.speed_mps": 0.0})


def test_auto_spacing_is_the_effective_swath_of_a_calm_pattern(calm):
    lanes = pattern.lane_choice(calm)
    # the oracle: the pattern test run by hand at the mission's figures (3 m, 5 m/s, calm,
    # the body-x drag) with a full 2.7 L tank and an empty one: the worse CV of the two. In calm
    # air the pass back is the pass out mirrored, so the back-and-forth overlay is the plain one
    # (lanes up to 8 m, to 2e-3: the overlays treat the profile's far tail differently)
    dc = DepositionConfig.from_config(calm, swath_m=6.0)
    sp = pattern.SPACINGS
    cvs = []
    for mass in (6.47 + 2.7, 6.47):
        y, p, _ = pattern.single_pass(dc, 5.0, 3.0, 0.0, mass, 0.25, 0.18)
        cvs.append(pattern.cv_vs_spacing(y, p, sp))
        near = sp <= 8.0
        np.testing.assert_allclose(pattern.cv_back_and_forth(y, p, p[::-1], sp[near]),
                                   cvs[-1][near], atol=2e-3)
    cv = np.maximum(*cvs)
    # the default rule (CV <= 15 %) and the effective swath proper (CV <= 25 %)
    assert lanes.source == "auto" and lanes.swath_m == pattern.effective_swath(sp, cv, 0.15)
    assert lanes.swath_m < pattern.effective_swath(sp, cv, 0.25)
    lanes = pattern.lane_choice(load_config(None, {"wind.speed_mps": 0.0,
                                                   "mission.swath_cv_max": 0.25}))
    want = pattern.effective_swath(sp, cv, 0.25)
    assert lanes.source == "auto" and lanes.swath_m == want
    assert 2.0 < want < 12.0
    i = int(np.argmin(np.abs(sp - want)))
    assert cv[i] <= 0.25 < cv[i + 1:].min()      # widest with CV <= 25 %: every wider one fails
    assert lanes.cv == pytest.approx(cv[i], abs=1e-4)   # back-and-forth vs plain overlay
    assert "calm" in lanes.text() and f"lanes {want:g} m" in lanes.text()


def test_the_plan_sprayer_and_sortie_planner_use_the_lanes(calm):
    lanes = pattern.lane_choice(calm)
    plan = build_plan(calm, build_field(calm))
    assert plan.swath == lanes.swath_m and plan.meta["lanes"] is lanes
    # equal strips over the interior: the legs are at most one lane apart
    assert lanes.swath_m * 0.8 < plan.spacing <= lanes.swath_m + 1e-9
    assert plan.headland == lanes.swath_m and plan.n_headland == 1     # headland_m = "auto"
    assert liquid_l_per_m(calm) == pytest.approx(calm.spray.rate_l_per_ha * lanes.swath_m / 1e4)


def test_a_number_sets_the_lanes_by_hand_and_headland_follows():
    cfg = load_config(None, {"mission.swath_m": 5.5})
    lanes = pattern.lane_choice(cfg)
    assert (lanes.swath_m, lanes.source, lanes.case) == (5.5, "config", None)
    assert "set by hand" in lanes.text()
    plan = build_plan(cfg, build_field(cfg))
    assert plan.swath == 5.5 and plan.headland == 5.5
    cfg = load_config(None, {"mission.swath_m": 5.5, "mission.headland_m": 0.0})
    assert build_plan(cfg, build_field(cfg)).n_headland == 0


def test_the_choice_is_cached_deterministic_and_depends_on_its_inputs(calm):
    a = pattern.lane_choice(calm)
    assert pattern.lane_choice(load_config(None, {"wind.speed_mps": 0.0})) is a   # cached
    pattern._CACHE.clear()
    b = pattern.lane_choice(calm)
    assert b is not a and b == a and np.array_equal(b.profiles, a.profiles)     # recomputed
    # what the pattern test depends on changes it; what it does not (the seed) does not
    assert pattern.lane_choice(load_config(None, {"wind.speed_mps": 0.0, "seed": 9})) is b
    strict = pattern.lane_choice(load_config(None, {"wind.speed_mps": 0.0,
                                                    "mission.swath_cv_max": 0.1}))
    assert strict.swath_m < a.swath_m and strict.cv <= 0.1
    assert "CV <= 10 %" in strict.text()
    low = pattern.pattern_case(load_config(None, {"mission.altitude_m": 2.0}))
    assert low.height_m == 2.0


def test_the_default_legs_run_across_the_wind():
    cfg = load_config(None)              # 3 m/s from 240°: blowing to 060°, 30° CCW from east
    assert pattern.mission_direction(cfg) == 120.0
    assert build_plan(cfg, build_field(cfg)).direction_deg == pytest.approx(120.0)
    case = pattern.pattern_case(cfg)
    assert case.legs_deg == 120.0 and case.wind_along_mps == pytest.approx(0.0, abs=1e-9)
    for frm, legs in ((0.0, 0.0), (90.0, 90.0), (45.0, 135.0), (300.0, 60.0)):
        assert pattern.crosswind_heading(frm) == pytest.approx(legs)
    # in calm air there is no crosswind: the planner's fewest turns, as "auto"
    calm = load_config(None, {"wind.speed_mps": 0.0})
    assert pattern.mission_direction(calm) is None
    auto = load_config(None, {"wind.speed_mps": 0.0, "mission.direction_deg": "auto"})
    assert build_plan(calm, build_field(calm)).direction_deg == build_plan(
        auto, build_field(auto)).direction_deg


def test_the_wind_is_split_across_and_along_the_legs():
    # legs with the fewest turns on the default field run nearly along the default wind
    cfg = load_config(None, {"mission.direction_deg": "auto", "mission.swath_cv_max": 0.25})
    case = pattern.pattern_case(cfg)
    plan = build_plan(cfg, build_field(cfg))
    assert case.legs_deg == pytest.approx(plan.direction_deg)
    t = np.radians(30.0 - case.legs_deg)          # the wind's angle from the legs, CCW
    assert case.wind_along_mps == pytest.approx(3.0 * np.cos(t), abs=1e-6)
    assert case.wind_cross_mps == pytest.approx(3.0 * np.sin(t), abs=1e-6)
    across = load_config(None, {"mission.direction_deg": 120.0, "mission.swath_cv_max": 0.25})
    c2 = pattern.pattern_case(across)
    assert (c2.legs_deg, c2.wind_along_mps) == (120.0, pytest.approx(0.0, abs=1e-6))
    assert abs(c2.wind_cross_mps) == pytest.approx(3.0)
    # a wind along the legs makes the passes out and back differ: narrower lanes than across
    assert pattern.lane_choice(cfg).swath_m < pattern.lane_choice(across).swath_m


def test_back_and_forth_overlay_known_answers():
    y = np.arange(-20.0, 20.0, 0.25) + 0.125
    box = (np.abs(y) < 1.0).astype(float)          # 2 m wide, flat
    sp = np.array([2.0, 3.0])
    # the same pass both ways: the plain overlay
    np.testing.assert_allclose(pattern.cv_back_and_forth(y, box, box, sp),
                               pattern.cv_vs_spacing(y, box, sp))
    # out flat, back twice as heavy: halves of the ground at 1 and 2 -> CV 1/3 at 2 m lanes
    assert pattern.cv_back_and_forth(y, box, 2 * box, sp)[0] == pytest.approx(1 / 3)


@pytest.mark.parametrize("value, msg", [
    ("wide", 'mission.swath_m = "wide": expected a number or "auto"'),
    (0.0, "mission.swath_m = 0.0: must be >= 0.5"),
    (-3, "mission.swath_m = -3.0: must be >= 0.5"),
])
def test_swath_is_auto_or_a_positive_number(value, msg):
    with pytest.raises(ConfigError) as e:
        load_config(None, {"mission.swath_m": value})
    assert str(e.value) == msg


def test_cli_bad_swath_is_one_line_exit_2(capsys):
    assert main(["plan", "-o", "x.geojson", "--set", "mission.swath_m=wide"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ['ag-uav: config error: mission.swath_m = "wide": expected a number or "auto"']


def test_plan_prints_the_lanes_and_exports_them(tmp_path, capsys):
    out = tmp_path / "p.geojson"
    assert main(["plan", "-o", str(out), "--origin", "52.0,5.0"]) == 0
    text = capsys.readouterr().out
    cfg = _load_config(None)   # the CLI plans on the default forecast
    lanes = pattern.lane_choice(cfg)
    assert lanes.text() in text
    assert "widest spacing with CV <= 15 % of the back-and-forth pattern test at 3 m, 5 m/s" in text
    props = [f["properties"] for f in json.loads(out.read_text())["features"]
             if f["properties"].get("role") == "field"][0]
    assert props["swath_m"] == lanes.swath_m and props["lanes"] == lanes.text()
    assert props["leg_spacing_m"] <= lanes.swath_m
