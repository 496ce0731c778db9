"""Crash safety of the open run logs: SIGTERM and SIGINT close every open log (a tick row
still being filled is dropped, not written half-done) and then behave as before
(KeyboardInterrupt / exit status 128+signal); an ``atexit`` hook closes the rest."""

from __future__ import annotations

import atexit
import signal
import threading
import weakref
from typing import Any

_OPEN: weakref.WeakSet[Any] = weakref.WeakSet()
_PREV_HANDLERS: dict[int, Any] = {}
_HANDLERS_INSTALLED = False


def track(log: Any) -> None:
    """Close ``log`` (anything with ``close(partial=...)``) on SIGTERM/SIGINT and at exit."""
    _OPEN.add(log)
    _install_handlers()


def untrack(log: Any) -> None:
    """``log`` is closed (or its writer is gone): forget it."""
    _OPEN.discard(log)


def close_all(partial: bool = False) -> None:
    for log in list(_OPEN):
        try:
            log.close(partial=partial)
        except Exception:  # noqa: BLE001 - closing the others matters more
            pass


def _on_signal(signum: int, frame: Any) -> None:
    close_all(partial=True)  # a tick row being filled when the signal came is dropped
    prev = _PREV_HANDLERS.get(signum)
    if callable(prev):
        prev(signum, frame)
        return
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise SystemExit(128 + signum)


def _install_handlers() -> None:
    global _HANDLERS_INSTALLED
    if _HANDLERS_INSTALLED or threading.current_thread() is not threading.main_thread():
        return
    for sig in (signal.SIGTERM, signal.SIGINT):
        try:
            prev = signal.getsignal(sig)
            if prev is _on_signal:
                continue
            signal.signal(sig, _on_signal)
            _PREV_HANDLERS[sig] = prev
        except (ValueError, OSError):  # not allowed here: rely on context manager / atexit
            pass
    atexit.register(close_all)
    _HANDLERS_INSTALLED = True
