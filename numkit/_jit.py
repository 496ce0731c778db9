"""``njit``: numba's ``njit(cache=True)`` when numba imports, else the identity.

``numkit``'s compiled functions are leaf laws that the kernels of ``controllers``,
``estimators`` and ``ag_uav`` call (numba compiles them into the caller), and that plain Python
calls too; without numba they run as plain Python (same results, slower), so the packages stay
importable on numpy alone.  No ``fastmath``: IEEE order of operations kept.  At import the
package's stale kernels are swept from numba's cache (:func:`jitcache.sweep_stale_caches`);
the callers' packages sweep theirs against ``numkit``'s sources too.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from jitcache import sweep_stale_caches

__all__ = ["HAVE_NUMBA", "njit"]

F = TypeVar("F", bound=Callable[..., Any])

try:
    import numba as _numba
except ImportError:  # pragma: no cover - exercised only where numba is not installed
    _numba = None

#: True when the functions are compiled (numba importable).
HAVE_NUMBA: bool = _numba is not None


def njit(fn: F) -> F:
    """Compile ``fn`` with ``numba.njit(cache=True)``; without numba return it unchanged."""
    return fn if _numba is None else _numba.njit(cache=True)(fn)  # type: ignore[no-any-return]


if _numba is not None:
    sweep_stale_caches(Path(__file__).parent, [Path(__file__).parent])
