"""Standalone controller library: IT2 / type-1 fuzzy PID, PID, and BB-BC / PSO tuners.

Depends on numpy (and nothing from ``ag_uav`` or ``mujoco``). Hot paths (``update``,
``Φ``) use plain Python floats so that a control tick costs a few microseconds.
"""

from .factory import CONTROLLERS, make_controller
from .fpid import FPID, IT2FPID, PAPER_TABLE_I, equivalent_pid
from .fuzzy import REDUCERS, IT2FuzzyPD, T1FuzzyPD, heights_from_alpha, small_signal_gain
from .optim import BBBC, PSO, OptimResult, bbbc_minimize, pso_minimize
from .pid import PID

__all__ = [
    "BBBC",
    "CONTROLLERS",
    "FPID",
    "IT2FPID",
    "IT2FuzzyPD",
    "OptimResult",
    "PAPER_TABLE_I",
    "PID",
    "PSO",
    "REDUCERS",
    "T1FuzzyPD",
    "bbbc_minimize",
    "equivalent_pid",
    "heights_from_alpha",
    "make_controller",
    "pso_minimize",
    "small_signal_gain",
]
