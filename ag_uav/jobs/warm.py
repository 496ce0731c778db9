"""The first run's compile on two cores: the run compiles the INS first while a helper process
compiles the other kernels.

On a checkout whose numba cache is empty, the run's kernels compile one after another in the
flying process (docs/speed.md, "The first run"). The INS's tick kernel and its laws are most of
that; the rest (the deposition pattern that chooses the lanes, the log's encoders, the
controller, the sprayer, the wind, the dose map) does not depend on them. :func:`start`
launches a helper process that flies the same config on the true state (``estimator.name =
"true"`` with no shadow filters: no INS) for :data:`FLY_S` simulated seconds into a temporary
folder, at low priority, with its log but no renders: it compiles those kernels into the same
numba cache. The run meanwhile compiles the INS before anything else (:func:`compile_ins`, one
tick of a one-vehicle bank, called by :func:`ag_uav.jobs.run.fly` once the helper is started),
then plans and flies, and numba loads from the cache what the helper has written by then. The
helper shares nothing with the run but the cache's files, which numba writes whole (a
temporary file renamed into place), so the run computes exactly what it computes without it; a
kernel the run reaches before the helper has written it is compiled by the run as before.
:func:`stop` ends the helper if it is still running and removes its folder. The run loads its
field before it starts the helper, so a field it cannot load is refused at once; a plan it cannot
make (the lanes, the sorties) is refused after the INS's compile, on an empty cache only.

It starts only when it can help: the run flies the INS, the INS's tick kernel is not in the
cache, this process may use at least two cores, and ``AG_UAV_WARM`` is not ``0``.
``python -m ag_uav.jobs.first_run`` measures the first run with and without it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

__all__ = ["FLY_S", "Warmer", "compile_ins", "start", "stop", "wanted"]

#: simulated seconds the helper flies (every per-tick kernel and the log's encoders run in them)
FLY_S = 2.0
#: what the helper flies differently from the run: no INS, no renders, briefly
HELPER_OVERRIDES: dict[str, Any] = {"estimator.name": "true", "estimator.shadow": [],
                                    "sim.max_time_s": FLY_S, "log.render": False}


class Warmer:
    """A started helper: its process and its temporary folder."""

    def __init__(self, proc: subprocess.Popen, folder: Path) -> None:
        self.proc, self.folder = proc, folder


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _ins_kernel_cached() -> bool:
    """Whether numba's cache holds the INS's tick kernel (True when that cannot be told)."""
    try:
        from estimators.ins.fusion import step_kernel
    except ImportError:  # pragma: no cover - numba missing: nothing compiles
        return True
    index = getattr(getattr(getattr(step_kernel, "_cache", None), "_cache_file", None),
                    "_index_path", None)
    return index is None or os.path.exists(index)


def wanted(cfg: Any) -> bool:
    """Whether a helper would help ``cfg``'s run here (see the module docstring)."""
    e = cfg.estimator
    flies_ins = e.name != "true" and e.source == "gps" and e.nav == "ins"
    return (os.environ.get("AG_UAV_WARM", "1") != "0" and flies_ins and _cores() >= 2
            and not _ins_kernel_cached())


def start(cfg: Any) -> Warmer | None:
    """The helper for ``cfg``'s run, started, or None when :func:`wanted` says no (or it could
    not start: the run then compiles everything itself, as it would anyway)."""
    if not wanted(cfg):
        return None
    folder = Path(tempfile.mkdtemp(prefix="ag-uav-warm-"))
    try:
        (folder / "config.toml").write_text(cfg.to_toml())
        env = {**os.environ, "AG_UAV_WARM": "0", "AG_UAV_ENGINE_THREADS": "1"}
        proc = subprocess.Popen([sys.executable, "-m", "ag_uav.jobs.warm_helper", str(folder)],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, env=env)
    except OSError:
        shutil.rmtree(folder, ignore_errors=True)
        return None
    return Warmer(proc, folder)


def compile_ins() -> None:
    """Compile the INS's tick kernel and the laws it calls, in this process, now: one tick of a
    one-vehicle bank on zeros. Its arguments have the types a run's bank passes (every bank's
    arrays are C-contiguous float64 or int64, whatever its rules), so the run loads the kernel
    from the cache at its first tick."""
    import numpy as np

    from estimators.ins import BatchINS

    BatchINS(1).step(np.zeros((1, 6)))


def stop(w: Warmer | None) -> None:
    """End the helper if it still runs (the run is done) and remove its folder."""
    if w is None:
        return
    if w.proc.poll() is None:
        w.proc.terminate()
        try:
            w.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:  # pragma: no cover - it ignored SIGTERM
            w.proc.kill()
            w.proc.wait()
    shutil.rmtree(w.folder, ignore_errors=True)
