"""``njit``: numba's ``njit(cache=True)`` when numba imports, else an identity decorator.

numba is a declared dependency (the batched per-tick kernels of :mod:`controllers.batched` are
compiled with it), but :mod:`controllers` must stay importable and correct on numpy alone: without
numba the decorated functions run as plain Python (same results, much slower).
No ``fastmath``: the compiled kernels must give the scalar Python floats' results (IEEE order of
operations kept), to ~1e-12.  At import the package's stale kernels are swept from the cache
(:func:`jitcache.sweep_stale_caches`), the shared laws of ``numkit`` among their sources.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from jitcache import package_dir, sweep_stale_caches

__all__ = ["HAVE_NUMBA", "njit"]

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


if _numba is not None:
    sweep_stale_caches(Path(__file__).parent, [Path(__file__).parent, package_dir("numkit")])
