"""Wind model: steady mean wind plus Dryden turbulence (MIL-F-8785C, low altitude).

Units and frames
----------------
* All public inputs and outputs are SI: metres, seconds, m/s.  Internally the MIL-F-8785C
  low-altitude formulas are evaluated with the height in **feet**, exactly as the standard writes
  them, and the resulting scale lengths are converted back to metres.
* World frame is ENU: x = East, y = North, z = Up.
* Wind direction follows the **meteorological "from" convention**: ``direction_deg`` is the compass
  bearing the wind blows FROM, measured clockwise from true north (0 deg = from the north, i.e. the
  air moves towards the south; 90 deg = from the east, air moves towards the west).  The mean wind
  velocity in ENU is therefore ``U * (-sin(d), -cos(d), 0)``.
* Dryden gust components ``(u, v, w)`` live in the mean-wind frame: ``u`` along the direction the
  mean wind blows (downwind), ``w`` up, ``v`` horizontal completing a right-handed frame
  (``e_v = e_w x e_u``, i.e. 90 deg to the left of downwind).

Dryden model (MIL-F-8785C, low altitude, h in ft, 10 ft < h < 1000 ft)
-------------------------------------------------------------------
    L_w = h,            L_u = L_v = h / (0.177 + 0.000823 h)^1.2
    sigma_w = 0.1 W20,  sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4

``W20`` is the mean wind speed at 20 ft; sigma is in the same unit as W20 (m/s here).

* Longitudinal (first order, H_u(s) = sigma_u sqrt(2 L_u/(pi V)) / (1 + (L_u/V) s)), sampled
  exactly:
  ``u_{k+1} = a u_k + sigma_u sqrt(1 - a^2) n_k``, ``a = exp(-V dt / L_u)``.
* Lateral and vertical (second order,
  H(s) = sigma sqrt(L/(pi V)) (1 + sqrt(3) (L/V) s) / (1 + (L/V) s)^2): realised as a 2-state
  linear SDE, discretised exactly (matrix exponential; the state transition has the closed form
  ``e^{-theta} (I + theta N)`` with ``theta = V dt / L`` and nilpotent ``N``), in coordinates in
  which the stationary state covariance is the identity.  The exact discrete process-noise
  covariance is then ``Q = I - Phi Phi^T`` and the output ``sigma (z1/2 + sqrt(3)/2 z2)`` has
  stationary std exactly ``sigma`` and autocorrelation ``exp(-s)(1 - s/2)``, ``s = V tau / L`` --
  the Dryden lateral/vertical correlation function.
* ``V = max(airspeed, 1 m/s)`` (Taylor's frozen-turbulence hypothesis breaks down at hover; the
  floor keeps the time constants finite) and ``h`` is clamped to [3 m, 1000 ft] (the validity
  range of the low-altitude model; above 1000 ft the formulas are not monotone).

Intensity presets (``Wind(turbulence=...)``)
-------------------------------------------
``"light" | "moderate" | "severe"`` are the MIL-F-8785C values W20 = 15 / 30 / 45 kt
(7.7 / 15.4 / 23.2 m/s).  They are meant for manned aircraft: for a spray drone at 3 m they give
sigma_u = 1.5 / 3.0 / 4.5 m/s, i.e. multi-m/s gusts, regardless of the mean wind.
``"mean"`` ties the intensity to the configured mean wind, W20 = ``mean_speed`` (so sigma_w = 10 %
of the mean wind and sigma_u ~ 20 % at 3 m, 14 % at 30 m), which is the physically consistent choice
for a low-flying drone and the recommended default when turbulence is wanted.  A float gives an
explicit W20 in m/s; ``"none"`` (or 0) disables turbulence.

Where the law lives (each law written once)
-------------------------------------------
One vehicle's wind is one **row** of state: ``fs[i]`` (float columns :data:`WIND_ROW`: the
cached discretisation, the five filter states, the mean wind and its direction), ``ist[i]`` (int
columns :data:`WIND_INTS`: read position and length of the draw buffer, turbulence on, block
size) and ``buf[i]`` (the buffered standard normals).  The per-tick law is :func:`wind_row`
(mean wind + rotated gusts) over :func:`gust_row` (clamps, coefficient refresh by
:func:`_refresh_row` when V or h drift by more than ``rel_tol`` relative or dt changes, the exact
discretised filters), numba-compiled (``cache=True``, no fastmath).  :meth:`Wind.step` and
:meth:`DrydenTurbulence.step` call them on their own one-row arrays (a batch of one);
:class:`ag_uav.vehicle.sensors_batched.BatchWind` runs the loops over rows below
(:func:`wind_rows`, :func:`wind_drag_rows`), which call the same functions.  The
drag law is :func:`drag_axis` (one axis), used by :func:`drag_force` and the batch kernels.
Gaussian numbers come from the vehicle's Generator in blocks of ``block`` (5 per tick, refilled
by :func:`refill_row` only when fewer than 5 are left), so a vehicle's wind depends only on its
Generator.  The independent reference (plain Python, from the formulas above) is
``tests/oracles/wind_ref.py``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from numkit import Layout, X, Y, Z

from .._jit import njit, register_jitable

__all__ = [
    "FT_PER_M",
    "KNOT",
    "TURBULENCE_PRESETS_W20",
    "DrydenTurbulence",
    "Wind",
    "WindRow",
    "drag_axis",
    "drag_force",
    "dryden_parameters",
    "drag_rows",
    "gust_row",
    "refill_row",
    "wind_drag_rows",
    "wind_row",
    "wind_rows",
]

M_PER_FT = 0.3048
FT_PER_M = 1.0 / M_PER_FT
KNOT = 1852.0 / 3600.0  # m/s per knot

#: MIL-F-8785C low-altitude W20 (wind speed at 20 ft) for the named intensities, in m/s.
TURBULENCE_PRESETS_W20: dict[str, float] = {
    "none": 0.0,
    "light": 15.0 * KNOT,
    "moderate": 30.0 * KNOT,
    "severe": 45.0 * KNOT,
}

H_MIN_M = 3.0
H_MAX_M = 1000.0 * M_PER_FT
V_MIN = 1.0
_SQRT3_2 = math.sqrt(3.0) / 2.0

#: the float columns of a wind row ``fs[i]`` (one row per vehicle): the cached discretisation
#: (V, h, dt, the tolerances on V and h, σ_u, σ_w, a = e^−θu, b = √(1 − e^−2θu)), the
#: :data:`FILTER2` coefficients of the lateral (vc) and vertical (wc) filters, L_u, L_w, rel_tol,
#: W20, the five filter states (unit stationary variance), the downwind unit vector and the mean
#: wind (ENU)
WIND_ROW = Layout("v h dt tolv tolh su sw a b vc:7 wc:7 lu lw reltol w20 zu zv1 zv2 zw1 zw2 "
                  "ex ey mx my")
#: the coefficients of an exactly discretised 2nd-order filter, z' = F z + L n
#: (:func:`_second_order_coeffs`)
FILTER2 = Layout("f11 f12 f21 f22 l11 l21 l22")
#: the int columns of ``ist[i]``: next unread normal, normals buffered, turbulence on, block size
WIND_INTS = Layout("i len turb block")
#: the standard normals one tick reads, in buffer order: one for u, two for v, two for w
DRAWS = Layout("nu nv1 nv2 nw1 nw2")
W, F2, WI, D = WIND_ROW.at, FILTER2.at, WIND_INTS.at, DRAWS.at
WF_N, WI_N = WIND_ROW.size, WIND_INTS.size
# (the columns :mod:`ag_uav.vehicle.sensors_batched` reads, by name)
WF_EX, WF_EY, WF_MX, WF_MY, WF_LU, WF_LW = W.EX, W.EY, W.MX, W.MY, W.LU, W.LW
WI_TURB = WI.TURB


@register_jitable
def dryden_parameters(w20: float, altitude_m: float) -> tuple[float, float, float, float, float]:
    """MIL-F-8785C low-altitude Dryden parameters.

    Args:
        w20: wind speed at 20 ft (m/s; sigma comes out in the same unit).
        altitude_m: height above ground in metres (clamped to [3 m, 1000 ft]).

    Returns:
        ``(sigma_u, sigma_w, L_u_m, L_w_m, h_used_m)``; sigma_v = sigma_u and L_v = L_u.
    """
    h_m = min(max(altitude_m, H_MIN_M), H_MAX_M)
    h = h_m * FT_PER_M
    base = 0.177 + 0.000823 * h
    sigma_w = 0.1 * w20
    sigma_u = sigma_w / base**0.4
    l_u_ft = h / base**1.2
    return sigma_u, sigma_w, l_u_ft * M_PER_FT, h * M_PER_FT, h_m


@register_jitable
def _p3(x: float) -> float:
    """Regularised lower incomplete gamma P(3, x) = 1 - e^{-x}(1 + x + x^2/2), cancellation-free."""
    if x < 0.5:
        term = x * x * x / 6.0
        s = term
        k = 3
        while term > 1e-18 * s:
            k += 1
            term *= x / k
            s += term
        return math.exp(-x) * s
    return 1.0 - math.exp(-x) * (1.0 + x + 0.5 * x * x)


@register_jitable
def _second_order_coeffs(theta: float) -> tuple[float, float, float, float, float, float, float]:
    """Exact discretisation of the normalised 2nd-order Dryden state for step theta = V dt / L.

    Returns (f11, f12, f21, f22, l11, l21, l22): z' = F z + L n with L lower-triangular,
    n ~ N(0, I), stationary cov(z) = I.
    """
    e = math.exp(-theta)
    f11 = e * (1.0 + theta)
    f12 = e * theta
    f21 = -f12
    f22 = e * (1.0 - theta)
    e2 = e * e
    x = 2.0 * theta
    q11 = _p3(x)
    q12 = 2.0 * theta * theta * e2
    q22 = -math.expm1(-x) + e2 * (x - 2.0 * theta * theta)
    l11 = math.sqrt(q11)
    l21 = q12 / l11
    l22 = math.sqrt(max(q22 - l21 * l21, 0.0))
    return f11, f12, f21, f22, l11, l21, l22


@register_jitable
def drag_axis(r: float, c_lin: float, c_quad: float) -> float:
    """Drag on one world axis, ``F = -c_lin r - c_quad |r| r`` (``r``: velocity relative to the
    air on that axis; N s/m and N s^2/m^2)."""
    return -c_lin * r - c_quad * abs(r) * r


# ============================================================================ the row law


@njit(cache=True)
def _refresh_row(fs: np.ndarray, i: int, dt: float, h: float, V: float) -> None:
    """Recompute row ``i``'s cached discretisation at (dt, h, V) (h, V already clamped)."""
    su, sw, l_u, l_w, _ = dryden_parameters(fs[i, W.W20], h)
    fs[i, W.SU] = su
    fs[i, W.SW] = sw
    fs[i, W.LU] = l_u
    fs[i, W.LW] = l_w
    theta_u = V * dt / l_u
    fs[i, W.A] = math.exp(-theta_u)  # a = e^−θu
    fs[i, W.B] = math.sqrt(-math.expm1(-2.0 * theta_u))  # b = √(1 − e^−2θu)
    co = _second_order_coeffs(theta_u)  # L_v = L_u
    for j in range(F2.SIZE):
        fs[i, W.VC + j] = co[j]
    co = _second_order_coeffs(V * dt / l_w)
    for j in range(F2.SIZE):
        fs[i, W.WC + j] = co[j]
    fs[i, W.V] = V
    fs[i, W.H] = h
    fs[i, W.DT] = dt
    fs[i, W.TOLV] = fs[i, W.RELTOL] * V
    fs[i, W.TOLH] = fs[i, W.RELTOL] * h


@njit(cache=True, inline="always")
def _second_order_step(fs: np.ndarray, i: int, c: int, z1: float, z2: float, na: float,
                       nb: float) -> tuple[float, float]:
    """One step of a second-order Dryden filter whose coefficients sit at ``c`` of row ``i``:
    (z1, z2) ← F (z1, z2) + L (na, nb), L lower-triangular."""
    y1 = fs[i, c + F2.F11] * z1 + fs[i, c + F2.F12] * z2 + fs[i, c + F2.L11] * na
    y2 = (fs[i, c + F2.F21] * z1 + fs[i, c + F2.F22] * z2 + fs[i, c + F2.L21] * na
          + fs[i, c + F2.L22] * nb)
    return y1, y2


@njit(cache=True)
def gust_row(fs: np.ndarray, ist: np.ndarray, buf: np.ndarray, i: int, dt: float,
             altitude: float, airspeed: float) -> tuple[float, float, float]:
    """Advance row ``i``'s Dryden filters by ``dt``; the gust ``(u, v, w)`` (m/s, mean-wind frame).

    Clamps V to >= 1 m/s and h to [3 m, 1000 ft], refreshes the discretisation when V or h
    moved by more than ``rel_tol`` relative or dt changed, and reads the next 5 normals of
    ``buf[i]`` (there must be 5 unread: :func:`refill_row` first).
    """
    V = airspeed if airspeed > V_MIN else V_MIN
    h = altitude if altitude > H_MIN_M else H_MIN_M
    if h > H_MAX_M:
        h = H_MAX_M
    if (abs(V - fs[i, W.V]) > fs[i, W.TOLV] or abs(h - fs[i, W.H]) > fs[i, W.TOLH]
            or dt != fs[i, W.DT]):
        _refresh_row(fs, i, dt, h, V)
    k = ist[i, WI.I]
    n0 = buf[i, k + D.NU]
    n1 = buf[i, k + D.NV1]
    n2 = buf[i, k + D.NV2]
    n3 = buf[i, k + D.NW1]
    n4 = buf[i, k + D.NW2]
    ist[i, WI.I] = k + D.SIZE
    zu = fs[i, W.A] * fs[i, W.ZU] + fs[i, W.B] * n0  # zu ← a zu + b n
    zv1, zv2 = _second_order_step(fs, i, W.VC, fs[i, W.ZV1], fs[i, W.ZV2], n1, n2)
    zw1, zw2 = _second_order_step(fs, i, W.WC, fs[i, W.ZW1], fs[i, W.ZW2], n3, n4)
    fs[i, W.ZU] = zu
    fs[i, W.ZV1] = zv1
    fs[i, W.ZV2] = zv2
    fs[i, W.ZW1] = zw1
    fs[i, W.ZW2] = zw2
    su = fs[i, W.SU]
    # (u, v, w) = (σu zu, σu (½ zv1 + √3/2 zv2), σw (½ zw1 + √3/2 zw2))
    return (su * zu, su * (0.5 * zv1 + _SQRT3_2 * zv2),
            fs[i, W.SW] * (0.5 * zw1 + _SQRT3_2 * zw2))


@njit(cache=True)
def wind_row(fs: np.ndarray, ist: np.ndarray, buf: np.ndarray, i: int, dt: float,
             altitude: float, airspeed: float) -> tuple[float, float, float]:
    """Row ``i``'s wind ``(wx, wy, wz)`` (m/s, ENU) for this tick: the mean wind, plus the gust
    of :func:`gust_row` rotated from the mean-wind frame when turbulence is on
    (``e_u = (ex, ey, 0)`` downwind, ``e_v = e_w x e_u = (-ey, ex, 0)``, ``e_w = (0, 0, 1)``)."""
    if ist[i, WI.TURB] == 0:
        return fs[i, W.MX], fs[i, W.MY], 0.0
    u, v, w = gust_row(fs, ist, buf, i, dt, altitude, airspeed)
    ex = fs[i, W.EX]
    ey = fs[i, W.EY]
    # wind = mean + u e_u + v e_v + w e_w
    return fs[i, W.MX] + u * ex - v * ey, fs[i, W.MY] + u * ey + v * ex, w


@register_jitable
def needs_draws(ist: np.ndarray, i: int) -> bool:
    """Row ``i`` is turbulent and has fewer than 5 unread normals (its next step needs a block)."""
    return ist[i, WI.TURB] != 0 and ist[i, WI.I] + D.SIZE > ist[i, WI.LEN]


def refill_row(rng: np.random.Generator, ist: np.ndarray, buf: np.ndarray, i: int) -> None:
    """Draw row ``i``'s next block of ``ist[i, WI.BLOCK]`` standard normals into ``buf[i]`` when
    :func:`needs_draws` (the Generator is touched only then; the unread rest is dropped)."""
    if needs_draws(ist, i):
        m = int(ist[i, WI.BLOCK])
        buf[i, :m] = rng.standard_normal(m)
        ist[i, WI.I] = 0
        ist[i, WI.LEN] = m


# ============================================================================ over a batch
# The loops of ag_uav.vehicle.sensors_batched.BatchWind live here, beside the row law: numba's
# cache of a function is renewed only when its own file changes.


@njit(cache=True)
def wind_rows_need(active: np.ndarray, ist: np.ndarray) -> int:
    """Number of active rows whose draw buffer cannot serve this tick."""
    need = 0
    for i in range(ist.shape[0]):
        if active[i] and needs_draws(ist, i):
            need += 1
    return need


@njit(cache=True)
def wind_rows(dt: float, altitude: np.ndarray, airspeed: np.ndarray, active: np.ndarray,
              fs: np.ndarray, ist: np.ndarray, buf: np.ndarray, out: np.ndarray) -> int:
    """:func:`wind_row` of every active row into ``out`` (N, 3); returns 0, or (nothing done)
    the number of active rows that need draws first (:func:`refill_row`)."""
    need = wind_rows_need(active, ist)
    if need:
        return need
    for i in range(fs.shape[0]):
        if active[i]:
            wx, wy, wz = wind_row(fs, ist, buf, i, dt, altitude[i], airspeed[i])
            out[i, X] = wx
            out[i, Y] = wy
            out[i, Z] = wz
    return 0


@njit(cache=True)
def wind_drag_rows(dt: float, z: np.ndarray, v: np.ndarray, c_lin: np.ndarray,
                   c_quad: np.ndarray, active: np.ndarray, rows: tuple, out: np.ndarray,
                   force: np.ndarray) -> int:
    """:func:`wind_rows` at altitude ``max(z, 0)`` and airspeed ``|v_xy - mean_xy|`` (the
    engine's per-tick inputs), and the drag ``force`` (N, 3) of ``r = v - wind``
    (:func:`drag_axis`). ``rows``: the stacked wind rows, :class:`WindRow`'s fields as a plain
    tuple (numba types a plain tuple of arrays on its fast path)."""
    st = WindRow(*rows)
    fs, ist, buf = st.fs, st.ist, st.buf
    need = wind_rows_need(active, ist)
    if need:
        return need
    for i in range(fs.shape[0]):
        if not active[i]:
            continue
        vx = v[i, X]
        vy = v[i, Y]
        vz = v[i, Z]
        pz = z[i]
        ax = vx - fs[i, W.MX]
        ay = vy - fs[i, W.MY]
        wx, wy, wz = wind_row(fs, ist, buf, i, dt, pz if pz > 0.0 else 0.0,
                              math.sqrt(ax * ax + ay * ay))
        out[i, X] = wx
        out[i, Y] = wy
        out[i, Z] = wz
        force[i, X] = drag_axis(vx - wx, c_lin[i, X], c_quad[i, X])
        force[i, Y] = drag_axis(vy - wy, c_lin[i, Y], c_quad[i, Y])
        force[i, Z] = drag_axis(vz - wz, c_lin[i, Z], c_quad[i, Z])
    return 0


@njit(cache=True)
def drag_rows(v: np.ndarray, wind: np.ndarray, c_lin: np.ndarray, c_quad: np.ndarray,
              out: np.ndarray) -> None:
    """:func:`drag_axis` of every row and axis: ``out = -c_lin r - c_quad |r| r``,
    ``r = v - wind``."""
    for i in range(v.shape[0]):
        for j in range(3):
            out[i, j] = drag_axis(v[i, j] - wind[i, j], c_lin[i, j], c_quad[i, j])


def _new_row(w20: float, rel_tol: float, block: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One wind row (``fs`` (1, WF_N), ``ist`` (1, WI_N), ``buf`` (1, block)) before its first
    step: no discretisation cached, no normals buffered."""
    fs = np.zeros((1, WF_N))
    fs[0, W.V] = fs[0, W.H] = fs[0, W.DT] = -1.0
    fs[0, W.RELTOL] = rel_tol
    fs[0, W.W20] = w20
    ist = np.zeros((1, WI_N), dtype=np.int64)
    ist[0, WI.BLOCK] = block
    return fs, ist, np.zeros((1, block))


# ============================================================================ per vehicle


class DrydenTurbulence:
    """Dryden gust generator (MIL-F-8785C low altitude), exact discretisation.

    Args:
        w20: wind speed at 20 ft in m/s (intensity; sigma_w = 0.1 w20).
        rng: numpy Generator; Gaussian numbers are drawn from it in blocks of ``block`` values.
        rel_tol: relative change of V or h that triggers recomputing the cached discretisation.
        block: number of standard normals drawn per refill (rounded down to a multiple of 5).

    The state is kept in normalised units (unit stationary variance), so a change of altitude
    rescales the gusts immediately without a transient.  The initial state is drawn from the
    stationary distribution.  The state is one wind row (module docstring); :meth:`step` is
    :func:`gust_row` on it.
    """

    def __init__(
        self, w20: float, rng: np.random.Generator, rel_tol: float = 0.01, block: int = 5120
    ) -> None:
        if not (w20 >= 0.0 and math.isfinite(w20)):
            raise ValueError(
                f"DrydenTurbulence: w20 = {w20!r} is invalid; must be finite and >= 0"
            )
        if not isinstance(rng, np.random.Generator):
            raise ValueError(
                f"DrydenTurbulence: rng = {rng!r} is invalid; must be a numpy Generator"
            )
        if not (0.0 <= rel_tol < 0.5):
            raise ValueError(
                f"DrydenTurbulence: rel_tol = {rel_tol!r} is invalid; need 0 <= rel_tol < 0.5"
            )
        self.w20 = float(w20)
        self.rng = rng
        self.rel_tol = float(rel_tol)
        self.block = max(5, (int(block) // 5) * 5)
        self._fs, self._ist, self._buf = _new_row(self.w20, self.rel_tol, self.block)
        self._ist[0, WI.TURB] = 1
        self._fs[0, W.ZU:W.ZW2_END] = rng.standard_normal(W.ZW2_END - W.ZU)  # the 5 states

    @property
    def L_u(self) -> float:
        """Longitudinal (= lateral) scale length of the last step (m; 0 before the first)."""
        return float(self._fs[0, W.LU])

    @property
    def L_w(self) -> float:
        """Vertical scale length of the last step (m; 0 before the first)."""
        return float(self._fs[0, W.LW])

    def sigmas(self, altitude_m: float) -> tuple[float, float, float]:
        """Stationary stds (sigma_u, sigma_v, sigma_w) in m/s at ``altitude_m``."""
        su, sw, *_ = dryden_parameters(self.w20, altitude_m)
        return su, su, sw

    def step(self, dt: float, altitude_m: float, airspeed_mps: float) -> tuple[float, float, float]:
        """Advance by ``dt`` seconds and return the gust ``(u, v, w)`` in m/s (mean-wind frame)."""
        refill_row(self.rng, self._ist, self._buf, 0)
        return gust_row(self._fs, self._ist, self._buf, 0, float(dt), float(altitude_m),
                        float(airspeed_mps))


class WindRow(NamedTuple):
    """A wind's row state (module docstring), one row each: the floats ``fs`` (1, NF; columns
    :data:`WIND_ROW`), the integers ``ist`` (1, NI; columns :data:`WIND_INTS`) and the draw
    buffer ``buf``.
    :class:`~ag_uav.vehicle.sensors_batched.BatchWind` stacks the rows of its winds."""

    fs: np.ndarray
    ist: np.ndarray
    buf: np.ndarray


class Wind:
    """Mean wind plus optional Dryden turbulence, in world ENU.

    Args:
        mean_speed: mean horizontal wind speed in m/s (>= 0), taken as constant with height.
        direction_deg: meteorological direction the wind blows FROM, degrees clockwise from north
            (0 = from north -> air moves south; 90 = from east -> air moves west).
        turbulence: ``"none"``, ``"light"``, ``"moderate"``, ``"severe"`` (MIL-F-8785C W20 =
            15/30/45 kt, aircraft values -- strong for a drone), ``"mean"`` (W20 = mean_speed), or a
            float: explicit W20 in m/s.
        rng: numpy Generator; required when turbulence is on.
        rel_tol: see :class:`DrydenTurbulence`.

    ``step(dt, altitude_m, airspeed_mps)`` returns ``(wx, wy, wz)`` in m/s, ENU, where
    ``altitude_m`` is height above ground and ``airspeed_mps`` the vehicle speed relative to the
    air (used for the frozen-turbulence time scaling; floored at 1 m/s).  The state is one wind
    row (module docstring; shared with ``turbulence`` when it is on); ``step`` is
    :func:`wind_row` on it.
    """

    def __init__(
        self,
        mean_speed: float = 0.0,
        direction_deg: float = 0.0,
        turbulence: str | float = "none",
        rng: np.random.Generator | None = None,
        rel_tol: float = 0.01,
    ) -> None:
        if not (math.isfinite(mean_speed) and mean_speed >= 0.0):
            raise ValueError(
                f"Wind: mean_speed = {mean_speed!r} is invalid; must be finite and >= 0"
            )
        if not math.isfinite(direction_deg):
            raise ValueError(f"Wind: direction_deg = {direction_deg!r} is invalid; must be finite")
        w20 = _w20(turbulence, mean_speed)
        self.mean_speed = float(mean_speed)
        self.direction_deg = float(direction_deg)
        self.w20 = w20
        d = math.radians(direction_deg)
        ex, ey = -math.sin(d), -math.cos(d)  # downwind unit vector (where the air goes), ENU
        self.mean: tuple[float, float, float] = (self.mean_speed * ex, self.mean_speed * ey, 0.0)
        self.turbulence: DrydenTurbulence | None = None
        if w20 > 0.0:
            if rng is None:
                raise ValueError(
                    "Wind: rng = None is invalid when turbulence is on; pass a Generator"
                )
            self.turbulence = DrydenTurbulence(w20, rng, rel_tol=rel_tol)
            t = self.turbulence
            self._fs, self._ist, self._buf = t._fs, t._ist, t._buf
        else:
            self._fs, self._ist, self._buf = _new_row(w20, float(rel_tol), 0)
        self._fs[0, W.EX], self._fs[0, W.EY] = ex, ey
        self._fs[0, W.MX], self._fs[0, W.MY] = self.mean[X], self.mean[Y]

    @property
    def row_state(self) -> WindRow:
        """This wind's row state (the arrays themselves: a batch taking it over copies them)."""
        return WindRow(self._fs, self._ist, self._buf)

    def sigmas(self, altitude_m: float) -> tuple[float, float, float]:
        """Gust stds (sigma_u, sigma_v, sigma_w) at ``altitude_m`` (zeros without turbulence)."""
        if self.turbulence is None:
            return 0.0, 0.0, 0.0
        return self.turbulence.sigmas(altitude_m)

    def step(self, dt: float, altitude_m: float, airspeed_mps: float) -> tuple[float, float, float]:
        """Advance by ``dt`` and return the wind velocity ``(wx, wy, wz)`` (m/s, ENU)."""
        if self.turbulence is not None:
            refill_row(self.turbulence.rng, self._ist, self._buf, 0)
        return wind_row(self._fs, self._ist, self._buf, 0, float(dt), float(altitude_m),
                        float(airspeed_mps))


def _w20(turbulence: str | float, mean_speed: float) -> float:
    """W20 (m/s) of the ``turbulence`` setting of :class:`Wind`."""
    if isinstance(turbulence, str):
        key = turbulence.strip().lower()
        if key == "mean":
            return float(mean_speed)
        if key in TURBULENCE_PRESETS_W20:
            return TURBULENCE_PRESETS_W20[key]
        allowed = ", ".join(repr(k) for k in [*TURBULENCE_PRESETS_W20, "mean"])
        raise ValueError(
            f"Wind: turbulence = {turbulence!r} is invalid; allowed: {allowed} "
            "or a float W20 in m/s"
        )
    w20 = float(turbulence)
    if not (math.isfinite(w20) and w20 >= 0.0):
        raise ValueError(
            f"Wind: turbulence = {turbulence!r} is invalid; an explicit W20 must be "
            "finite and >= 0 (m/s)"
        )
    return w20


def drag_force(
    v: Sequence[float],
    v_wind: Sequence[float],
    c_d_lin: float | Sequence[float],
    c_d_quad: float | Sequence[float] = 0.0,
) -> tuple[float, float, float]:
    """Aerodynamic drag on the vehicle, per world axis.

    ``F_i = -c_lin_i * r_i - c_quad_i * |r_i| * r_i`` (:func:`drag_axis`) with ``r = v - v_wind``
    the velocity relative to the air (component-wise magnitude, so each axis has its own
    effective area).  Coefficients are scalars or 3-sequences (N s/m and N s^2/m^2) and are set
    by the vehicle config, not here.  A steady wind on a hovering vehicle (v = 0) gives
    ``F = c_lin w + c_quad |w| w``, pushing it downwind.
    """
    cl = [float(c_d_lin)] * 3 if isinstance(c_d_lin, (int, float)) else [float(c) for c in c_d_lin]
    cq = ([float(c_d_quad)] * 3 if isinstance(c_d_quad, (int, float))
          else [float(c) for c in c_d_quad])
    f = [drag_axis(float(v[j]) - float(v_wind[j]), cl[j], cq[j]) for j in range(3)]
    return f[X], f[Y], f[Z]
