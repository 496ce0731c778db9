"""``ag-uav bench``'s big job (its configuration is the documented 38 ha job, and it stays out of
``--quick``; the job itself flies for minutes: the bench runs it, not the suite) and the dose
model's stage share."""

from __future__ import annotations

from ag_uav.config import load_config
from ag_uav.jobs.bench import suite as bench
from ag_uav.jobs.bench.big import BIG_JOB_OVERRIDES, FIELD_38HA
from ag_uav.world.field import Field


def test_big_job_config_is_the_38ha_job_with_the_full_log():
    cfg = load_config(None, dict(BIG_JOB_OVERRIDES))
    assert FIELD_38HA.is_file()
    assert cfg.log.enabled and cfg.log.channels == "full" and not cfg.log.render
    assert cfg.mission.swath_m == 6.0 and cfg.mission.direction_deg == "auto"
    area = Field.from_geojson(str(FIELD_38HA)).area
    assert 38e4 < area < 39e4


def test_big_job_is_left_out_of_quick_bench():
    assert bench._big_job(load_config(None, {}), 1, True) == {}


def test_the_dose_stage_share_is_the_stage_over_its_own_loop():
    """``deposition.loop_share``: the deposition stage's time over the loop's, of one flight
    (a share strictly between 0 and 1 with the dose model on; none timed without it)."""
    from ag_uav.jobs.bench.suite import (
        TRUE_STATE_OVERRIDES,
        _stage_share,
        closed_loop,
        with_overrides,
    )

    c = with_overrides(load_config(None, {}), TRUE_STATE_OVERRIDES)
    on = with_overrides(c, {"spray.deposition": True, "sim.max_time_s": 30.0})
    off = with_overrides(on, {"spray.deposition": False})
    closed_loop(on)  # a kernel compiled in tick 0 would count in the stage, not in the loop
    r = _stage_share(lambda conf: [closed_loop(conf)[2]], on, 1, "")
    assert 0.0 < r["loop_share"] < 0.5
    assert _stage_share(lambda conf: [closed_loop(conf)[2]], off, 1, "")["loop_share"] == 0.0
