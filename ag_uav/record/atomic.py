"""Atomic file writes: an output appears whole, under its final name, or not at all.

Every output of a command (``summary.json``, plans, plots, recovered logs, videos, batch
results) is written to a temporary file in the destination's folder and renamed onto the
destination with :func:`os.replace`, which is atomic on one filesystem (POSIX ``rename(2)``).
A failed write (disk full, no permission, a writer's exception) removes the temporary file, so
no 0-byte or half-written output and no ``*.tmp`` file is left, and the destination keeps its
old content if it had one.  An :class:`OSError` raised while writing is re-raised with the
*destination* as its ``filename`` (a ``write(2)`` failure carries no name), so the command line
can print one line naming the path (:func:`disk_error_line`).

    atomic_write_text(path, text)        -> Path
    atomic_write_bytes(path, data)       -> Path
    with atomic_path(path) as tmp: ...   any writer that takes a file name (savefig, ffmpeg,
                                         an MCAP writer); renamed onto ``path`` on success
    with atomic_open(path, "w") as fh:   a file object on the temporary file
    disk_error_line(err)                 "PATH: No space left on device"
    silent_write_failure(path, detail)   an OSError for a writer that failed without one

The temporary name is ``.<name>.<random>.tmp<suffix>`` (hidden, and it keeps the suffix, so a
writer that picks its format from the extension still sees ``.png`` or ``.mp4``).
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_path", "atomic_open", "atomic_write_text", "atomic_write_bytes",
           "disk_error_line", "temp_name", "silent_write_failure"]


def temp_name(path: str | os.PathLike[str]) -> Path:
    """A fresh temporary path beside ``path``: ``.<name>.<random>.tmp<suffix>``."""
    p = Path(path)
    return p.with_name(f".{p.name}.{secrets.token_hex(4)}.tmp{p.suffix}")


def _named(err: OSError, path: Path, tmp: Path | None = None) -> OSError:
    """``err`` with ``path`` as its file name (same class and errno), for a one-line message.

    Only an error about no file, or about ``tmp``, is renamed: one naming another file (an
    input that could not be read) is left as it is."""
    if err.filename is not None and (tmp is None or str(err.filename) != str(tmp)):
        return err
    out = type(err)(err.errno, err.strerror or str(err), str(path))
    out.__cause__ = err
    return out


def _unlink(p: Path) -> None:
    with contextlib.suppress(OSError):
        p.unlink()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], *, mkdir: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on a normal exit rename it onto ``path``.

    On any exception the temporary file is removed and the exception re-raised (an
    :class:`OSError` renamed to ``path``).  A body that writes nothing leaves nothing.
    """
    dest = Path(path)
    if mkdir:
        try:
            dest.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise _named(e, dest.parent) from None
    tmp = temp_name(dest)
    try:
        yield tmp
        if tmp.exists():
            os.replace(tmp, dest)
    except OSError as e:
        _unlink(tmp)
        raise _named(e, dest, tmp) from None
    except BaseException:
        _unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w", *, fsync: bool = True,
                **kw: Any) -> Iterator[IO[Any]]:
    """``open(tmp, mode)`` for writing; flushed (and fsync'ed), closed, then renamed."""
    if "w" not in mode:
        raise ValueError(f"atomic_open: mode {mode!r}: only 'w' modes (the file is replaced)")
    with atomic_path(path) as tmp:
        fh = open(tmp, mode, **kw)  # noqa: SIM115 - closed just below
        try:
            yield fh
            fh.flush()
            if fsync:
                os.fsync(fh.fileno())
        finally:
            fh.close()  # a close that fails (delayed ENOSPC) raises here, inside atomic_path


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes, *, fsync: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically; the path."""
    with atomic_open(path, "wb", fsync=fsync) as fh:
        fh.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike[str], text: str, *, encoding: str = "utf-8",
                      fsync: bool = True) -> Path:
    """Write ``text`` to ``path`` atomically; the path."""
    return atomic_write_bytes(path, text.encode(encoding), fsync=fsync)


#: the errors of an output that cannot be written (space, permission, read-only, quota, size)
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EACCES, errno.EPERM, errno.EROFS, errno.EDQUOT,
                         errno.EFBIG})


def savefig(fig: Any, path: str | os.PathLike[str], **kw: Any) -> Path:
    """``fig.savefig`` atomically (the format from ``path``'s extension, kept by the temp)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kw)
    return Path(path)


def disk_error_line(err: OSError) -> str:
    """One line for a failed file operation: ``PATH: <strerror>`` (``<strerror>`` alone when
    the error names no file)."""
    what = err.strerror or str(err)
    return what if err.filename is None else f"{err.filename}: {what}"


def silent_write_failure(path: str | os.PathLike[str], detail: str) -> OSError:
    """An :class:`OSError` naming ``path`` for a writer that failed without an OS error (an
    SDK's generic error, a subprocess's exit): ENOSPC when ``path``'s folder has less than
    1 MiB free (the likely cause), else EIO with ``detail``."""
    p = Path(path)
    try:
        full = shutil.disk_usage(p.parent if p.parent.exists() else ".").free < (1 << 20)
    except OSError:
        full = False
    code = errno.ENOSPC if full else errno.EIO
    return OSError(code, f"{os.strerror(code)} ({detail})", str(p))
