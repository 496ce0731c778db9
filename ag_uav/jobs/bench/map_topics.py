"""What the log's map topics (:mod:`ag_uav.record.geo`, group ``geo``) cost: the default
mission's loop unlogged, with the full log, and with the full log without the map topics
(``rates={"geo": 0}``), with the writer process and inline, interleaved in each repeat so that
every ratio is taken between neighbouring runs (as :func:`ag_uav.jobs.bench.logging_cost`).

    python -m ag_uav.jobs.bench.map_topics [REPEATS]     # JSON: median, min, max of each ratio

Ratios over the unlogged loop: ``wall`` (the loop's wall time), ``cpu`` (the loop process's CPU
time) and ``cpu_with_writer`` (plus the writer process's).  Figures: docs/guides/foxglove.md.
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

from ...config import Config, load_config

KINDS = ("full", "nogeo", "inline", "inline_nogeo")


def _fly(cfg: Config, path: Path | None, geo: bool = True, writer: str = "process",
         ) -> tuple[tuple[float, float, float], tuple[int, int]]:
    """(loop wall, loop CPU, loop + writer CPU), (log bytes, messages) of one flight."""
    from ...engine.missions import simulate
    from ...record.runlog import RunLog
    from .suite import LoopCpu

    hook = LoopCpu()
    if path is None:
        wall = simulate(cfg, tick_hook=hook).summary["loop_wall_time_s"]
        return (wall, hook.seconds, hook.seconds), (0, 0)
    rates: dict[str, float | None] = {"camera": 0.0} if geo else {"camera": 0.0, "geo": 0.0}
    with RunLog(path, channels="full", rates=rates, metadata={}, config_toml="", layout=False,
                writer=writer) as log:
        wall = simulate(cfg, log=log, tick_hook=hook).summary["loop_wall_time_s"]
    return ((wall, hook.seconds, hook.seconds + log.writer_cpu_s),
            (path.stat().st_size, sum(log.counts.values())))


def map_topics_cost(cfg: Config, repeats: int = 3) -> dict[str, Any]:
    """The ratios of each logged kind (:data:`KINDS`) over the unlogged loop."""
    from ...engine.missions import simulate

    runs: dict[str, list[tuple[float, float, float]]] = {k: [] for k in ("plain", *KINDS)}
    sizes: dict[str, tuple[int, int]] = {}
    simulate(cfg)  # compiled and cached before the first timed flight
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for i in range(repeats):
            runs["plain"].append(_fly(cfg, None)[0])
            for k in KINDS:
                runs[k].append((r := _fly(cfg, d / f"{k}{i}.mcap", geo="nogeo" not in k,
                                          writer="inline" if "inline" in k else "process"))[0])
                sizes[k] = r[1]
    out: dict[str, Any] = {"unlogged_loop_s": statistics.median(r[0] for r in runs["plain"])}
    for k in KINDS:
        for j, name in enumerate(("wall", "cpu", "cpu_with_writer")):
            r = [a[j] / b[j] for a, b in zip(runs[k], runs["plain"], strict=True)]
            out[f"{k}_over_unlogged_{name}"] = [round(statistics.median(r), 3),
                                                round(min(r), 3), round(max(r), 3)]
        out[f"{k}_log_bytes_messages"] = sizes[k]
    return out


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    cfg = load_config(None, {"log.render": False})
    print(json.dumps(map_topics_cost(cfg, int(args[0]) if args else 3), indent=1))


if __name__ == "__main__":
    main()
