"""Standalone controller library: IT2 / type-1 fuzzy PID, PID, and BB-BC / PSO tuners.

Depends on numpy and numba (optional: :mod:`controllers._jit`), nothing from ``ag_uav`` or
``mujoco``. Each control law is written once, as a compiled function on one controller's (or one
vehicle's) parameter and state arrays: the axis law in :mod:`controllers.axis`, thrust vectoring,
attitude and mixer in :mod:`controllers.attitude`, the cascade row in :mod:`controllers.cascade`;
a quad's three-rotor law after a rotor loss in :mod:`controllers.rotor_loss` (numpy).
The classes (``PID``, ``FPID``, ``IT2FPID``, ``PositionCascade``, ...) are thin shells that call
them on their own arrays; :mod:`controllers.batched` calls them row by row.
"""

from .factory import CONTROLLERS, make_controller
from .fpid import FPID, IT2FPID, PAPER_TABLE_I, equivalent_pid
from .fuzzy import REDUCERS, IT2FuzzyPD, T1FuzzyPD, heights_from_alpha, small_signal_gain
from .optim import BBBC, PSO, OptimResult, bbbc_minimize, pso_minimize
from .pid import PID
from .rotor_loss import RelaxedHover

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
    "RelaxedHover",
    "T1FuzzyPD",
    "bbbc_minimize",
    "equivalent_pid",
    "heights_from_alpha",
    "make_controller",
    "pso_minimize",
    "small_signal_gain",
]
