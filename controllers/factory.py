"""Build a controller from a name and keyword parameters (e.g. from a config file)."""

from __future__ import annotations

from typing import Any

from .fpid import FPID, IT2FPID
from .pid import PID

__all__ = ["CONTROLLERS", "make_controller"]

#: Allowed names for :func:`make_controller` and the class each one builds.
CONTROLLERS: dict[str, type] = {"it2-fpid": IT2FPID, "t1-fpid": FPID, "pid": PID}


def make_controller(name: str, **params: Any) -> IT2FPID | FPID | PID:
    """Construct ``"it2-fpid"`` (:class:`IT2FPID`), ``"t1-fpid"`` (:class:`FPID`) or
    ``"pid"`` (:class:`PID`) with ``params`` passed to the constructor.

    Raises ValueError for an unknown name (the message lists the allowed names).
    """
    try:
        cls = CONTROLLERS[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown controller {name!r}; allowed: {', '.join(CONTROLLERS)}"
        ) from None
    return cls(**params)
