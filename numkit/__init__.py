"""Numerics shared by ``controllers``, ``estimators`` and ``ag_uav``: flat-array layouts,
component names, and every quaternion, rotation and Euler-angle conversion
(:mod:`numkit.geometry`, its conventions stated there once).

It imports numpy, numba where a kernel needs it and ``jitcache`` only, never ``ag_uav`` or
``mujoco``."""

from .axes import QW, QX, QY, QZ, X, Y, Z
from .layout import Layout

__all__ = ["QW", "QX", "QY", "QZ", "X", "Y", "Z", "Layout"]
