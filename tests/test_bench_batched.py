"""``ag-uav bench``'s batch section: the engine against MuJoCo alone replaying its flights."""

from __future__ import annotations

from ag_uav.config import load_config
from ag_uav.jobs.bench.physics import paired
from ag_uav.jobs.bench.suite import TRUE_STATE_OVERRIDES, with_overrides


def test_each_engine_batch_is_paired_with_the_replay_of_its_own_flights() -> None:
    cfg = with_overrides(load_config(None), TRUE_STATE_OVERRIDES)
    out = paired(cfg, 4, 1.0, 2, 3)
    lo, hi = out["ratio_vs_physics_spread"]["min"], out["ratio_vs_physics_spread"]["max"]
    assert 0.0 < lo <= out["ratio_vs_physics"] <= hi
    assert out["sim_s_per_wall_s"] > 0 and out["physics_sim_s_per_wall_s"] > 0
    assert out["physics_best_of_ways_sim_s_per_wall_s"] > 0
    assert out["physics_how"] and out["lanes"] >= 1
    assert 0.0 < out["loop_cores_busy"] <= 2.2   # CPU ÷ wall of the loop, at most the threads


def test_stage_costs_add_up_to_the_loop_and_restore_the_engine() -> None:
    """``stages``: every stage and the physics timed per vehicle-tick, the rest of the loop
    small; the stage classes are left as they were."""
    from ag_uav.engine import loop, stages
    from ag_uav.jobs.bench.suite import _stages

    before = (stages.Guard.start, stages.Depositing.step, loop.Engine.physics)
    cfg = with_overrides(load_config(None), TRUE_STATE_OVERRIDES)
    out = _stages(cfg, 1, True)["stages_us_per_vehicle_tick"]
    for key in ("true_state", "ins_bank"):
        row = out[key]
        assert row["physics"] > 0 and row["guard"] > 0 and row["cascade"] > 0
        assert 0 < row["stages_over_physics"] < 10
        assert abs(row["loop_rest"]) < row["physics"]
    assert out["ins_bank"]["feedback"] > 5 * out["true_state"]["feedback"]   # the INS bank
    assert (stages.Guard.start, stages.Depositing.step, loop.Engine.physics) == before


def test_the_target_batches_are_also_paired_without_the_dose_model() -> None:
    """``ratio_vs_physics_without_deposition``: the workload the speed targets are stated for,
    paired with its own replay like the default one."""
    from ag_uav.jobs.bench.suite import ALSO_WITHOUT_DOSE, _without_dose

    assert ALSO_WITHOUT_DOSE == ("batched", "batched_ideal_attitude")
    cfg = with_overrides(load_config(None), TRUE_STATE_OVERRIDES)
    out = _without_dose(cfg, 4, 1.0, 2, 2)
    spread = out["ratio_vs_physics_without_deposition_spread"]
    assert 0.0 < spread["min"] <= out["ratio_vs_physics_without_deposition"] <= spread["max"]
    assert out["sim_s_per_wall_s_without_deposition"] > 0


def test_first_run_compile_spans_count_nested_kernels_once() -> None:
    """A kernel's own compile time is its span less its callees' spans; the total is the
    outermost spans' sum (numba's compile events nest)."""
    from ag_uav.jobs.bench.first_run import compile_spans

    ev = [(0.0, "a", True), (1.0, "b", True), (3.0, "c", True), (4.0, "c", False),
          (6.0, "b", False), (10.0, "a", False), (11.0, "d", True), (12.5, "d", False)]
    total, own = compile_spans(ev)
    assert total == 11.5
    assert own == {"a": 5.0, "b": 4.0, "c": 1.0, "d": 1.5}
