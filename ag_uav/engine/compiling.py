"""What the engine says of numba's compile on a fresh checkout: a notice when the first kernel
starts compiling (before the wait, once per process), the kernels counted on the flight's progress
bar as they compile, and how long the compile took, said at tick 0: tick 0's own time when it
compiled (kept out of the loop's wall time) plus what compiled before it under
:func:`compile_notice` (the INS, compiled first while a helper takes the rest:
:mod:`ag_uav.engine.warm`)."""

from __future__ import annotations

import contextlib
import math
import sys
import time
from typing import Any

__all__ = ["COMPILE_NOTICE", "COMPILE_THRESHOLD_S", "compile_notice", "first_tick",
           "kernel_name"]

#: first-tick time above which the numba kernels are taken to have been compiled (not loaded)
COMPILE_THRESHOLD_S = 3.0
#: what this process has said of the compile: "" nothing, "started", "done"
_announced = ""
#: seconds compiled before tick 0 (:func:`compile_notice` with ``ahead``), said with tick 0's
_before_s = 0.0
#: said before tick 0's wait when numba starts compiling (once per process)
COMPILE_NOTICE = ("compiling kernels: first run only, about a minute on a 2-core "
                  "machine (cached for later runs) ...")


def _say(msg: str) -> None:
    """One line on stderr, above a progress bar if one is drawn."""
    from tqdm import tqdm

    tqdm.write(msg, file=sys.stderr)


@contextlib.contextmanager
def compile_notice(bar: Any = None, ahead: bool = False):
    """While tick 0 runs: the first ``numba:compile`` event (a kernel not in the cache) prints
    :data:`COMPILE_NOTICE` at once, so the wait is said before it, not after. With a progress
    bar, its postfix counts the kernels as they compile and names the one compiling (the bar
    itself stands at 0 until the first tick is done), at most every ``bar.mininterval``.
    ``ahead``: kernels compiled before tick 0 (their time is said with tick 0's,
    :func:`first_tick`)."""
    try:
        from numba.core import event
    except ImportError:  # pragma: no cover - the kernels run as Python
        yield
        return

    class _First(event.Listener):
        n, last = 0, -math.inf

        def on_start(self, ev: Any) -> None:
            global _announced
            if _announced == "":
                _announced = "started"
                _say(COMPILE_NOTICE)
            self.n += 1
            now = time.perf_counter()
            if bar is not None and now - self.last >= getattr(bar, "mininterval", 0.1):
                self.last = now
                bar.set_postfix_str(f"compiling kernel {self.n}: {kernel_name(ev)}",
                                    refresh=False)
                bar.refresh()

        def on_end(self, ev: Any) -> None:
            pass

    first = _First()
    t0 = time.perf_counter()
    try:
        with event.install_listener("numba:compile", first):
            yield
    finally:
        if bar is not None and first.n:
            bar.set_postfix_str("", refresh=False)
        if ahead and first.n:
            global _before_s
            _before_s += time.perf_counter() - t0


def kernel_name(ev: Any) -> str:
    """``module.function`` that a ``numba:compile`` event compiles ("?" when it names none)."""
    disp = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
    fn = getattr(disp, "py_func", None)
    return "?" if fn is None else f"{fn.__module__}.{fn.__qualname__}"


def first_tick(wall0: float) -> tuple[float, float]:
    """Tick 0 runs (and compiles, on a fresh checkout) every kernel: a long one is compile time,
    said once per process (:func:`compile_notice` said it before; this says how long it took)
    and kept out of the loop's wall time."""
    global _announced, _before_s
    now = time.perf_counter()
    took = now - wall0
    compiled = took >= COMPILE_THRESHOLD_S
    if _announced != "done" and (compiled or _before_s > 0.0):
        _announced = "done"
        _say(f"compiled the kernels in {_before_s + took * compiled:.0f} s (first run only; "
             "cached for later runs)")
    _before_s = 0.0
    return (took, now) if compiled else (0.0, wall0)
