"""Batched wind + drag, MEMS IMU and attitude-error models for the lockstep engine.

The lockstep engine advances ``N`` missions at once (leading batch axis ``N``) at the control
rate.  This module runs, for the whole batch, the per-tick sensor/disturbance models of
:mod:`ag_uav.engine.loop`:

* :class:`BatchWind` -- ``N`` :class:`ag_uav.world.wind.Wind` (mean wind + Dryden turbulence)
  and the drag force ``F = -c_lin r - c_quad |r| r``, ``r = v - w``;
* :class:`BatchImu` -- ``N`` :class:`ag_uav.vehicle.imu.ImuSensor` (turn-on bias + random walk
  + white noise);
* :class:`BatchAttitudeError` -- ``N`` :class:`ag_uav.vehicle.imu.AttitudeError`
  (``R_hat = Exp(dtheta) R``, world-frame Gauss-Markov ``dtheta``).

Where the laws live (each law written once).  Nothing is modelled here: each law is
one compiled row function, which the per-vehicle object calls on its own one-row arrays and a
loop over rows, beside it, calls row by row --

* wind: :func:`ag_uav.world.wind.wind_row` (over :func:`~ag_uav.world.wind.gust_row`, the
  Dryden filters and their coefficient refresh), looped by :func:`~ag_uav.world.wind.wind_rows`
  and :func:`~ag_uav.world.wind.wind_drag_rows`; drag: :func:`ag_uav.world.wind.drag_axis`;
* IMU: :func:`ag_uav.vehicle.imu.imu_row` (looped by :func:`~ag_uav.vehicle.imu.imu_rows`) on
  the errors of :func:`ag_uav.vehicle.imu.imu_error_block`;
* attitude error: :func:`ag_uav.vehicle.imu.attitude_row` (looped by
  :func:`~ag_uav.vehicle.imu.attitude_rows`) on the ``dtheta`` of
  :func:`ag_uav.vehicle.imu.gauss_markov_block`.

This module adds the batch: the row state of ``N`` vehicles stacked, the refills, ``active``
and the engine's per-tick entry points (:meth:`BatchWind.step_drag`, :meth:`BatchImu.measure`,
:meth:`BatchAttitudeError.apply`).  The independent references the laws are tested against are
in ``tests/oracles/``.

Reproducibility contract
------------------------
Every vehicle keeps its **own** numpy Generator -- the one of the per-vehicle object the batch
was built from (shared, not copied).  Random numbers are drawn per vehicle, in the same blocks,
in the same order and at the same tick as the per-vehicle object draws them (a block is refilled
lazily, on the first tick that needs it, and only for a vehicle that is active that tick).  So a
vehicle's outputs depend only on its own Generator: they equal the per-vehicle object's bit for
bit (the same compiled row function on the same numbers) and are bit-identical alone or in any
batch.  The kernels (``@njit(cache=True)``, no fastmath) loop over the rows independently.

Once a batch is built from per-vehicle objects, those objects must not be stepped any more
(they share the Generators; their own state is left where it was).

Outputs are written into arrays owned by the batch and returned; they are overwritten on the
next call (copy them to keep them).  Inputs must be float64 numpy arrays of the documented
shapes; strided views (e.g. ``qpos[:, 2]``, ``qvel[:, :3]``) are fine.

``active`` (optional bool array ``(N,)``): rows that are ``False`` are not advanced -- their
state, Generator and output rows are left untouched -- so a crashed or finished mission can
sit in the batch without costing random numbers.

Memory: the draw buffers are ``N x 5120`` (wind), ``N x 4096 x 6`` (IMU) and ``N x 4096 x 3``
(attitude) float64 for the default block sizes, about 0.33 MB per vehicle.

``python -m ag_uav.vehicle.sensors_batched`` prints the per-tick cost at N = 1, 64, 256.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from ..world.wind import (
    WF_EX,
    WF_EY,
    WF_LU,
    WF_LW,
    WF_MX,
    WF_MY,
    WI_TURB,
    Wind,
    WindRow,
    drag_rows,
    refill_row,
    wind_drag_rows,
    wind_rows,
)
from .imu import (
    AttitudeError,
    ImuSensor,
    attitude_rows,
    filter_alpha,
    gauss_markov_block,
    imu_error_block,
    imu_integrate_rows,
    imu_rows,
)

__all__ = ["BatchAttitudeError", "BatchImu", "BatchWind", "drag"]

F64 = NDArray[np.float64]


# ============================================================================ classes


def _active(active: NDArray[np.bool_] | None, ones: NDArray[np.bool_]) -> NDArray[np.bool_]:
    if active is None:
        return ones
    if active.dtype != np.bool_ or active.shape != ones.shape:
        raise ValueError(f"active: need a bool array of shape {ones.shape}, got "
                         f"{active.dtype} {active.shape}")
    return active


def _nonempty(items: Sequence, what: str) -> None:
    if len(items) == 0:
        raise ValueError(f"{what}: need at least one vehicle, got an empty sequence")


def drag(v: F64, wind: F64, c_lin: F64, c_quad: F64, out: F64 | None = None) -> F64:
    """Drag force per vehicle and world axis, :func:`ag_uav.world.wind.drag_force` for the batch.

    ``F = -c_lin * r - c_quad * |r| * r`` with ``r = v - wind``; all arrays ``(N, 3)`` float64.
    Writes into ``out`` when given (``(N, 3)``) and returns it.
    """
    if out is None:
        out = np.empty((v.shape[0], 3))
    drag_rows(v, wind, c_lin, c_quad, out)
    return out


class BatchWind:
    """``N`` :class:`ag_uav.world.wind.Wind` objects stepped together (module docstring).

    Build with :meth:`from_winds`.  ``mean`` is the mean wind ``(N, 3)`` (ENU, m/s),
    ``turbulent`` a bool ``(N,)`` (False: the vehicle's wind is its mean, no draws).  Row ``i``
    of the state is ``winds[i]``'s wind row (:mod:`ag_uav.world.wind`), stepped by the same
    :func:`~ag_uav.world.wind.wind_row`.
    """

    def __init__(self, fs: F64, ist: NDArray[np.int64], buf: F64,
                 rngs: list[np.random.Generator | None]) -> None:
        self._fs = fs
        self._ist = ist
        self._buf = buf
        self._rows = tuple(WindRow(fs, ist, buf))  # wind_drag_rows' argument
        self._rngs = rngs
        n = fs.shape[0]
        self.n = n
        self._ones = np.ones(n, dtype=np.bool_)
        self.mean: F64 = np.zeros((n, 3))
        self.mean[:, 0] = fs[:, WF_MX]
        self.mean[:, 1] = fs[:, WF_MY]
        self.turbulent: NDArray[np.bool_] = ist[:, WI_TURB] != 0
        self.wind: F64 = self.mean.copy()   # last output (N, 3)
        self.force: F64 = np.zeros((n, 3))  # last drag force of step_drag (N, 3)
        self._e0: F64 = fs[:, [WF_EX, WF_EY]].copy()          # the downwind unit vectors
        self._speed: F64 = np.hypot(fs[:, WF_MX], fs[:, WF_MY])

    def turn(self, phi: F64) -> None:
        """Turn each row's mean wind (and its gusts' frame) by ``phi`` (N,) radians
        counter-clockwise from the direction it was built with (the meander of the flown
        wind's direction, :func:`ag_uav.world.forecast.meander_angles`): ``e = R(φ) e₀``,
        mean = U e."""
        c, s = np.cos(phi), np.sin(phi)
        ex = c * self._e0[:, 0] - s * self._e0[:, 1]
        ey = s * self._e0[:, 0] + c * self._e0[:, 1]
        self._fs[:, WF_EX], self._fs[:, WF_EY] = ex, ey
        self._fs[:, WF_MX], self._fs[:, WF_MY] = self._speed * ex, self._speed * ey
        self.mean[:, 0], self.mean[:, 1] = self._fs[:, WF_MX], self._fs[:, WF_MY]

    @classmethod
    def from_winds(cls, winds: Sequence[Wind]) -> BatchWind:
        """Take over ``winds`` (their current rows, copied, and their Generators, shared; do not
        step them after)."""
        _nonempty(winds, "BatchWind.from_winds")
        n = len(winds)
        rows = [w.row_state for w in winds]
        fs = np.concatenate([r.fs for r in rows])
        ist = np.concatenate([r.ist for r in rows])
        buf = np.zeros((n, max(max(r.buf.shape[1] for r in rows), 5)))
        for i, r in enumerate(rows):
            buf[i, :r.buf.shape[1]] = r.buf[0]
        rngs = [w.turbulence.rng if w.turbulence is not None else None for w in winds]
        return cls(fs, ist, buf, rngs)

    @property
    def L_u(self) -> F64:
        """Current longitudinal/lateral scale length per vehicle (m; 0 before the first step)."""
        return self._fs[:, WF_LU].copy()

    @property
    def L_w(self) -> F64:
        """Current vertical scale length per vehicle (m)."""
        return self._fs[:, WF_LW].copy()

    def _refill(self, active: NDArray[np.bool_]) -> None:
        """:func:`~ag_uav.world.wind.refill_row` for the active rows that need draws."""
        for i in np.flatnonzero(active & self.turbulent):
            refill_row(self._rngs[i], self._ist, self._buf, int(i))

    def step(self, dt: float, altitude: F64, airspeed: F64,
             active: NDArray[np.bool_] | None = None) -> F64:
        """Advance by ``dt`` and return the wind ``(N, 3)`` (ENU, m/s).

        Row ``i`` is ``winds[i].step(dt, altitude[i], airspeed[i])``; ``altitude`` and
        ``airspeed`` are ``(N,)`` float64 (height above ground, speed relative to the air for
        the frozen-turbulence time scales -- the engine passes ``max(pz, 0)`` and the
        horizontal speed relative to the *mean* wind, see :meth:`step_drag`).
        """
        act = _active(active, self._ones)
        dt = float(dt)
        while wind_rows(dt, altitude, airspeed, act, self._fs, self._ist, self._buf,
                           self.wind):
            self._refill(act)
        return self.wind

    def step_drag(self, dt: float, z: F64, v: F64, c_lin: F64, c_quad: F64,
                  active: NDArray[np.bool_] | None = None) -> tuple[F64, F64]:
        """Wind step and drag force in one kernel, as the engine needs them per tick.

        ``z`` ``(N,)``: height; ``v`` ``(N, 3)``: world velocity; ``c_lin``, ``c_quad``
        ``(N, 3)``: drag coefficients.  Uses altitude ``max(z, 0)``, airspeed
        ``|v_xy - mean_xy|`` and returns ``(wind, force)``, both ``(N, 3)``, with
        ``force = -c_lin r - c_quad |r| r``, ``r = v - wind`` (the body's ``xfrc_applied``
        force for the next control period).
        """
        act = _active(active, self._ones)
        dt = float(dt)
        while wind_drag_rows(dt, z, v, c_lin, c_quad, act, self._rows, self.wind, self.force):
            self._refill(act)
        return self.wind, self.force


class BatchImu:
    """``N`` :class:`ag_uav.vehicle.imu.ImuSensor` objects measured together (module docstring).

    ``bias0`` ``(N, 6)``: the turn-on biases (accel m/s^2, gyro rad/s).
    """

    def __init__(self, imus: Sequence[ImuSensor]) -> None:
        _nonempty(imus, "BatchImu")
        n = len(imus)
        self.n = n
        self._rngs = [s.rng for s in imus]
        self._block = np.array([s.block for s in imus], dtype=np.int64)
        self._sigma_rw = np.stack([s.sigma_rw for s in imus])
        self._sigma_white = np.stack([s.sigma_white for s in imus])
        rows = [s.row_state for s in imus]
        self._bias = np.stack([r.bias for r in rows])         # bias after the buffered block
        self.bias0: F64 = np.stack([s.bias0 for s in imus])
        width = max(int(self._block.max()), max(r.err.shape[1] for r in rows), 1)
        self._err = np.zeros((n, width, 6))
        self._ist = np.concatenate([r.ist for r in rows])      # next sample, samples buffered
        for i, r in enumerate(rows):
            self._err[i, :r.err.shape[1]] = r.err[0]
        self._ones = np.ones(n, dtype=np.bool_)
        self.f_meas: F64 = np.zeros((n, 3))
        self.w_meas: F64 = np.zeros((n, 3))
        self._filter_hz = np.array([s.cfg.filter_hz for s in imus])
        self._dt = np.array([s.dt for s in imus])
        self._alpha: F64 | None = None
        self._lp = np.concatenate([r.lp for r in rows])
        self.f_int: F64 = np.zeros((n, 3))
        self.w_int: F64 = np.zeros((n, 3))
        #: the walked bias ``b_k`` of each row's buffered block (accel m/s^2, gyro rad/s), sample
        #: k of the block at ``walked[i, k]`` (zeros before the first block; scoring truth of
        #: the INS bias states, ``ag_uav.navigation.ins_feedback``)
        self.walked: F64 = np.zeros((n, width, 6))

    @classmethod
    def from_sensors(cls, imus: Sequence[ImuSensor]) -> BatchImu:
        """Take over ``imus`` (their current state and Generators; do not use them after)."""
        return cls(imus)

    def _refill(self, active: NDArray[np.bool_]) -> None:
        """:func:`~ag_uav.vehicle.imu.imu_error_block` for the rows whose block is used up."""
        ist = self._ist
        for i in np.flatnonzero(active & (ist[:, 0] >= ist[:, 1])):
            n = int(self._block[i])
            err, self._bias[i], walked = imu_error_block(self._rngs[i], self._bias[i], n,
                                                         self._sigma_rw[i], self._sigma_white[i])
            self._err[i, :n] = err
            self.walked[i, :n] = walked
            ist[i] = 0, n

    def integrate(self, sub: F64, ia: int, ig: int, w_end: F64,
                  active: NDArray[np.bool_] | None = None) -> tuple[F64, F64]:
        """The noiseless samples of one control period, ``(f (N, 3), w (N, 3))``: the means
        of each row's filtered delta-velocity and delta-angle over the period
        (:func:`~ag_uav.vehicle.imu.imu_integrate_row`) from the physics' sub-step readings
        ``sub`` (N, nsub, nsensordata; accelerometer at ``ia``, gyro at ``ig``) and the rates
        at the period's end ``w_end`` (N, 3); hand them to :meth:`measure`."""
        act = _active(active, self._ones)
        if self._alpha is None:
            h = self._dt / sub.shape[1]
            self._alpha = np.array([filter_alpha(float(fc), float(hh))
                                    for fc, hh in zip(self._filter_hz, h, strict=True)])
        imu_integrate_rows(sub, ia, ig, w_end, act, self._alpha, self._lp, self.f_int,
                           self.w_int)
        return self.f_int, self.w_int

    def measure(self, f: F64, w: F64,
                active: NDArray[np.bool_] | None = None) -> tuple[F64, F64]:
        """Measured specific force and body rate, ``(f_meas (N, 3), w_meas (N, 3))``.

        ``f``, ``w``: MuJoCo's exact readings ``(N, 3)`` (accelerometer, gyro sensordata).
        """
        act = _active(active, self._ones)
        while imu_rows(f, w, act, self._err, self._ist, self.f_meas, self.w_meas):
            self._refill(act)
        return self.f_meas, self.w_meas


class BatchAttitudeError:
    """``N`` :class:`ag_uav.vehicle.imu.AttitudeError` objects applied together (module docstring).

    ``last`` ``(N, 3)``: the last ``dtheta`` per vehicle (rad, world x, y, z).
    """

    def __init__(self, errs: Sequence[AttitudeError]) -> None:
        _nonempty(errs, "BatchAttitudeError")
        n = len(errs)
        self.n = n
        self._rngs = [e.rng for e in errs]
        self._block = np.array([e.block for e in errs], dtype=np.int64)
        self._phi = np.array([e.phi for e in errs])
        self._sigma = np.stack([e.sigma for e in errs])
        rows = [e.row_state for e in errs]
        self._x = np.stack([r.x for r in rows])
        width = max(int(self._block.max()), max(r.dth.shape[1] for r in rows), 1)
        self._dth = np.zeros((n, width, 3))
        self._ist = np.concatenate([r.ist for r in rows])
        for i, r in enumerate(rows):
            self._dth[i, :r.dth.shape[1]] = r.dth[0]
        self.last: F64 = np.concatenate([r.last for r in rows])
        self._ones = np.ones(n, dtype=np.bool_)
        self.R_hat: F64 = np.zeros((n, 9))

    @classmethod
    def from_errors(cls, errs: Sequence[AttitudeError]) -> BatchAttitudeError:
        """Take over ``errs`` (their current state and Generators; do not use them after)."""
        return cls(errs)

    def _refill(self, active: NDArray[np.bool_]) -> None:
        """:func:`~ag_uav.vehicle.imu.gauss_markov_block` for the rows whose block is used up."""
        ist = self._ist
        for i in np.flatnonzero(active & (ist[:, 0] >= ist[:, 1])):
            n = int(self._block[i])
            x = gauss_markov_block(self._rngs[i], self._x[i].copy(), n, float(self._phi[i]),
                                   self._sigma[i])
            self._x[i] = x[-1]
            self._dth[i, :n] = x
            ist[i] = 0, n

    def apply(self, R: F64, active: NDArray[np.bool_] | None = None) -> F64:
        """``R_hat = Exp(dtheta) R`` per vehicle; ``R`` and the result are row-major ``(N, 9)``."""
        act = _active(active, self._ones)
        while attitude_rows(R, act, self._dth, self._ist, self.R_hat, self.last):
            self._refill(act)
        return self.R_hat


# ============================================================================ timing


def _timed(fn, ticks: int, warm: int = 50) -> float:
    """Mean µs per call of ``fn(k)`` over ticks ``warm..ticks``."""
    for k in range(warm):
        fn(k)
    t0 = time.perf_counter()
    for k in range(warm, ticks):
        fn(k)
    return (time.perf_counter() - t0) / (ticks - warm) * 1e6


def _bench_one(n: int, ticks: int) -> dict[str, float]:
    from ..config import ImuConfig

    def winds() -> BatchWind:
        return BatchWind.from_winds([
            Wind(3.0 + 0.01 * i, 10.0 * i, "mean", rng=np.random.default_rng(i))
            for i in range(n)])

    rng = np.random.default_rng(99)
    t = np.arange(ticks)[:, None] * 0.01
    ph = rng.random(n) * 2.0 * math.pi
    # smooth flight: the coefficient refresh fires every ~10-20 ticks per vehicle
    alt = 10.0 + 2.0 * np.sin(2.0 * math.pi * t / 20.0 + ph)
    spd = 5.0 + np.sin(2.0 * math.pi * t / 15.0 + ph)
    # worst case: altitude jumps every tick, the refresh fires every tick
    alt_jump = 5.0 + 10.0 * rng.random((ticks, n))
    vel = np.stack([spd, 0.0 * spd, 0.1 * spd], axis=2)
    cl, cq = np.full((n, 3), 0.1), np.full((n, 3), 0.02)
    res: dict[str, float] = {"N": n}
    bw = winds()
    res["wind.step"] = _timed(lambda k: bw.step(0.01, alt[k], spd[k]), ticks)
    bw2 = winds()
    res["wind.step (refresh each tick)"] = _timed(
        lambda k: bw2.step(0.01, alt_jump[k], spd[k]), ticks)
    bw3 = winds()
    res["wind.step_drag"] = _timed(lambda k: bw3.step_drag(0.01, alt[k], vel[k], cl, cq), ticks)
    cfg = ImuConfig()
    imu = BatchImu.from_sensors([ImuSensor(cfg, 100.0, i) for i in range(n)])
    f = rng.standard_normal((n, 3))
    res["imu.measure"] = _timed(lambda k: imu.measure(f, f), ticks)
    att = BatchAttitudeError.from_errors([AttitudeError(cfg, 100.0, i) for i in range(n)])
    R = np.tile(np.eye(3).ravel(), (n, 1))
    res["att.apply"] = _timed(lambda k: att.apply(R), ticks)
    return res


def _bench(ns: Sequence[int] = (1, 64, 256), ticks: int = 5000) -> list[dict[str, float]]:
    """Per-tick cost (µs per call) of each batched model at batch sizes ``ns``, block refills
    included (``ticks`` > 4096 crosses one IMU/attitude refill and several wind refills)."""
    return [_bench_one(n, ticks) for n in ns]


if __name__ == "__main__":
    rows = _bench()
    print("per-tick cost: µs per call [µs per vehicle-tick]")
    for key in rows[0]:
        if key != "N":
            print(f"{key:>32}: " + "   ".join(
                f"N={int(r['N'])}: {r[key]:8.2f} [{r[key] / r['N']:.3f}]" for r in rows))
