"""numba's cache made safe for kernels that call laws in other files, shared by the three
packages (``ag_uav``, ``controllers``, ``estimators``): each package's ``_jit`` module calls
:func:`sweep_stale_caches` at import, before any of its kernels runs.

numba keys a cached kernel on its own file's time stamp only; a kernel that compiles a law
from another file into itself would keep running the old law after that file alone changes.
The sweep deletes exactly the cache files of the modules whose source, or the source of any
module they import (transitively, across the packages), changed.

A top-level package of its own, neither library's private module: the two standalone
libraries and the application all import it publicly, and it imports none of them (numpy-free,
numba optional: without numba there is no cache to sweep).
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import json
import os
from collections.abc import Sequence
from pathlib import Path

__all__ = ["HAVE_NUMBA", "STAMP", "module_closures", "package_dir", "sweep_stale_caches"]

try:
    import numba as _numba
except ImportError:  # pragma: no cover - exercised only where numba is not installed
    _numba = None

#: True when numba imports (the packages' kernels are compiled and cached).
HAVE_NUMBA: bool = _numba is not None


#: the stamp each package keeps in its ``__pycache__``: the hash of the sources its kernels were
#: compiled from
STAMP = "numba-sources.stamp"


def package_dir(name: str) -> Path:
    """The folder of the top-level package ``name``, found without importing it."""
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        raise ImportError(f"package {name!r} not found")
    return Path(list(spec.submodule_search_locations)[0])


def _module_name(f: Path, root: Path) -> str:
    parts = list(f.relative_to(root.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported(tree: ast.AST, mod: str, is_pkg: bool) -> set[str]:
    """Every dotted name ``mod``'s source imports (function-local imports too), relative ones
    resolved; ``from a import b`` names both ``a`` and ``a.b`` (``b`` may be a module)."""
    out: set[str] = set()
    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            head = base[:len(base) - node.level + 1] if node.level else []
            name = ".".join([*head, *([node.module] if node.module else [])])
            out.add(name)
            out.update(f"{name}.{a.name}" for a in node.names)
    return out


def module_closures(sources: Sequence[Path], memo: dict | None = None,
                    only: str | None = None) -> dict[str, str]:
    """For each module under ``sources``: a hash of its source and of the sources of every
    module under ``sources`` it imports, transitively (parent packages included).

    A cached kernel can only call code its module reaches by imports, so a kernel is stale
    exactly when its module's closure hash changed.  ``memo`` (``{module: [digest, imports]}``)
    spares parsing files whose bytes did not change; it is updated in place.  ``only``: the
    closures of that top-level package's modules alone."""
    memo = {} if memo is None else memo
    digest: dict[str, str] = {}
    deps: dict[str, set[str]] = {}
    for d in sources:
        for f in sorted(d.rglob("*.py")):
            mod, data = _module_name(f, d), f.read_bytes()
            h = hashlib.blake2b(data, digest_size=16).hexdigest()
            if memo.get(mod, [None])[0] != h:
                tree = ast.parse(data)
                memo[mod] = [h, sorted(_imported(tree, mod, f.name == "__init__.py"))]
            digest[mod] = h
            deps[mod] = set(memo[mod][1])
    for mod in digest:  # a module's parents run before it; only modules under sources count
        parts = mod.split(".")
        deps[mod].update(".".join(parts[:i]) for i in range(1, len(parts)))
        deps[mod] = {n for n in deps[mod] if n in digest and n != mod}
    out = {}
    for mod in digest:
        if only is not None and mod.split(".")[0] != only:
            continue
        seen, todo = {mod}, [mod]
        while todo:
            for n in deps[todo.pop()]:
                if n not in seen:
                    seen.add(n)
                    todo.append(n)
        h = hashlib.blake2b(digest_size=16)
        for n in sorted(seen):
            h.update(f"{n}={digest[n]};".encode())
        out[mod] = h.hexdigest()
    return out


def sweep_stale_caches(own: Path, sources: Sequence[Path]) -> int:
    """Delete the numba cache files (``*.nbi``, ``*.nbc``) of each module of the package
    ``own`` whose source, or the source of any module of ``sources`` it imports (transitively),
    differs from what its cache was compiled from; returns how many were deleted.

    numba keys a kernel's cache on its own file's time stamp only: a kernel that inlines a law
    from another file (the INS calls :mod:`estimators.kf`'s update; the engine's kernels call
    the controllers') would keep running the old law after that file alone changes, silently.
    Called once at import, before any kernel runs (numba reads an index at a kernel's first
    call).  A module whose imports do not reach the changed file keeps its kernels (an edit of
    the command line does not recompile the physics).  A concurrent process at worst
    recompiles.  Both places numba may keep them are swept, each with its own stamp (a JSON
    of every module's closure hash): the package's ``__pycache__`` folders and, when
    ``NUMBA_CACHE_DIR`` is set, numba's folders for the package's source folders there.  A
    user-wide cache (numba's fallback for a read-only install, whose files change together) is
    not swept."""
    srcs = _source_dirs(own)
    places = [(own / "__pycache__" / STAMP, [d / "__pycache__" for d in srcs])]
    user = _user_cache_dirs(own)
    if user:
        tag = hashlib.sha1(str(own.resolve()).encode()).hexdigest()[:16]
        places.append((user[0].parent / "ag-uav-stamps" / f"{own.name}-{tag}", user))
    n = 0
    for stamp, caches in places:
        old = _read_stamp(stamp)
        memo = old.get("parsed", {})
        try:
            closures = module_closures(sources, memo, own.name)
        except (OSError, SyntaxError, ValueError):
            return n
        was = old.get("closures", {})
        stale = {m for m, h in closures.items() if was.get(m) != h}
        files = [f for src, cache in zip(srcs, caches, strict=True)
                 for f in _cache_files(src, cache, own, stale)]
        n += _unlink_all(files)
        if closures != was:
            _write_stamp(stamp, json.dumps({"closures": closures, "parsed": memo}))
    return n


def _source_dirs(own: Path) -> list[Path]:
    """The package's source folders, sorted (numba keeps a cache folder for each)."""
    return sorted({f.parent for f in own.rglob("*.py")})


def _cache_files(src: Path, cache: Path, own: Path, stale: set[str]) -> list[Path]:
    """The cache files in ``cache`` (numba's folder for source folder ``src``) of the modules
    in ``stale``: numba names them ``<file stem>.<qualname>-<line>.pyXY[.N].nbi|nbc``."""
    if not cache.is_dir():
        return []
    return [f for f in (*cache.glob("*.nbi"), *cache.glob("*.nbc"))
            if _module_name(src / (f.name.split(".", 1)[0] + ".py"), own) in stale]


def _read_stamp(stamp: Path) -> dict:
    """The stamp's record, ``{}`` when there is none or it is unreadable (all stale)."""
    try:
        rec = json.loads(stamp.read_text())
    except (OSError, ValueError):
        return {}
    return rec if isinstance(rec, dict) else {}


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
