"""``njit``: :func:`numba.njit` with ``cache=True`` when numba is installed, else the identity.

The row functions where each filter law lives (:mod:`estimators.kf`, :mod:`estimators.mckf`,
:mod:`estimators.pca`, :mod:`estimators._linalg`) and the batched kernels of
:mod:`estimators.batched` that loop over them are written as plain Python loops over float64
arrays so that they also run (slowly, for tests and small batches) on numpy alone: the package
must stay importable with numpy/scipy only.  No ``fastmath``: a vehicle's results must be
bit-identical in a scalar filter and in any row of any batch.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from jitcache import package_dir, sweep_stale_caches

__all__ = ["HAVE_NUMBA", "njit"]

try:  # pragma: no cover - depends on the environment
    import numba as _numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    _numba = None
    HAVE_NUMBA = False

if _numba is not None:  # the estimators use the controllers (estimators.pso_r): both are keys
    sweep_stale_caches(Path(__file__).parent, [Path(__file__).parent, package_dir("controllers"),
                                               package_dir("numkit")])


def njit(func: Callable[..., Any] | None = None, **options: Any) -> Any:
    """Compile ``func`` with ``numba.njit(cache=True, nogil=True, **options)`` (the GIL released:
    a batch of filters is long work, and callers may run it in several threads, as an engine's
    lanes do with the INS bank); without numba return it
    unchanged.  Use as ``@njit`` or ``@njit(inline="always")``."""
    if func is None:
        return lambda f: njit(f, **options)
    if _numba is None:  # pragma: no cover
        return func
    options.setdefault("nogil", True)
    return _numba.njit(cache=True, **options)(func)
