"""``ag-uav bench``'s logging section on a short mission: the keys the docs quote, and message
counts that follow from the channel rates (no timing is asserted)."""

from __future__ import annotations

import math

from ag_uav.config import default_config
from ag_uav.jobs.bench.suite import TRUE_STATE_OVERRIDES, logging_cost, with_overrides


def test_logging_cost_reports_ratios_and_the_cost_per_message():
    c = with_overrides(default_config(), TRUE_STATE_OVERRIDES)
    c.sim.max_time_s = 6.0
    r = logging_cost(c, repeats=1)
    for key in ("full_over_unlogged", "estimators_ratio", "light_over_unlogged",
                "full_over_unlogged_cpu", "estimators_ratio_cpu",
                "full_over_unlogged_inline_writer", "estimators_ratio_inline_writer"):
        assert math.isfinite(r[key]) and r[key] > 0, key
    # the writer process's CPU time is counted too: it can only add to the loop's own
    assert r["full_over_unlogged_cpu_with_writer"] > r["full_over_unlogged_cpu"]
    assert r["estimators_ratio_cpu_with_writer"] > r["estimators_ratio_cpu"]
    # full set over 6 s: /tf at 10 Hz, three poses at 10 Hz, /drone/state at 20 Hz (ticks only)
    assert r["full_log_messages"] >= 6 * (10 + 30 + 20) - 10
    # the estimator set adds /gps and the four /estimator/<rule> channels
    assert r["estimators_full_log_messages"] > r["full_log_messages"] + 6 * 4 * 5
    assert math.isfinite(r["full_log_us_per_message"])
    assert math.isfinite(r["estimators_full_log_us_per_message"])
