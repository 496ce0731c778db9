"""Which code produced a result: the product's version and a hash of its sources.

:func:`source_hash` is the SHA-256 (first 16 hex digits) of every ``.py`` file of the packages
the product runs (:data:`PACKAGES`: ``ag_uav``, ``controllers``, ``estimators``, ``jitcache``),
as they are imported in this process: each file's path relative to its package's parent folder
and its bytes, in sorted path order (``__pycache__`` left out). Two processes with the same hash
run the same Python code; an edited file, added or removed, gives another hash. It is computed
once per process (reading ~1 MB) and cached.

:func:`provenance` is what a run's summary (``summary.json``) and each row of a batch's
``results.csv`` carry: ``ag_uav_version``, ``source_hash`` and, for a row, the ``worker_host``
and ``worker_pid`` of the process that flew it. A Dask batch compares every worker's
:func:`provenance` with its own before it runs anything
(:meth:`ag_uav.jobs.executor.DaskExecutor.check_sources`), as Dask's own version check compares
the packages.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import socket
from pathlib import Path
from typing import Any

__all__ = ["PACKAGES", "provenance", "row_provenance", "source_hash", "source_root"]

#: the packages whose sources are hashed
PACKAGES = ("ag_uav", "controllers", "estimators", "jitcache")

_CACHE: dict[str, str] = {}


def _package_dirs() -> list[Path]:
    """The folder of each of :data:`PACKAGES` as this process imports (or would import) it,
    found without importing it."""
    out = []
    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is None or not spec.submodule_search_locations:
            raise ModuleNotFoundError(f"no package {name!r} to hash")
        out.append(Path(next(iter(spec.submodule_search_locations))).resolve())
    return out


def source_hash() -> str:
    """The hash of the sources this process runs (module docstring); cached per process."""
    if "hash" not in _CACHE:
        h = hashlib.sha256()
        files = []
        for pkg in _package_dirs():
            for p in pkg.rglob("*.py"):
                if "__pycache__" not in p.parts:
                    files.append((p.relative_to(pkg.parent).as_posix(), p))
        for rel, p in sorted(files):
            data = p.read_bytes()
            h.update(f"{rel}\0{len(data)}\0".encode())
            h.update(data)
        _CACHE["hash"] = h.hexdigest()[:16]
    return _CACHE["hash"]


def source_root() -> str:
    """The folder this process imports ``ag_uav`` from (where its sources are)."""
    return str(_package_dirs()[0].parent)


def provenance() -> dict[str, Any]:
    """``ag_uav_version`` and ``source_hash``: the keys a run's summary carries."""
    from .. import __version__

    return {"ag_uav_version": __version__, "source_hash": source_hash()}


def row_provenance() -> dict[str, Any]:
    """:func:`provenance` with the ``worker_host`` and ``worker_pid`` of this process: the keys
    of a batch row (and, with ``source_root``, what a Dask worker reports to the client)."""
    return {**provenance(), "worker_host": socket.gethostname(), "worker_pid": os.getpid()}
