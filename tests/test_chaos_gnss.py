"""Chaos: GNSS denied from take-off.  An autopilot does not arm without a fix: on either
navigation chain the vehicle stays on the ground, the summary says why, and nothing flies on
the true state.  GNSS lost in flight: the position failsafe lands the vehicle where it is."""

from __future__ import annotations

import numpy as np
import pytest

import ag_uav
from ag_uav.cli import main
from ag_uav.engine.missions import simulate, simulate_many

DENIED = {"gps.overrides": {"outage": {"mean_up_s": 30.0, "mean_down_s": 5.0,
                                       "start_in_outage": True}}}


@pytest.mark.parametrize("nav", ["ideal-attitude", "ins"])
def test_no_take_off_without_a_fix(nav, capsys):
    cfg = ag_uav.load_config(None, {"sim.max_time_s": 5.0, "log.enabled": False,
                                    "estimator.nav": nav, **DENIED})
    res = simulate(cfg)
    s = res.summary
    assert s["preflight"].startswith("pre-flight check: no GNSS fix at take-off")
    assert s["incomplete_reason"] == s["preflight"] and not s["completed"]
    assert s["sim_time_s"] == 0.0 and len(res.t) == 0  # nothing flown, on the truth or else
    (line,) = [ln for ln in capsys.readouterr().err.splitlines() if "pre-flight" in ln]
    assert line == f"ag-uav: {s['preflight']}"


def test_the_truth_chain_and_a_batch(capsys):
    """The true-state run needs no fix (it flies); in a lockstep batch the grounded run is a
    row and the others fly."""
    base = {"sim.max_time_s": 3.0, "log.enabled": False}
    truth = simulate(ag_uav.load_config(None, {**base, "estimator.name": "true", **DENIED}))
    assert "preflight" not in truth.summary and truth.summary["sim_time_s"] == 3.0
    rows = simulate_many([ag_uav.load_config(None, {**base, **DENIED}),
                          ag_uav.load_config(None, base)],
                         reduce=lambda i, r: r.summary)
    assert rows[0]["preflight"] and rows[0]["sim_time_s"] == 0.0
    assert "preflight" not in rows[1] and rows[1]["sim_time_s"] == 3.0


def test_fly_prints_the_reason(tmp_path, capsys):
    rc = main(["fly", "--no-log", "-q", "--out", str(tmp_path), "--run-id", "g", "--set",
               'gps.overrides={outage={mean_up_s=30, mean_down_s=5, start_in_outage=true}}'])
    out, err = capsys.readouterr()
    assert rc == 0 and "pre-flight check" in out
    assert [ln for ln in err.splitlines() if ln.strip()] == [
        "ag-uav: pre-flight check: no GNSS fix at take-off (gps.overrides.outage."
        "start_in_outage = true): not armed, the vehicle stays on the ground"]


LOST = {"gps.overrides": {"outage": {"mean_up_s": 20.0, "mean_down_s": 3600.0}}}
FLY = {"sim.max_time_s": 90.0, "log.enabled": False, "mission.swath_m": 6.0, **LOST}


def _after(r, t0):
    return r.t >= t0 + 0.1


def test_gnss_lost_in_flight_engages_the_failsafe():
    """The fix is lost for good (about 25 s in, seed 0): once the flown estimate's horizontal
    1-sigma passes the bound the vehicle stops spraying, brakes and descends where it is, under
    control, and its flight ends on the ground within seconds; the summary says why and when.
    The touchdown's sideways speed is the dead reckoning's drift (in this wind 1-2 m/s, which
    the contact rule may count as a crash: then the crash reason names the failsafe). With the
    failsafe off it flies on, dead reckoning."""
    r = simulate(ag_uav.load_config(None, FLY))
    s = r.summary
    assert s["failsafe"].startswith("GNSS failsafe (land) at t="), s.get("failsafe")
    assert "gps.failsafe_sigma_m = 1.24 m" in s["failsafe"]  # auto: rtk-m350's DGPS 1-sigma
    assert not s["completed"]
    t0 = s["failsafe_time_s"]
    after = _after(r, t0)
    assert not r.spray[after].any()
    assert np.max(np.abs(r.v_true[after, 2])) < 1.0  # a controlled descent, no fall
    assert t0 + 3.0 < r.t[-1] < t0 + 15.0 and r.p_true[-1, 2] < 0.6
    if s["crashed"]:
        assert s["crash_reason"].endswith("(in the GNSS failsafe)")
    else:
        assert s["incomplete_reason"] == f"{s['failsafe']}; landed at t={s['failsafe_landed_s']}s"
    off = simulate(ag_uav.load_config(None, {**FLY, "gps.failsafe": "off"})).summary
    assert "failsafe" not in off and off["sim_time_s"] > r.t[-1] + 20.0


def test_a_soft_landing_is_recorded_as_landed():
    """A landing that settles (seed 2 with a bound of 1 m: the vehicle settles on its skids) is
    recorded as landed, not crashed, and the summary's times and reason say so. Whether the
    dead-reckoned descent settles depends on the seed: with the same bound seeds 0 and 1 touch
    down 2.4 and 1.3 m/s sideways, which the contact rule counts as crashes."""
    s = simulate(ag_uav.load_config(None, {**FLY, "gps.failsafe_sigma_m": 1.0,
                                           "seed": 2})).summary
    assert not s["crashed"], s.get("crash_reason")
    t0, t1 = s["failsafe_time_s"], s["failsafe_landed_s"]
    assert t0 + 3.0 < t1 < t0 + 15.0
    assert s["incomplete_reason"] == f"{s['failsafe']}; landed at t={t1}s"
    assert s["sim_time_s"] == pytest.approx(t1, abs=0.02)


def test_hold_hovers_before_it_lands():
    """``hold`` keeps the height for ``gps.failsafe_hold_s`` and then descends (on dead
    reckoning the hover drifts, so only the timing is pinned)."""
    r = simulate(ag_uav.load_config(None, {**FLY, "gps.failsafe": "hold",
                                           "gps.failsafe_hold_s": 10.0}))
    s = r.summary
    assert s["failsafe"].startswith("GNSS failsafe (hold)")
    t0 = s["failsafe_time_s"]
    hold = (r.t >= t0) & (r.t < t0 + 10.0)
    assert np.max(np.abs(r.p_true[hold, 2] - 3.0)) < 0.15
    assert r.p_true[-1, 2] < 1.0 and r.t[-1] > t0 + 11.0


def test_the_radar_height_outlives_the_fix_on_the_ideal_chain():
    """The ideal-attitude chain's height comes from the radar with or without a fix: through
    the outage and the failsafe's descent the flown height stays on the true one (its
    horizontal dead reckoning drifts, so its touchdown may be fast sideways)."""
    r = simulate(ag_uav.load_config(None, {**FLY, "estimator.nav": "ideal-attitude"}))
    s = r.summary
    assert s["failsafe"].startswith("GNSS failsafe (land)")
    out = r.t >= s["failsafe_time_s"] - 3.0
    assert np.max(np.abs(r.p_true[out, 2] - r.p_fb[out, 2])) < 0.15
    assert np.max(np.abs(r.v_true[out, 2])) < 1.0
