"""The first run's compile on two cores: the run compiles the INS first while a helper process
compiles the MCKF's update and then the other kernels.

On a checkout whose numba cache is empty, the run's kernels compile one after another in the
flying process (docs/speed.md, "The first run"). The INS's tick kernel and its laws are most of
that; the rest (the deposition pattern that chooses the lanes, the log's encoders, the
controller, the sprayer, the wind, the dose map) does not depend on them. :func:`start`
launches a helper process that flies the same config on the true state (``estimator.name =
"true"`` with no shadow filters: no INS) for :data:`FLY_S` simulated seconds into a temporary
folder, at low priority, with its log but no renders: it compiles those kernels into the same
numba cache (first the MCKF update, at the run's priority: see below). The run
meanwhile compiles the INS before anything else (:func:`compile_ins`, one
tick of a one-vehicle bank, called by :func:`ag_uav.jobs.run.fly` once the helper is started),
then plans and flies, and numba loads from the cache what the helper has written by then. The
helper shares nothing with the run but the cache's files, which numba writes whole (a
temporary file renamed into place), so the run computes exactly what it computes without it; a
kernel the run reaches before the helper has written it is compiled by the run as before.

:func:`stop` ends the helper if it is still running and removes its folder. The run loads its
field before it starts the helper, so a field it cannot load is refused at once; a plan it cannot
make (the lanes, the sorties) is refused after the INS's compile, on an empty cache only.

The INS's tick kernel calls its laws in one order, and the MCKF's update
(:func:`estimators.mckf.mckf_update_row`, over a quarter of the INS's compile) comes after the PCA,
the propagation and the KF innovation. The helper compiles that update first, with the types the
tick kernel passes it (:func:`compile_mckf_row`), and says so with a file in its folder; the run
compiles the laws before it meanwhile, and when its tick kernel reaches the update it waits for
that file (or for the helper to end, at most :data:`MCKF_WAIT_S`) and loads the update from the
cache. The INS's compile is then shared between the two cores instead of running on one.

It starts only when it can help: the run flies the INS, the INS's tick kernel is not in the
cache, this process may use at least two cores, and ``AG_UAV_WARM`` is not ``0``.
``python -m ag_uav.jobs.bench.first_run`` measures the first run with and without it.

Nothing outlives the run. The helper dies with the process that started it, however that ends
(SIGKILL included: :func:`die_with_parent`, Linux's ``PR_SET_PDEATHSIG``, and a thread that
watches the parent's pid elsewhere), and its folder (:data:`PREFIX` in the temporary
directory) names its owner (:data:`OWNER`: the run's pid and start time); a run that could not
remove it (SIGKILL) leaves it to the next run, which removes every such folder whose owner is
gone (:func:`sweep`, called at the start of each run).
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["FLY_S", "MCKF_DONE", "MCKF_WAIT_S", "OWNER", "PARENT_ENV", "PREFIX", "Warmer",
           "compile_ins", "compile_mckf_row", "die_with_parent", "mckf_row_args", "owned_folder",
           "owner_alive", "start", "stop", "sweep", "wanted"]

#: simulated seconds the helper flies (every per-tick kernel and the log's encoders run in them)
FLY_S = 2.0
#: what the helper flies differently from the run: no INS, no renders, briefly
HELPER_OVERRIDES: dict[str, Any] = {"estimator.name": "true", "estimator.shadow": [],
                                    "sim.max_time_s": FLY_S, "log.render": False}
#: the longest the run waits for the helper's MCKF update before compiling it itself
MCKF_WAIT_S = 60.0
#: the file the helper writes in its folder once the MCKF update is in the cache
MCKF_DONE = "mckf-row.done"
#: the helper's folder in the temporary directory: this prefix and a random suffix
PREFIX = "ag-uav-warm-"
#: the file in such a folder naming its owner: ``"PID START"`` (START: the process's start
#: time in clock ticks since boot, ``/proc/PID/stat`` field 22; 0 where there is no /proc)
OWNER = "owner"
#: the environment variable that gives the helper its parent's pid (checked at its start)
PARENT_ENV = "AG_UAV_WARM_PARENT"
#: a folder of ours with no owner file yet is left alone this long (it is being made; s)
UNOWNED_GRACE_S = 600.0


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


#: ``/proc/PID/stat``'s field 22 (starttime) counted from field 3 (state), the first after the
#: command's closing parenthesis
_STARTTIME_AFTER_COMM = 19


def _start_ticks(pid: int) -> int:
    """The process's start time (clock ticks since boot, ``/proc/PID/stat`` field 22; 0 where
    it cannot be read): with the pid, it tells a process from a later one given the same pid."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
        return int(text.rsplit(")", 1)[1].split()[_STARTTIME_AFTER_COMM])
    except (OSError, ValueError, IndexError):
        return 0


def owned_folder(prefix: str = PREFIX) -> Path:
    """A new folder ``prefix*`` in the temporary directory, its :data:`OWNER` file naming this
    process (so that :func:`sweep` removes it once this process is gone)."""
    folder = Path(tempfile.mkdtemp(prefix=prefix))
    pid = os.getpid()
    (folder / OWNER).write_text(f"{pid} {_start_ticks(pid)}\n")
    return folder


def owner_alive(folder: Path, now: float | None = None) -> bool:
    """Whether the process named in ``folder/``:data:`OWNER` still runs (the same pid and start
    time). A folder with no owner file counts as alive for :data:`UNOWNED_GRACE_S` after it was
    last modified (its maker may be writing the file), then as gone."""
    try:
        pid_s, ticks_s = (folder / OWNER).read_text().split()
        pid, ticks = int(pid_s), int(ticks_s)
    except FileNotFoundError:
        try:
            age = (time.time() if now is None else now) - folder.stat().st_mtime
        except OSError:
            return False
        return age < UNOWNED_GRACE_S
    except (OSError, ValueError):  # unreadable or damaged: not a live run's
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive (and not ours to judge)
        return True
    return ticks == 0 or _start_ticks(pid) in (0, ticks)


def sweep(prefix: str = PREFIX) -> list[Path]:
    """Remove the folders ``prefix*`` in the temporary directory whose owner is gone (a run
    SIGKILLed before it could remove its helper's folder); returns those removed. Folders of
    another user, or that cannot be removed, are left as they are."""
    removed = []
    for folder in Path(tempfile.gettempdir()).glob(f"{prefix}*"):
        try:
            st = folder.lstat()
        except OSError:
            continue
        if not stat.S_ISDIR(st.st_mode) or st.st_uid != _uid():
            continue
        if owner_alive(folder):
            continue
        shutil.rmtree(folder, ignore_errors=True)
        if not folder.exists():
            removed.append(folder)
    return removed


def _uid() -> int:
    return os.getuid() if hasattr(os, "getuid") else -1


def die_with_parent(parent: int | None = None) -> None:
    """Make this process end when its parent does, however the parent ends (SIGKILL included):
    on Linux ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (the kernel kills this process when the
    thread that started it exits); elsewhere, or if that fails, a daemon thread that exits the
    process once its parent pid changes (polled every 0.5 s). ``parent``: the pid the parent
    gave (:data:`PARENT_ENV`); a parent already gone before this call is caught by comparing
    it with ``os.getppid()``."""
    if parent is None:
        try:
            parent = int(os.environ.get(PARENT_ENV, ""))
        except ValueError:
            parent = os.getppid()
    armed = False
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        try:
            libc = ctypes.CDLL(None, use_errno=True)
            pr_set_pdeathsig = 1
            armed = libc.prctl(pr_set_pdeathsig, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent:  # the parent died before the prctl (or this was reparented)
        os._exit(1)
    if not armed:
        import threading

        def watch() -> None:
            while os.getppid() == parent:
                time.sleep(0.5)
            os._exit(1)

        threading.Thread(target=watch, name="ag-uav-parent-watch", daemon=True).start()


def start(cfg: Any, command: Sequence[str]) -> Warmer | None:
    """The helper for ``cfg``'s run, started, or None when :func:`wanted` says no (or it could
    not start: the run then compiles everything itself, as it would anyway). ``command``: the
    arguments after the interpreter that run the helper, its folder appended (a module calling
    :func:`ag_uav.engine.warm.helper.run_helper` with the caller's flight: the run's
    :data:`ag_uav.jobs.run.WARM_HELPER`). The helper ends with this process
    (:func:`die_with_parent`); its folder names this process as its owner
    (:func:`owned_folder`)."""
    if not wanted(cfg):
        return None
    try:
        folder = owned_folder(PREFIX)
    except OSError:
        return None
    try:
        (folder / "config.toml").write_text(cfg.to_toml())
        env = {**os.environ, "AG_UAV_WARM": "0", "AG_UAV_ENGINE_THREADS": "1",
               PARENT_ENV: str(os.getpid())}
        proc = subprocess.Popen([sys.executable, *command, str(folder)],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, env=env)
    except OSError:
        shutil.rmtree(folder, ignore_errors=True)
        return None
    return Warmer(proc, folder)


def compile_ins(w: Warmer | None = None) -> None:
    """Compile the INS's tick kernel and the laws it calls, in this process, now: one tick of a
    one-vehicle bank on zeros. Its arguments have the types a run's bank passes (every bank's
    arrays are C-contiguous float64 or int64, whatever its rules), so the run loads the kernel
    from the cache at its first tick. With a helper ``w``, the MCKF update is the helper's
    (module docstring)."""
    import numpy as np

    from estimators.ins import BatchINS
    from estimators.mckf import mckf_update_row

    if w is not None:  # numba asks the law's dispatcher to compile when the caller's typing
        mckf_update_row.compile = _after_helper(w, mckf_update_row)  # reaches it
    try:
        BatchINS(1).step(np.zeros((1, 6)))
    finally:
        mckf_update_row.__dict__.pop("compile", None)


def _after_helper(w: Warmer, law: Any) -> Any:
    """``law.compile`` that first waits for the helper's file (see the module docstring)."""
    compile_law = type(law).compile

    def compile_after_helper(sig: Any) -> Any:
        law.__dict__.pop("compile", None)  # once
        deadline = time.monotonic() + MCKF_WAIT_S
        while (not (w.folder / MCKF_DONE).exists() and w.proc.poll() is None
               and time.monotonic() < deadline):
            time.sleep(0.05)
        return compile_law(law, sig)

    return compile_after_helper


def compile_mckf_row() -> None:
    """Compile :func:`estimators.mckf.mckf_update_row` with the argument types the INS's tick
    kernel passes it (:func:`mckf_row_args`); on a fix of NaN it returns at once."""
    from estimators.mckf import mckf_update_row

    mckf_update_row(*mckf_row_args())


def mckf_row_args() -> tuple[Any, ...]:
    """Arguments of :func:`estimators.mckf.mckf_update_row` typed as the INS's tick kernel types
    its own: C-contiguous float64 arrays, int64 counters, the work arrays as
    :func:`estimators.mckf.mckf_work` makes them (``tests/test_warm.py`` compares the types)."""
    import numpy as np

    from estimators.mckf import mckf_work

    n, m = 15, 3
    return (np.zeros(n), np.eye(n), np.eye(m), np.zeros((m, n)), np.full(m, np.nan),
            (np.zeros(n), np.zeros(m), np.zeros(5), np.zeros(4, np.int64)),
            (np.zeros(4, np.int64), np.zeros(m)), mckf_work(n, m))


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
