"""The feedback seam: what the controller flies on.

Each control tick the engine hands every flight's :class:`Feedback` the true state and gets
back the position and velocity the controller flies on. :class:`TrueFeedback` passes the truth
through; the estimator bank (:class:`ag_uav.navigation.estimation.EstimatorFeedback`), the
bearing localiser and the route-constrained bank plug in with the same interface.
:meth:`Feedback.batch` lets a feedback class fly a whole engine batch at once (the estimator bank
does), without the engine knowing the class.
"""

from __future__ import annotations

from typing import Any


class Feedback:
    """What the controller flies on. ``update`` is called once per control tick.

    A feedback with ``wants_imu`` gets the MEMS IMU's reading each tick as
    ``imu = (f̃, R̂)``: the measured specific force (body frame, m/s²) and the attitude estimate
    (row-major 3×3), see :mod:`ag_uav.vehicle.imu`; the controller then flies on ``R̂`` and the gyro.
    """

    name = "base"
    wants_imu = False

    def update(self, t: float, p_true: tuple[float, float, float],
               v_true: tuple[float, float, float], imu: tuple | None = None,
               ) -> tuple[tuple[float, ...], tuple[float, ...]]:
        raise NotImplementedError

    def summary(self) -> dict[str, Any]:
        return {}

    @classmethod
    def batch(cls, feedbacks: list[Feedback], n_max: int) -> Any | None:
        """One object that updates a whole engine batch of feedbacks at once (the engine
        calls it on the first feedback's class), or None: the engine then updates them one
        by one. ``n_max``: the most control ticks of any flight in the batch."""
        return None


class TrueFeedback(Feedback):
    """Perfect state feedback (the baseline and the tuning default)."""

    name = "true"

    def update(self, t, p_true, v_true, imu=None):
        return p_true, v_true
