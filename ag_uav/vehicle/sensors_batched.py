"""Batched wind + drag, MEMS IMU and attitude-error models for the lockstep engine.

The lockstep engine advances ``N`` missions at once (leading batch axis ``N``) at the control
rate.  This module holds, for the whole batch, the per-tick sensor/disturbance models that
:func:`ag_uav.engine.missions.fly_reference` runs per vehicle:

* :class:`BatchWind` -- :class:`ag_uav.world.wind.Wind` (mean wind + Dryden turbulence, exact
  discretisation, coefficient refresh when V or h drift by ``rel_tol``) and the drag force
  ``F = -c_lin r - c_quad |r| r``, ``r = v - w`` (:func:`ag_uav.world.wind.drag_force`);
* :class:`BatchImu` -- :class:`ag_uav.vehicle.imu.ImuSensor` (turn-on bias + random walk + white
noise);
* :class:`BatchAttitudeError` -- :class:`ag_uav.vehicle.imu.AttitudeError` (``R_hat = Exp(dtheta)
R``,
  world-frame Gauss-Markov ``dtheta``).

The equations are those of the scalar classes (see their docstrings); nothing is re-modelled.

Reproducibility contract
------------------------
Every vehicle keeps its **own** numpy Generator -- the one of the scalar object the batch was
built from (shared, not copied).  Random numbers are drawn per vehicle, in the same blocks, in
the same order and at the same tick as the scalar class draws them (a block is refilled lazily,
on the first tick that needs it, and only for a vehicle that is active that tick).  So a
vehicle's outputs depend only on its own Generator: they equal the scalar class's (to rounding;
in practice bit for bit with glibc's libm) and are bit-identical alone or in any batch.  The
per-tick arithmetic runs in ``numba`` kernels (``@njit(cache=True)``, no fastmath) that loop
over the rows independently.

Once a batch is built from scalar objects, those objects must not be stepped any more (they
share the Generators; their own state is left where it was).

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
from numba import njit
from numpy.typing import NDArray

from ..world.wind import (
    H_MAX_M,
    H_MIN_M,
    V_MIN,
    Wind,
    _second_order_coeffs,
    dryden_parameters,
)
from .imu import AttitudeError, ImuSensor, _gauss_markov_block

__all__ = ["BatchAttitudeError", "BatchImu", "BatchWind", "drag"]

F64 = NDArray[np.float64]

_SQRT3_2 = math.sqrt(3.0) / 2.0

# ---- BatchWind float state columns (one row per vehicle)
_V, _H, _DT, _TOLV, _TOLH, _SU, _SW, _A, _B = range(9)
_VC = 9       # 7 coefficients (f11, f12, f21, f22, l11, l21, l22) of the lateral filter
_WC = 16      # 7 coefficients of the vertical filter
_LU, _LW, _RELTOL, _W20 = 23, 24, 25, 26
_Z = 27       # 5 filter states zu, zv1, zv2, zw1, zw2
_EX, _EY, _MX, _MY = 32, 33, 34, 35
_NF = 36
# ---- BatchWind int state columns
_I, _LEN, _TURB, _BLOCK = range(4)


# ============================================================================ numba kernels


@njit(cache=True)
def _second_order_into(theta: float, fs: np.ndarray, i: int, c: int) -> None:
    """:func:`ag_uav.world.wind._second_order_coeffs` (the same function, compiled) written into
    ``fs[i, c:c+7]``."""
    co = _second_order_coeffs(theta)
    for j in range(7):
        fs[i, c + j] = co[j]


@njit(cache=True)
def _update_row(fs: np.ndarray, i: int, dt: float, h: float, V: float) -> None:
    """:meth:`ag_uav.world.wind.DrydenTurbulence._update` for row ``i`` (h already clamped)."""
    su, sw, l_u, l_w, _ = dryden_parameters(fs[i, _W20], h)
    fs[i, _SU] = su
    fs[i, _SW] = sw
    fs[i, _LU] = l_u
    fs[i, _LW] = l_w
    theta_u = V * dt / l_u
    fs[i, _A] = math.exp(-theta_u)
    fs[i, _B] = math.sqrt(-math.expm1(-2.0 * theta_u))
    _second_order_into(theta_u, fs, i, _VC)
    _second_order_into(V * dt / l_w, fs, i, _WC)
    fs[i, _V] = V
    fs[i, _H] = h
    fs[i, _DT] = dt
    fs[i, _TOLV] = fs[i, _RELTOL] * V
    fs[i, _TOLH] = fs[i, _RELTOL] * h


@njit(cache=True)
def _wind_row(fs: np.ndarray, ist: np.ndarray, buf: np.ndarray, i: int, dt: float,
              altitude: float, airspeed: float, out: np.ndarray) -> None:
    """:meth:`ag_uav.world.wind.Wind.step` for row ``i`` (the buffer holds >= 5 unread normals)."""
    if ist[i, _TURB] == 0:
        out[i, 0] = fs[i, _MX]
        out[i, 1] = fs[i, _MY]
        out[i, 2] = 0.0
        return
    V = airspeed if airspeed > V_MIN else V_MIN
    h = altitude if altitude > H_MIN_M else H_MIN_M
    if h > H_MAX_M:
        h = H_MAX_M
    if (abs(V - fs[i, _V]) > fs[i, _TOLV] or abs(h - fs[i, _H]) > fs[i, _TOLH]
            or dt != fs[i, _DT]):
        _update_row(fs, i, dt, h, V)
    k = ist[i, _I]
    n0 = buf[i, k]
    n1 = buf[i, k + 1]
    n2 = buf[i, k + 2]
    n3 = buf[i, k + 3]
    n4 = buf[i, k + 4]
    ist[i, _I] = k + 5
    zu = fs[i, _A] * fs[i, _Z] + fs[i, _B] * n0
    z1 = fs[i, _Z + 1]
    z2 = fs[i, _Z + 2]
    c = _VC
    zv1 = fs[i, c] * z1 + fs[i, c + 1] * z2 + fs[i, c + 4] * n1
    zv2 = fs[i, c + 2] * z1 + fs[i, c + 3] * z2 + fs[i, c + 5] * n1 + fs[i, c + 6] * n2
    z1 = fs[i, _Z + 3]
    z2 = fs[i, _Z + 4]
    c = _WC
    zw1 = fs[i, c] * z1 + fs[i, c + 1] * z2 + fs[i, c + 4] * n3
    zw2 = fs[i, c + 2] * z1 + fs[i, c + 3] * z2 + fs[i, c + 5] * n3 + fs[i, c + 6] * n4
    fs[i, _Z] = zu
    fs[i, _Z + 1] = zv1
    fs[i, _Z + 2] = zv2
    fs[i, _Z + 3] = zw1
    fs[i, _Z + 4] = zw2
    su = fs[i, _SU]
    u = su * zu
    v = su * (0.5 * zv1 + _SQRT3_2 * zv2)
    w = fs[i, _SW] * (0.5 * zw1 + _SQRT3_2 * zw2)
    ex = fs[i, _EX]
    ey = fs[i, _EY]
    out[i, 0] = fs[i, _MX] + u * ex - v * ey
    out[i, 1] = fs[i, _MY] + u * ey + v * ex
    out[i, 2] = w


@njit(cache=True)
def _wind_need(active: np.ndarray, ist: np.ndarray) -> int:
    """Number of active turbulent rows whose buffer cannot serve this tick."""
    need = 0
    for i in range(ist.shape[0]):
        if active[i] and ist[i, _TURB] != 0 and ist[i, _I] + 5 > ist[i, _LEN]:
            need += 1
    return need


@njit(cache=True)
def _wind_kernel(dt: float, altitude: np.ndarray, airspeed: np.ndarray, active: np.ndarray,
                 fs: np.ndarray, ist: np.ndarray, buf: np.ndarray, out: np.ndarray) -> int:
    need = _wind_need(active, ist)
    if need:
        return need
    for i in range(fs.shape[0]):
        if active[i]:
            _wind_row(fs, ist, buf, i, dt, altitude[i], airspeed[i], out)
    return 0


@njit(cache=True)
def _wind_drag_kernel(dt: float, z: np.ndarray, v: np.ndarray, c_lin: np.ndarray,
                      c_quad: np.ndarray, active: np.ndarray, fs: np.ndarray, ist: np.ndarray,
                      buf: np.ndarray, out: np.ndarray, force: np.ndarray) -> int:
    need = _wind_need(active, ist)
    if need:
        return need
    for i in range(fs.shape[0]):
        if not active[i]:
            continue
        vx = v[i, 0]
        vy = v[i, 1]
        vz = v[i, 2]
        pz = z[i]
        ax = vx - fs[i, _MX]
        ay = vy - fs[i, _MY]
        _wind_row(fs, ist, buf, i, dt, pz if pz > 0.0 else 0.0, math.sqrt(ax * ax + ay * ay),
                  out)
        rx = vx - out[i, 0]
        ry = vy - out[i, 1]
        rz = vz - out[i, 2]
        force[i, 0] = -c_lin[i, 0] * rx - c_quad[i, 0] * abs(rx) * rx
        force[i, 1] = -c_lin[i, 1] * ry - c_quad[i, 1] * abs(ry) * ry
        force[i, 2] = -c_lin[i, 2] * rz - c_quad[i, 2] * abs(rz) * rz
    return 0


@njit(cache=True)
def _drag_kernel(v: np.ndarray, wind: np.ndarray, c_lin: np.ndarray, c_quad: np.ndarray,
                 out: np.ndarray) -> None:
    for i in range(v.shape[0]):
        for j in range(3):
            r = v[i, j] - wind[i, j]
            out[i, j] = -c_lin[i, j] * r - c_quad[i, j] * abs(r) * r


@njit(cache=True)
def _rows_need(active: np.ndarray, ist: np.ndarray) -> int:
    """Number of active rows whose sample buffer is used up (ist[:, 0] = next, [:, 1] = len)."""
    need = 0
    for i in range(ist.shape[0]):
        if active[i] and ist[i, 0] >= ist[i, 1]:
            need += 1
    return need


@njit(cache=True)
def _imu_kernel(f: np.ndarray, w: np.ndarray, active: np.ndarray, err: np.ndarray,
                ist: np.ndarray, f_out: np.ndarray, w_out: np.ndarray) -> int:
    need = _rows_need(active, ist)
    if need:
        return need
    for i in range(f.shape[0]):
        if not active[i]:
            continue
        k = ist[i, 0]
        ist[i, 0] = k + 1
        f_out[i, 0] = f[i, 0] + err[i, k, 0]
        f_out[i, 1] = f[i, 1] + err[i, k, 1]
        f_out[i, 2] = f[i, 2] + err[i, k, 2]
        w_out[i, 0] = w[i, 0] + err[i, k, 3]
        w_out[i, 1] = w[i, 1] + err[i, k, 4]
        w_out[i, 2] = w[i, 2] + err[i, k, 5]
    return 0


@njit(cache=True)
def _att_kernel(R: np.ndarray, active: np.ndarray, dth: np.ndarray, ist: np.ndarray,
                out: np.ndarray, last: np.ndarray) -> int:
    need = _rows_need(active, ist)
    if need:
        return need
    for i in range(R.shape[0]):
        if not active[i]:
            continue
        k = ist[i, 0]
        ist[i, 0] = k + 1
        x0 = dth[i, k, 0]
        x1 = dth[i, k, 1]
        x2 = dth[i, k, 2]
        last[i, 0] = x0
        last[i, 1] = x1
        last[i, 2] = x2
        # Exp(dtheta) by Rodrigues, as AttitudeError._refill
        th = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        ths = th if th > 1e-12 else 1.0
        kx = x0 / ths
        ky = x1 / ths
        kz = x2 / ths
        s = math.sin(th)
        c = math.cos(th)
        vv = 1.0 - c
        r0 = c + kx * kx * vv
        r1 = kx * ky * vv - kz * s
        r2 = kx * kz * vv + ky * s
        r3 = ky * kx * vv + kz * s
        r4 = c + ky * ky * vv
        r5 = ky * kz * vv - kx * s
        r6 = kz * kx * vv - ky * s
        r7 = kz * ky * vv + kx * s
        r8 = c + kz * kz * vv
        e0 = R[i, 0]
        e1 = R[i, 1]
        e2 = R[i, 2]
        e3 = R[i, 3]
        e4 = R[i, 4]
        e5 = R[i, 5]
        e6 = R[i, 6]
        e7 = R[i, 7]
        e8 = R[i, 8]
        out[i, 0] = r0 * e0 + r1 * e3 + r2 * e6
        out[i, 1] = r0 * e1 + r1 * e4 + r2 * e7
        out[i, 2] = r0 * e2 + r1 * e5 + r2 * e8
        out[i, 3] = r3 * e0 + r4 * e3 + r5 * e6
        out[i, 4] = r3 * e1 + r4 * e4 + r5 * e7
        out[i, 5] = r3 * e2 + r4 * e5 + r5 * e8
        out[i, 6] = r6 * e0 + r7 * e3 + r8 * e6
        out[i, 7] = r6 * e1 + r7 * e4 + r8 * e7
        out[i, 8] = r6 * e2 + r7 * e5 + r8 * e8
    return 0


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
    _drag_kernel(v, wind, c_lin, c_quad, out)
    return out


class BatchWind:
    """``N`` :class:`ag_uav.world.wind.Wind` objects stepped together (module docstring).

    Build with :meth:`from_winds`.  ``mean`` is the mean wind ``(N, 3)`` (ENU, m/s),
    ``turbulent`` a bool ``(N,)`` (False: the vehicle's wind is its mean, no draws).
    """

    def __init__(self, fs: F64, ist: NDArray[np.int64], buf: F64,
                 rngs: list[np.random.Generator | None]) -> None:
        self._fs = fs
        self._ist = ist
        self._buf = buf
        self._rngs = rngs
        n = fs.shape[0]
        self.n = n
        self._ones = np.ones(n, dtype=np.bool_)
        self.mean: F64 = np.zeros((n, 3))
        self.mean[:, 0] = fs[:, _MX]
        self.mean[:, 1] = fs[:, _MY]
        self.turbulent: NDArray[np.bool_] = ist[:, _TURB] != 0
        self.wind: F64 = self.mean.copy()   # last output (N, 3)
        self.force: F64 = np.zeros((n, 3))  # last drag force of step_drag (N, 3)

    @classmethod
    def from_winds(cls, winds: Sequence[Wind]) -> BatchWind:
        """Take over ``winds`` (their current state and Generators; do not step them after)."""
        _nonempty(winds, "BatchWind.from_winds")
        n = len(winds)
        fs = np.zeros((n, _NF))
        ist = np.zeros((n, 4), dtype=np.int64)
        rngs: list[np.random.Generator | None] = []
        blocks = [w.turbulence._block if w.turbulence is not None else 0 for w in winds]
        buf = np.zeros((n, max(max(blocks), 5)))
        for i, w in enumerate(winds):
            fs[i, _EX], fs[i, _EY] = w._ex, w._ey
            fs[i, _MX], fs[i, _MY] = w.mean[0], w.mean[1]
            fs[i, _W20] = w.w20
            t = w.turbulence
            if t is None:
                rngs.append(None)
                continue
            rngs.append(t.rng)
            ist[i, _TURB] = 1
            ist[i, _BLOCK] = t._block
            fs[i, _RELTOL] = t.rel_tol
            fs[i, _V], fs[i, _H], fs[i, _DT] = t._V, t._h, t._dt
            fs[i, _TOLV], fs[i, _TOLH] = t._tolV, t._toll
            fs[i, _SU], fs[i, _SW], fs[i, _A], fs[i, _B] = t._su, t._sw, t._a, t._b
            fs[i, _VC:_VC + 7] = t._v_coef
            fs[i, _WC:_WC + 7] = t._w_coef
            fs[i, _LU], fs[i, _LW] = t.L_u, t.L_w
            fs[i, _Z:_Z + 5] = (t._zu, t._zv1, t._zv2, t._zw1, t._zw2)
            m = len(t._buf)
            if m > buf.shape[1]:
                buf = np.concatenate([buf, np.zeros((n, m - buf.shape[1]))], axis=1)
            buf[i, :m] = t._buf
            ist[i, _I], ist[i, _LEN] = t._i, m
        return cls(fs, ist, buf, rngs)

    @property
    def L_u(self) -> F64:
        """Current longitudinal/lateral scale length per vehicle (m; 0 before the first step)."""
        return self._fs[:, _LU].copy()

    @property
    def L_w(self) -> F64:
        """Current vertical scale length per vehicle (m)."""
        return self._fs[:, _LW].copy()

    def _refill(self, active: NDArray[np.bool_]) -> None:
        """DrydenTurbulence._refill for the active turbulent rows whose buffer is used up."""
        ist = self._ist
        rows = np.flatnonzero(active & self.turbulent & (ist[:, _I] + 5 > ist[:, _LEN]))
        for i in rows:
            m = int(ist[i, _BLOCK])
            self._buf[i, :m] = self._rngs[i].standard_normal(m)
            ist[i, _I] = 0
            ist[i, _LEN] = m

    def step(self, dt: float, altitude: F64, airspeed: F64,
             active: NDArray[np.bool_] | None = None) -> F64:
        """Advance by ``dt`` and return the wind ``(N, 3)`` (ENU, m/s).

        Row ``i`` is ``winds[i].step(dt, altitude[i], airspeed[i])``; ``altitude`` and
        ``airspeed`` are ``(N,)`` float64 (height above ground, speed relative to the air for
        the frozen-turbulence time scales -- ``fly_reference`` passes ``max(pz, 0)`` and the
        horizontal speed relative to the *mean* wind).
        """
        act = _active(active, self._ones)
        dt = float(dt)
        while _wind_kernel(dt, altitude, airspeed, act, self._fs, self._ist, self._buf,
                           self.wind):
            self._refill(act)
        return self.wind

    def step_drag(self, dt: float, z: F64, v: F64, c_lin: F64, c_quad: F64,
                  active: NDArray[np.bool_] | None = None) -> tuple[F64, F64]:
        """Wind step and drag force in one kernel, exactly as ``fly_reference`` does per tick.

        ``z`` ``(N,)``: height; ``v`` ``(N, 3)``: world velocity; ``c_lin``, ``c_quad``
        ``(N, 3)``: drag coefficients.  Uses altitude ``max(z, 0)``, airspeed
        ``|v_xy - mean_xy|`` and returns ``(wind, force)``, both ``(N, 3)``, with
        ``force = -c_lin r - c_quad |r| r``, ``r = v - wind`` (the body's ``xfrc_applied``
        force for the next control period).
        """
        act = _active(active, self._ones)
        dt = float(dt)
        while _wind_drag_kernel(dt, z, v, c_lin, c_quad, act, self._fs, self._ist, self._buf,
                                self.wind, self.force):
            self._refill(act)
        return self.wind, self.force

    def _step_numpy(self, dt: float, altitude: F64, airspeed: F64,
                    active: NDArray[np.bool_] | None = None) -> F64:
        """The same step with numpy array operations instead of the kernel (for comparison;
        coefficient refreshes are done per row in Python)."""
        act = _active(active, self._ones)
        fs, ist = self._fs, self._ist
        self._refill(act)
        V = np.where(airspeed > V_MIN, airspeed, V_MIN)
        h = np.minimum(np.where(altitude > H_MIN_M, altitude, H_MIN_M), H_MAX_M)
        run = act & self.turbulent
        upd = run & ((np.abs(V - fs[:, _V]) > fs[:, _TOLV]) | (np.abs(h - fs[:, _H])
                                                               > fs[:, _TOLH])
                     | (dt != fs[:, _DT]))
        for i in np.flatnonzero(upd):
            su, sw, l_u, l_w, _ = dryden_parameters(fs[i, _W20], float(h[i]))
            theta_u = V[i] * dt / l_u
            fs[i, [_SU, _SW, _LU, _LW]] = su, sw, l_u, l_w
            fs[i, _A] = math.exp(-theta_u)
            fs[i, _B] = math.sqrt(-math.expm1(-2.0 * theta_u))
            fs[i, _VC:_VC + 7] = _second_order_coeffs(theta_u)
            fs[i, _WC:_WC + 7] = _second_order_coeffs(V[i] * dt / l_w)
            fs[i, [_V, _H, _DT]] = V[i], h[i], dt
            fs[i, _TOLV] = fs[i, _RELTOL] * V[i]
            fs[i, _TOLH] = fs[i, _RELTOL] * h[i]
        rows = np.flatnonzero(run)
        k = ist[rows, _I]
        nn = self._buf[rows[:, None], k[:, None] + np.arange(5)]
        ist[rows, _I] = k + 5
        f = fs[rows]
        z = f[:, _Z:_Z + 5]
        vc, wc = f[:, _VC:_VC + 7], f[:, _WC:_WC + 7]
        zu = f[:, _A] * z[:, 0] + f[:, _B] * nn[:, 0]
        zv1 = vc[:, 0] * z[:, 1] + vc[:, 1] * z[:, 2] + vc[:, 4] * nn[:, 1]
        zv2 = vc[:, 2] * z[:, 1] + vc[:, 3] * z[:, 2] + vc[:, 5] * nn[:, 1] + vc[:, 6] * nn[:, 2]
        zw1 = wc[:, 0] * z[:, 3] + wc[:, 1] * z[:, 4] + wc[:, 4] * nn[:, 3]
        zw2 = wc[:, 2] * z[:, 3] + wc[:, 3] * z[:, 4] + wc[:, 5] * nn[:, 3] + wc[:, 6] * nn[:, 4]
        fs[rows, _Z:_Z + 5] = np.stack([zu, zv1, zv2, zw1, zw2], axis=1)
        su = f[:, _SU]
        u = su * zu
        v = su * (0.5 * zv1 + _SQRT3_2 * zv2)
        w = f[:, _SW] * (0.5 * zw1 + _SQRT3_2 * zw2)
        ex, ey = f[:, _EX], f[:, _EY]
        out = self.wind
        out[rows, 0] = f[:, _MX] + u * ex - v * ey
        out[rows, 1] = f[:, _MY] + u * ey + v * ex
        out[rows, 2] = w
        calm = act & ~self.turbulent
        out[calm, :2] = self.mean[calm, :2]
        out[calm, 2] = 0.0
        return out


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
        self._bias = np.stack([s._bias for s in imus])        # bias after the buffered block
        self.bias0: F64 = np.stack([s.bias0 for s in imus])
        width = max(int(self._block.max()), max(len(s._err) for s in imus), 1)
        self._err = np.zeros((n, width, 6))
        self._ist = np.zeros((n, 2), dtype=np.int64)           # next sample, samples buffered
        for i, s in enumerate(imus):
            if s._err:
                self._err[i, :len(s._err)] = s._err
            self._ist[i] = s._i, len(s._err)
        self._ones = np.ones(n, dtype=np.bool_)
        self.f_meas: F64 = np.zeros((n, 3))
        self.w_meas: F64 = np.zeros((n, 3))

    @classmethod
    def from_sensors(cls, imus: Sequence[ImuSensor]) -> BatchImu:
        """Take over ``imus`` (their current state and Generators; do not use them after)."""
        return cls(imus)

    def _refill(self, active: NDArray[np.bool_]) -> None:
        """ImuSensor._refill (same draws and operations) for the rows that need it."""
        ist = self._ist
        for i in np.flatnonzero(active & (ist[:, 0] >= ist[:, 1])):
            n = int(self._block[i])
            rng = self._rngs[i]
            steps = rng.standard_normal((n, 6)) * self._sigma_rw[i]
            bias = self._bias[i] + np.cumsum(steps, axis=0) - steps
            self._bias[i] = bias[-1] + steps[-1]
            white = rng.standard_normal((n, 6)) * self._sigma_white[i]
            self._err[i, :n] = bias + white
            ist[i] = 0, n

    def measure(self, f: F64, w: F64,
                active: NDArray[np.bool_] | None = None) -> tuple[F64, F64]:
        """Measured specific force and body rate, ``(f_meas (N, 3), w_meas (N, 3))``.

        ``f``, ``w``: MuJoCo's exact readings ``(N, 3)`` (accelerometer, gyro sensordata).
        """
        act = _active(active, self._ones)
        while _imu_kernel(f, w, act, self._err, self._ist, self.f_meas, self.w_meas):
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
        self._x = np.stack([e._x for e in errs])
        width = max(int(self._block.max()), max(len(e._rot) for e in errs), 1)
        self._dth = np.zeros((n, width, 3))
        self._ist = np.zeros((n, 2), dtype=np.int64)
        for i, e in enumerate(errs):
            if e._rot:
                self._dth[i, :len(e._rot)] = e._dth
            self._ist[i] = e._i, len(e._rot)
        self.last: F64 = np.stack([np.asarray(e.last, dtype=float) for e in errs])
        self._ones = np.ones(n, dtype=np.bool_)
        self.R_hat: F64 = np.zeros((n, 9))

    @classmethod
    def from_errors(cls, errs: Sequence[AttitudeError]) -> BatchAttitudeError:
        """Take over ``errs`` (their current state and Generators; do not use them after)."""
        return cls(errs)

    def _refill(self, active: NDArray[np.bool_]) -> None:
        ist = self._ist
        for i in np.flatnonzero(active & (ist[:, 0] >= ist[:, 1])):
            n = int(self._block[i])
            x = _gauss_markov_block(self._rngs[i], self._x[i].copy(), n, float(self._phi[i]),
                                    self._sigma[i])
            self._x[i] = x[-1]
            self._dth[i, :n] = x
            ist[i] = 0, n

    def apply(self, R: F64, active: NDArray[np.bool_] | None = None) -> F64:
        """``R_hat = Exp(dtheta) R`` per vehicle; ``R`` and the result are row-major ``(N, 9)``."""
        act = _active(active, self._ones)
        while _att_kernel(R, act, self._dth, self._ist, self.R_hat, self.last):
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
    bw4 = winds()
    res["wind numpy"] = _timed(lambda k: bw4._step_numpy(0.01, alt[k], spd[k]), ticks)
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
