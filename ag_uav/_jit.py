"""numba for the application's kernels, in one place: ``njit`` and ``register_jitable`` are
numba's; without numba (a declared dependency) they return the function itself and the kernels
run as plain Python, correct and slow. Kernels use ``@njit(cache=True)`` and keep the GIL
(numba's default): they are the engine's short per-tick kernels, and a lane that released the
GIL at each of them handed it to another lane's Python and waited to get it back
(docs/speed.md); no ``fastmath`` (a vehicle's results must not depend on the batch it flies
in). At import a module's kernels are swept from the cache when its source or any
source it imports (in ``ag_uav``, ``estimators``, ``controllers`` or ``numkit``) changed
(:func:`jitcache.sweep_stale_caches`: numba alone would keep a kernel that inlined an old
law from another file).

LLVM optimises the kernels at level :data:`OPT_LEVEL` (numba's ``NUMBA_OPT``; numba's own
default is 3), set here for the process unless ``NUMBA_OPT`` is in the environment: the
results are the same bit for bit, the first run compiles faster and the warm loop keeps its
speed (docs/speed.md, "LLVM's optimisation level")."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from jitcache import package_dir, sweep_stale_caches

__all__ = ["HAVE_NUMBA", "OPT_LEVEL", "njit", "register_jitable"]

#: LLVM's optimisation level for the kernels compiled in this process (see the module)
OPT_LEVEL = 2


def _set_opt_level() -> None:
    """``NUMBA_OPT`` = :data:`OPT_LEVEL` for numba (and the processes started from this one)
    unless the environment sets it; numba reads its level when it optimises each kernel."""
    if "NUMBA_OPT" in os.environ:
        return
    os.environ["NUMBA_OPT"] = str(OPT_LEVEL)
    from numba.core import config

    config.reload_config()


try:
    import numba as _numba
    from numba.extending import register_jitable

    HAVE_NUMBA = True

    def njit(*args: Any, **kwargs: Any) -> Any:
        """numba's ``njit`` (the GIL kept unless ``nogil=True`` is passed: see the module)."""
        return _numba.njit(*args, **kwargs)
except ImportError:  # pragma: no cover - numba is a dependency
    HAVE_NUMBA = False

    def njit(*args: Any, **kwargs: Any) -> Any:  # type: ignore[no-redef]
        return args[0] if args and callable(args[0]) else (lambda f: f)

    def register_jitable(f: Callable[..., Any]) -> Callable[..., Any]:  # type: ignore[no-redef]
        return f

if HAVE_NUMBA:  # the application's kernels call the estimators' and the controllers'
    _set_opt_level()
    sweep_stale_caches(Path(__file__).parent, [Path(__file__).parent, package_dir("estimators"),
                                               package_dir("controllers"), package_dir("numkit")])
