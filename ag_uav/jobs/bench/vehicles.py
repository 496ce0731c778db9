"""``ag-uav bench``'s per-vehicle figures: the default mission flown on each preset
(``vehicle.preset``), one mission and a batch, each against MuJoCo alone stepping that preset's
own model, so that the vehicles' loop speeds compare as ratios taken in one run.

Per preset (:data:`PRESETS`; the default config with ``vehicle.preset`` set and the true state,
as the bench's main figures): ``closed_loop_sim_s_per_wall_s`` (one mission, no log; median of
the repeats), ``raw_per_step_sim_s_per_wall_s`` (``mj_step`` per physics step of its model at
hover, :func:`ag_uav.jobs.bench.physics.raw_stepping`), their ratio ``closed_vs_raw_per_step``, and
the batch of ``batch_vehicles`` missions of ``batch_sim_s`` each against MuJoCo alone replaying
the same flights, paired run by run (:func:`ag_uav.jobs.bench.physics.paired`):
``batch_ratio_vs_physics``. ``python -m ag_uav.jobs.bench.vehicles [--quick]`` prints them alone.
"""

from __future__ import annotations

import json
import statistics
import sys
from typing import Any

#: the presets the bench flies (the default M350 and the 40 L coaxial octocopter)
PRESETS = ("m350", "x8-40l")


def bench_vehicles(repeats: int = 3, quick: bool = False,
                   presets: tuple[str, ...] = PRESETS) -> dict[str, Any]:
    """The figures of the module docstring, one dict per preset."""
    from ...config import load_config
    from ...engine.physics import default_threads
    from .physics import TRUE_STATE_OVERRIDES, batched_capture, closed_loop, paired, raw_stepping

    n, batch_s = (16, 20.0) if quick else (64, 60.0)
    threads = default_threads(n)
    out: dict[str, Any] = {}
    for name in presets:
        over: dict[str, Any] = {**TRUE_STATE_OVERRIDES, "vehicle.preset": name}
        if quick:
            over["sim.max_time_s"] = 60.0
        c = load_config(None, over)
        closed_loop(c)  # the kernels loaded, outside the timed runs
        runs = [closed_loop(c) for _ in range(max(1, repeats))]
        sim_s = runs[0][0]
        closed = statistics.median(r[0] / r[1] for r in runs)
        raw = statistics.median(s / w for s, w in (raw_stepping(c, sim_s, 1)
                                                    for _ in range(max(1, repeats))))
        batched_capture(c, 2, 1.0)
        pr = paired(c, n, batch_s, threads, repeats)
        out[name] = {
            "mission_sim_s": sim_s, "completed": runs[0][2].get("completed"),
            "closed_loop_sim_s_per_wall_s": round(closed, 1),
            "raw_per_step_sim_s_per_wall_s": round(raw, 1),
            "closed_vs_raw_per_step": round(closed / raw, 3),
            "batch_vehicles": n, "batch_sim_s": batch_s,
            "batch_sim_s_per_wall_s": round(pr["sim_s_per_wall_s"], 1),
            "batch_physics_sim_s_per_wall_s": round(pr["physics_sim_s_per_wall_s"], 1),
            "batch_ratio_vs_physics": pr["ratio_vs_physics"],
            "batch_ratio_vs_physics_spread": pr["ratio_vs_physics_spread"],
        }
    return out


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    print(json.dumps(bench_vehicles(quick="--quick" in argv), indent=1))


if __name__ == "__main__":
    main()
