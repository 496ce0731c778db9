"""One writer per output folder.

A run folder (``ag-uav fly``) and a job folder (``ag-uav batch`` / ``ag-uav tune``'s ``--out``)
belong to one process at a time: :func:`hold` takes an exclusive POSIX record lock
(``fcntl.lockf``, IEEE Std 1003.1 ``fcntl(F_SETLK)``) on ``.ag-uav.lock`` inside the folder for as
long as the job writes there.  The kernel drops the lock when the process ends, however it ends
(a SIGKILL included), so a stale lock file never blocks anyone; the lock is not inherited by
forked children (the log's writer process, pool workers), which write only what the holder
hands them.  The file is removed when the holder lets go.
A second writer is refused with one line naming the folder and the holder's process id
(:class:`FolderInUse`).

A run folder is never reused silently: :func:`claim_run_dir` refuses a folder that holds a
previous run's outputs unless ``overwrite`` is given, and then removes those outputs first (so a
rerun with ``--no-log`` leaves no old ``run.mcap`` behind).  The default run id
(:func:`unique_run_dir`) is the time, the field and the seed, with a counter suffix
(``-2``, ``-3``, ...) when that folder exists already; the folder is made with an exclusive
``mkdir``, so two runs started in the same second get two folders.

A run id is a folder *name*, not a path (:func:`check_run_id`): one with a path separator, ``.``
or ``..``, an absolute path, a control character or more than 255 bytes is refused with one line
(a :class:`~ag_uav.config.ConfigError`), so a run never writes outside its ``--out`` folder nor
into that folder itself.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path

from ..config import ConfigError

LOCK_NAME = ".ag-uav.lock"
#: what a run writes into its folder (and ``ag-uav plot``'s default output folder)
RUN_OUTPUTS = ("summary.json", "run.mcap", "layout.json", "dose.npz", "plots")

_HELD: set[str] = set()  # folders locked by this process (POSIX locks do not exclude threads)
_HELD_LOCK = threading.Lock()


class FolderInUse(RuntimeError):
    """Another process (or another job of this one) is writing into the folder."""


def _holder(lock: Path) -> str:
    try:
        pid = lock.read_text("ascii", "replace").strip()
    except OSError:
        pid = ""
    return f"pid {pid}" if pid.isdigit() else "another process"


def _lock(lock: Path) -> int | None:
    """An fd holding the lock on ``lock`` (made if missing), or None if another process holds
    it.  Retried when the file was removed or replaced between the open and the lock (its
    holder was leaving): the lock held is always the one on the file at that path."""
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno not in (errno.EACCES, errno.EAGAIN):
                raise
            return None
        try:
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)


@contextlib.contextmanager
def hold(folder: str | os.PathLike[str], what: str, hint: str) -> Iterator[Path]:
    """Hold ``folder`` (made if missing) for one writer while the block runs; raise
    :class:`FolderInUse` (one line: ``what`` is the kind of job, ``hint`` what to do) if another
    writer holds it.  The lock file is removed when the block ends."""
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    key, lock = str(d.resolve()), d / LOCK_NAME
    with _HELD_LOCK:
        fd = None if key in _HELD else _lock(lock)
        if fd is None:
            who = "this process" if key in _HELD else _holder(lock)
            raise FolderInUse(f"{d} is in use by another {what} ({who} holds {lock}); {hint}")
        _HELD.add(key)
    try:
        with contextlib.suppress(OSError):  # the holder's pid, for the refusal (a full disk:
            os.ftruncate(fd, 0)             # the lock holds without it)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield d
    finally:
        with _HELD_LOCK:
            _HELD.discard(key)
            with contextlib.suppress(OSError):
                lock.unlink()  # still held: a process that opened it now retries (see _lock)
            os.close(fd)


def check_run_id(run_id: str, flag: str = "--run-id") -> str:
    """``run_id`` if it is a plain folder name; else :class:`~ag_uav.config.ConfigError` (one
    line naming ``flag``, the value and what is allowed): not empty, not ``.`` or ``..``, no
    ``/`` or ``\\`` (nor the platform's separators), not absolute, no control character, at
    most 255 bytes (a POSIX file name)."""
    why = None
    if not isinstance(run_id, str) or not run_id.strip():
        why = "is empty"
    elif run_id in (".", ".."):
        why = "names the --out folder itself or its parent"
    elif os.path.isabs(run_id) or any(c in run_id for c in {"/", "\\", os.sep, os.altsep or "/"}):
        why = "is a path"
    elif any(ord(c) < 32 or ord(c) == 127 for c in run_id):
        why = "holds a control character"
    elif len(run_id.encode("utf-8", "surrogateescape")) > 255:
        why = "is longer than 255 bytes"
    if why:
        raise ConfigError(f"{flag} = {run_id!r}: {why}; a run id is a folder name inside --out, "
                          "not a path (no '/' or '\\', not '.' or '..')")
    return run_id


def unique_run_dir(root: str | os.PathLike[str], base: str) -> Path:
    """A new folder ``root/base``, or ``root/base-2``, ``-3``, ... where that exists (made with an
    exclusive ``mkdir``: two processes never get the same one)."""
    r = Path(root)
    r.mkdir(parents=True, exist_ok=True)
    for k in range(1, 10_000):
        d = r / (base if k == 1 else f"{base}-{k}")
        try:
            d.mkdir()
        except FileExistsError:
            continue
        return d
    raise FileExistsError(errno.EEXIST, "no free run folder name", str(r / base))


def old_outputs(run_dir: Path) -> list[Path]:
    """A previous run's outputs in ``run_dir`` (and leftover temporary files)."""
    if not run_dir.is_dir():
        return []
    out = [run_dir / n for n in RUN_OUTPUTS if (run_dir / n).exists()]
    return out + sorted(p for p in run_dir.glob(".*.tmp*") if p.is_file())


def clear_outputs(paths: list[Path]) -> None:
    for p in paths:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink(missing_ok=True)


def check_reuse(run_dir: Path, overwrite: bool, flag: str = "--run-id") -> None:
    """Refuse a run folder holding a previous run's outputs unless ``overwrite``
    (:class:`RunFolderExists`, one line); with it, remove them."""
    old = old_outputs(run_dir)
    if not old:
        return
    if not overwrite:
        names = ", ".join(p.name for p in old[:4]) + (", ..." if len(old) > 4 else "")
        raise RunFolderExists(f"{run_dir} holds a previous run's outputs ({names}); pass "
                              f"--overwrite to replace them, or choose another {flag}")
    clear_outputs(old)


class RunFolderExists(RuntimeError):
    """A run folder holds a previous run's outputs and ``overwrite`` was not given."""
