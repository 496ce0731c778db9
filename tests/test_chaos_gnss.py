"""Chaos: GNSS denied from take-off.  An autopilot does not arm without a fix: on either
navigation chain the vehicle stays on the ground, the summary says why, and nothing flies on
the true state."""

from __future__ import annotations

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
