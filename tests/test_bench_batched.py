"""``ag-uav bench``'s batch section: the engine against MuJoCo alone replaying its flights."""

from __future__ import annotations

from ag_uav.config import load_config
from ag_uav.jobs.bench import TRUE_STATE_OVERRIDES, _paired, with_overrides


def test_each_engine_batch_is_paired_with_the_replay_of_its_own_flights() -> None:
    cfg = with_overrides(load_config(None), TRUE_STATE_OVERRIDES)
    out = _paired(cfg, 4, 1.0, 2, 3)
    lo, hi = out["ratio_vs_physics_spread"]["min"], out["ratio_vs_physics_spread"]["max"]
    assert 0.0 < lo <= out["ratio_vs_physics"] <= hi
    assert out["sim_s_per_wall_s"] > 0 and out["physics_sim_s_per_wall_s"] > 0
    assert out["physics_best_of_ways_sim_s_per_wall_s"] > 0
    assert out["physics_how"] and out["lanes"] >= 1
