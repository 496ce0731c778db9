"""Replaying a recorded flight through the product's INS (``ag-uav replay``): readers of PX4
ULog, ArduPilot DataFlash, a documented CSV layout and the Phantom 4 RTK set's path folders
(:mod:`~ag_uav.navigation.replay.readers`), the clock and mounting alignment and the initial
state (:mod:`~ag_uav.navigation.replay.align`), the run of the INS bank — the four GNSS rules
with the gate and latch, the same compiled kernel a simulated flight navigates on
(:mod:`~ag_uav.navigation.replay.runner`) — and its scores
(:mod:`~ag_uav.navigation.replay.scores`)."""

from __future__ import annotations

from .data import FlightLog, ReplayError, Track
from .readers import read_log
from .runner import ReplayOptions, ReplayResult, run_replay
from .scores import score_replay

__all__ = ["FlightLog", "ReplayError", "ReplayOptions", "ReplayResult", "Track", "read_log",
           "run_replay", "score_replay"]
