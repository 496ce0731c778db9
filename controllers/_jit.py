"""``njit``: numba's ``njit(cache=True)`` when numba imports, else an identity decorator.

numba is a declared dependency (the batched per-tick kernels of :mod:`controllers.batched` are
compiled with it), but :mod:`controllers` must stay importable and correct on numpy alone: without
numba the decorated functions run as plain Python (same results, much slower).
No ``fastmath``: the compiled kernels must give the scalar Python floats' results (IEEE order of
operations kept), to ~1e-12.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

__all__ = ["HAVE_NUMBA", "njit", "package_dir", "sweep_stale_caches"]

F = TypeVar("F", bound=Callable[..., Any])

try:
    import numba as _numba
except ImportError:  # pragma: no cover - exercised only where numba is not installed
    _numba = None

#: True when the kernels are compiled (numba importable).
HAVE_NUMBA: bool = _numba is not None


def njit(fn: F) -> F:
    """Compile ``fn`` with ``numba.njit(cache=True)`` (the GIL kept, numba's default: the batched
    cascade is a short per-tick kernel, and releasing the GIL at each call costs a thread
    hand-off when other threads want it); without numba return it unchanged.

    Without numba (or with ``NUMBA_DISABLE_JIT=1``) the function gets a ``py_func`` attribute
    pointing to itself, so callers and tests can use ``kernel.py_func`` either way.
    """
    out = fn if _numba is None else _numba.njit(cache=True)(fn)
    if not hasattr(out, "py_func"):  # no numba, or NUMBA_DISABLE_JIT=1
        out.py_func = fn
    return out  # type: ignore[no-any-return]


#: the stamp each package keeps in its ``__pycache__``: the hash of the sources its kernels were
#: compiled from
STAMP = "numba-sources.stamp"


def package_dir(name: str) -> Path:
    """The folder of the top-level package ``name``, found without importing it."""
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        raise ImportError(f"package {name!r} not found")
    return Path(list(spec.submodule_search_locations)[0])


def sources_hash(sources: Sequence[Path]) -> str:
    """blake2b of every ``.py`` file under ``sources`` (relative names and bytes, sorted)."""
    h = hashlib.blake2b(digest_size=16)
    for d in sources:
        for f in sorted(d.rglob("*.py")):
            h.update(f.relative_to(d.parent).as_posix().encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def sweep_stale_caches(own: Path, sources: Sequence[Path]) -> int:
    """Delete the numba cache files (``*.nbi``, ``*.nbc``) of the package ``own`` when the
    sources of ``sources`` (the package and every package its kernels call) differ from those
    the cache was compiled from; returns how many were deleted.

    numba keys a kernel's cache on its own file's time stamp only: a kernel that inlines a law
    from another file (the INS calls :mod:`estimators.kf`'s update; the engine's kernels call
    the controllers') would keep running the old law after that file alone changes, silently.
    Called once at import, before any kernel runs (numba reads an index at a kernel's first
    call).  A concurrent process at worst recompiles.  Both places numba may keep them are
    swept, each with its own stamp: the package's ``__pycache__`` folders and, when
    ``NUMBA_CACHE_DIR`` is set, numba's folders for the package's source folders there.  A
    user-wide cache (numba's fallback for a read-only install, whose files change together) is
    not swept."""
    try:
        key = sources_hash(sources)
    except OSError:
        return 0
    n = 0
    places = [(own / "__pycache__" / STAMP,
               [*own.rglob("__pycache__/*.nbi"), *own.rglob("__pycache__/*.nbc")])]
    user = _user_cache_dirs(own)
    if user:
        tag = hashlib.sha1(str(own.resolve()).encode()).hexdigest()[:16]
        places.append((user[0].parent / "ag-uav-stamps" / f"{own.name}-{tag}",
                       [f for d in user for f in (*d.glob("*.nbi"), *d.glob("*.nbc"))]))
    for stamp, files in places:
        try:
            if stamp.is_file() and stamp.read_text() == key:
                continue
        except OSError:
            continue
        n += _unlink_all(files)
        _write_stamp(stamp, key)
    return n


def _user_cache_dirs(own: Path) -> list[Path]:
    """Where numba keeps the kernels of ``own``'s modules when ``NUMBA_CACHE_DIR`` is set: one
    folder per source folder, named by numba's own ``UserProvidedCacheLocator``; [] when it is
    not set."""
    if _numba is None:  # pragma: no cover
        return []
    from numba.core import config
    from numba.core.caching import UserProvidedCacheLocator

    if not config.CACHE_DIR:
        return []
    dirs = sorted({f.parent for f in own.rglob("*.py")})
    return [Path(config.CACHE_DIR) / UserProvidedCacheLocator.get_suitable_cache_subpath(
        str(d / "_.py")) for d in dirs]


def _unlink_all(files: Sequence[Path]) -> int:
    n = 0
    for f in files:
        try:
            f.unlink()
            n += 1
        except OSError:
            pass
    return n


def _write_stamp(stamp: Path, key: str) -> None:
    try:
        stamp.parent.mkdir(parents=True, exist_ok=True)
        tmp = stamp.with_name(f"{stamp.name}.{os.getpid()}")
        tmp.write_text(key)
        os.replace(tmp, stamp)
    except OSError:
        pass


if _numba is not None:
    sweep_stale_caches(Path(__file__).parent, [Path(__file__).parent])
