"""Numerics shared by ``controllers``, ``estimators`` and ``ag_uav``: flat-array layouts and
component names.

It imports numpy (and numba where a kernel needs it) only, never ``ag_uav`` or ``mujoco``."""

from .axes import QW, QX, QY, QZ, X, Y, Z
from .layout import Layout

__all__ = ["QW", "QX", "QY", "QZ", "X", "Y", "Z", "Layout"]
