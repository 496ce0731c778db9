"""Numerics shared by ``controllers``, ``estimators`` and ``ag_uav``: flat-array layouts.

It imports numpy (and numba where a kernel needs it) only, never ``ag_uav`` or ``mujoco``."""

from .layout import Layout

__all__ = ["Layout"]
