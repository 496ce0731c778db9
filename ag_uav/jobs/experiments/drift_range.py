"""The drift trial's buffers with an error bar: the low and high bounds of the uncertain inputs
(the wake-edge escape share, the surface layer's stability, the wind direction's meander), as
:mod:`ag_uav.world.drift_bounds` defines them (the flight's summary uses the same law)."""

from __future__ import annotations

from ...world.drift_bounds import BOUNDS, bound_config, meander  # noqa: F401

__all__ = ["BOUNDS", "bound_config", "meander"]
