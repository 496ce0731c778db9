"""The big job as ``ag-uav bench`` measures it: the 38 ha field flown whole, with the full log.

:func:`measure_big_job` starts a fresh Python process that flies ``examples/field_38ha.geojson``
with :data:`BIG_JOB_OVERRIDES` (the 15-sortie job of docs/guides/spray-jobs.md: 6 m lanes, the
legs with the fewest turns, the "light" gusts), the full MCAP log and no camera frames, into a
temporary folder, and reports its wall time, its loop's wall time, the simulated job time and the
peak resident memory of the flying process (``peak_rss_mb``, its ``VmHWM``) and of the log's
writer process (``writer_peak_rss_mb``, its child, from ``getrusage``: a forked writer's figure
includes the pages it shared with the flying process when it was forked). Kernels are loaded
from the cache (the first run's compile is ``first_run``'s figure). ``python -m
ag_uav.jobs.bench.big`` prints it alone.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

__all__ = ["BIG_JOB_OVERRIDES", "FIELD_38HA", "measure_big_job"]

#: the 38 ha field (a 690 m × 560 m rectangle) in the repository's examples
FIELD_38HA = Path(__file__).resolve().parents[3] / "examples" / "field_38ha.geojson"

#: the job of docs/guides/spray-jobs.md's 38 ha table (with the full log instead of the light one)
BIG_JOB_OVERRIDES: dict[str, Any] = {
    "mission.field": str(FIELD_38HA), "mission.swath_m": 6.0, "mission.headland_m": 6.0,
    "mission.direction_deg": "auto", "wind.turbulence": "light", "log.render": False,
}


def _child() -> dict[str, Any]:
    """Fly the big job here (in the child) and report its figures."""
    t0 = time.perf_counter()
    from ...config import load_config
    from ..run import fly

    cfg = load_config(None, dict(BIG_JOB_OVERRIDES))
    with tempfile.TemporaryDirectory(prefix="ag-uav-big-job-") as out:
        res, _ = fly(cfg, out_root=out, run_id="big", progress=False)
        mcap_mb = sum(f.stat().st_size for f in Path(out, "big").glob("*.mcap")) / 1e6
    s = res.summary
    return {"wall_s": round(time.perf_counter() - t0, 1),
            "loop_wall_s": s.get("loop_wall_time_s"), "job_sim_s": s.get("sim_time_s"),
            "sorties": s.get("sorties"), "completed": s.get("completed"),
            "mcap_mb": round(mcap_mb, 1),
            "peak_rss_mb": round(_peak_rss_kb() / 1024, 1),
            "writer_peak_rss_mb": round(
                resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, 1)}


def _peak_rss_kb() -> float:
    """This process's peak resident memory (kB): ``VmHWM`` of ``/proc/self/status`` where there
    is one. ``getrusage``'s ``ru_maxrss`` of a process started by fork and exec also counts the
    parent's resident memory at the fork, so it is only the fallback."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return float(line.split()[1])
    except OSError:  # pragma: no cover - not Linux
        pass
    return float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)  # pragma: no cover


def measure_big_job(timeout_s: float = 3600.0) -> dict[str, Any]:
    """The big job in a fresh process (see the module docstring); ``{"error": ...}`` if it
    fails."""
    p = subprocess.run([sys.executable, "-m", "ag_uav.jobs.bench.big", "--child"],
                       capture_output=True, text=True, timeout=timeout_s)
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode or not lines:
        return {"error": f"exit {p.returncode}: {p.stderr.strip()[-500:]}"}
    out = json.loads(lines[-1])
    shown = {**BIG_JOB_OVERRIDES, "mission.field": "examples/field_38ha.geojson"}
    out["config"] = ", ".join(f"{k}={v}" for k, v in shown.items())
    return out


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        print(json.dumps(_child()))
        return
    print(json.dumps(measure_big_job(), indent=1))


if __name__ == "__main__":
    main()
