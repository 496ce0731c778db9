"""What a new user waits for: the first run on a fresh checkout, compile included.

:func:`measure_first_run` starts a fresh Python process whose numba cache is an empty folder
(``NUMBA_CACHE_DIR``; numba then neither reads nor writes the package's ``__pycache__``), flies
the default mission for :data:`FLY_S` simulated seconds with the full log (no renders), and
reports the process's wall time, the seconds spent compiling and the kernels that cost most
(the child ends with this process, however it ends: :func:`ag_uav.engine.warm.die_with_parent`).
The compile is read from numba's own ``numba:compile`` events: each event spans a kernel's
compile including the kernels it compiles on the way, so a kernel's *own* time is its span less
its nested spans, and the total is the sum of the outermost spans.  ``ag-uav bench`` reports it
as ``first_run``; ``python -m ag_uav.jobs.bench.first_run`` prints it alone (``--one-process``:
without the second-core helper of :mod:`ag_uav.engine.warm`, every kernel compiled by the flying
process).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from typing import Any

__all__ = ["FLY_S", "compile_spans", "measure_first_run"]

#: simulated seconds the child flies: every per-tick kernel and the log's encoders run in them
FLY_S = 2.0
#: the measurement's folder in the temporary directory (removed after; a killed measurement's
#: by the next, :func:`ag_uav.engine.warm.sweep`)
TMP_PREFIX = "ag-uav-first-run-"


def compile_spans(events: list[tuple[float, str, bool]]) -> tuple[float, dict[str, float]]:
    """(total, own seconds by kernel) from ``(time, kernel, is_start)`` events in time order.

    Spans nest (a kernel compiles its callees inside its own compile); a kernel's own time is
    its span less the spans nested in it, and the total is the sum of the outermost spans."""
    total, own, stack = 0.0, {}, []
    for t, name, start in events:
        if start:
            stack.append([name, t, 0.0])
            continue
        name, t0, nested = stack.pop()
        span = t - t0
        own[name] = own.get(name, 0.0) + span - nested
        if stack:
            stack[-1][2] += span
        else:
            total += span
    return total, own


def _child(out_dir: str) -> dict[str, Any]:
    """Fly the default mission briefly with numba's compile events recorded (in the child)."""
    t0 = time.perf_counter()
    from numba.core import event

    from ...config import load_config
    from ...engine.compiling import kernel_name
    from ..run import fly

    events: list[tuple[float, str, bool]] = []

    class _Rec(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            events.append((time.perf_counter(), kernel_name(ev), True))

        def on_end(self, ev: event.Event) -> None:
            events.append((time.perf_counter(), kernel_name(ev), False))

    cfg = load_config(None, {"sim.max_time_s": FLY_S, "log.render": False})
    from ...engine import warm

    helper = warm.wanted(cfg)  # checked before the run fills the cache, as fly() checks it
    with event.install_listener("numba:compile", _Rec()):
        res, _ = fly(cfg, out_root=out_dir, run_id="first", progress=False)
    wall = time.perf_counter() - t0
    total, own = compile_spans(events)
    top = sorted(own.items(), key=lambda kv: -kv[1])[:10]
    return {"sim_time_s": res.summary["sim_time_s"], "wall_s": round(wall, 2),
            "compile_s": round(total, 2), "kernels_compiled": len(own), "warm_helper": helper,
            "top_kernels_s": {k: round(v, 2) for k, v in top}}




def measure_first_run(timeout_s: float = 900.0, helper: bool = True) -> dict[str, Any]:
    """The first run of a fresh checkout, measured in a child process with an empty numba
    cache: ``wall_s`` (interpreter start to the summary), ``compile_s`` (all kernels the
    flying process compiled or loaded, the log's encoders included), ``kernels_compiled`` and
    ``top_kernels_s`` (the ten costliest, own time). ``helper``: whether the second-core
    helper of :mod:`ag_uav.engine.warm` may start (as it does for a user; ``warm_helper`` says
    whether it did), or the flying process compiles every kernel itself."""
    from ...engine import warm

    warm.sweep(TMP_PREFIX)  # the folders of measurements that were killed (SIGKILL)
    tmp = str(warm.owned_folder(TMP_PREFIX))
    try:
        env = {**os.environ, "NUMBA_CACHE_DIR": os.path.join(tmp, "numba"),
               "AG_UAV_WARM": "1" if helper else "0", warm.PARENT_ENV: str(os.getpid())}
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "ag_uav.jobs.bench.first_run", "--child", tmp],
                           env=env, capture_output=True, text=True, timeout=timeout_s)
        process_s = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if p.returncode != 0:
        tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["no output"]
        raise RuntimeError(f"first-run child exited {p.returncode}: {tail[0]}")
    out = json.loads(p.stdout.strip().splitlines()[-1])
    out["process_s"] = round(process_s, 2)
    out["fly_sim_s"] = FLY_S
    return out


def _print(out: dict[str, Any]) -> None:
    how = "with the second-core helper" if out["warm_helper"] else "one process"
    print(f"first run, fresh numba cache, {how}: {out['process_s']:.1f} s in all, "
          f"{out['compile_s']:.1f} s compiling {out['kernels_compiled']} kernels")
    for k, v in out["top_kernels_s"].items():
        print(f"  {v:7.2f} s  {k}")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        from ...engine.warm import die_with_parent

        die_with_parent()  # a measurement killed takes its child (and the child's helper) along
        res = _child(sys.argv[2])
        sys.stdout.flush()
        print(json.dumps(res))
    else:
        _print(measure_first_run(helper="--one-process" not in sys.argv))
