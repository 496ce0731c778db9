"""Whole-file writes of the batch and tune outputs: written beside the target, fsynced, renamed.

A reader sees the old file or the new one, never a part; a failed write (ENOSPC, EACCES, ...)
leaves no ``.tmp`` behind and raises :class:`OSError` whose ``filename`` is the target, so the
command line can say in one line which path could not be written.

Private to ``ag_uav.jobs`` until the shared ``ag_uav.record.atomic`` replaces it.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` (``os.replace``);
    on any error it is removed and an :class:`OSError` names ``path``."""
    target = Path(path)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        yield tmp
        with tmp.open("rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise OSError(e.errno, e.strerror or str(e), str(target)) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_atomic(path: str | Path, writer: Callable[[IO[Any]], None], *, binary: bool = False,
                 newline: str | None = None) -> Path:
    """``writer(f)`` into a temporary file beside ``path``, then rename it to ``path``."""
    with atomic_path(path) as tmp:
        with tmp.open("wb" if binary else "w", **({} if binary else {"newline": newline})) as f:
            writer(f)
    return Path(path)


def write_text_atomic(path: str | Path, text: str) -> Path:
    return write_atomic(path, lambda f: f.write(text))


def savefig_atomic(fig: Any, path: str | Path, **kw: Any) -> Path:
    """``fig.savefig`` through a temporary file (the format from ``path``'s suffix)."""
    fmt = Path(path).suffix.lstrip(".") or None
    return write_atomic(path, lambda f: fig.savefig(f, format=fmt, **kw), binary=True)


def disk_error_line(e: OSError) -> str | None:
    """One line for an output that could not be written (no space, no permission, read-only
    or quota), or None for any other OSError."""
    import errno

    codes = {errno.ENOSPC, errno.EACCES, errno.EPERM, errno.EROFS, errno.EDQUOT, errno.EFBIG}
    if e.errno not in codes:
        return None
    where = f" {e.filename}" if e.filename else ""
    return f"cannot write{where}: {e.strerror or os.strerror(e.errno or 0)}"
