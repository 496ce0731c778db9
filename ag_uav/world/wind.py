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

Speed: :meth:`DrydenTurbulence.step` uses plain Python floats, caches the discretisation (recomputed
only when V or h drift by more than ``rel_tol`` relative, or dt changes), and draws Gaussian
numbers from the Generator in blocks.  Typical cost is a few microseconds per call.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

try:  # plain Python functions that numba kernels may also call (ag_uav.vehicle.sensors_batched)
    from numba.extending import register_jitable
except ImportError:  # pragma: no cover
    def register_jitable(f):
        return f

__all__ = [
    "FT_PER_M",
    "KNOT",
    "TURBULENCE_PRESETS_W20",
    "DrydenTurbulence",
    "Wind",
    "drag_force",
    "dryden_parameters",
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


class DrydenTurbulence:
    """Dryden gust generator (MIL-F-8785C low altitude), exact discretisation.

    Args:
        w20: wind speed at 20 ft in m/s (intensity; sigma_w = 0.1 w20).
        rng: numpy Generator; Gaussian numbers are drawn from it in blocks of ``block`` values.
        rel_tol: relative change of V or h that triggers recomputing the cached discretisation.
        block: number of standard normals drawn per refill (rounded down to a multiple of 5).

    The state is kept in normalised units (unit stationary variance), so a change of altitude
    rescales the gusts immediately without a transient.  The initial state is drawn from the
    stationary distribution.
    """

    __slots__ = (
        "w20", "rng", "rel_tol", "_block", "_buf", "_i",
        "_V", "_h", "_dt", "_tolV", "_toll",
        "_su", "_sw", "_a", "_b",
        "_v_coef", "_w_coef",
        "_zu", "_zv1", "_zv2", "_zw1", "_zw2",
        "L_u", "L_w",
    )

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
        self._block = max(5, (int(block) // 5) * 5)
        self._buf: list[float] = []
        self._i = 0
        self._V = -1.0
        self._h = -1.0
        self._dt = -1.0
        self._tolV = 0.0
        self._toll = 0.0
        self._su = self._sw = 0.0
        self._a = self._b = 0.0
        self._v_coef = (0.0,) * 7
        self._w_coef = (0.0,) * 7
        self.L_u = self.L_w = 0.0
        z = rng.standard_normal(5).tolist()
        self._zu, self._zv1, self._zv2, self._zw1, self._zw2 = z

    def _refill(self) -> None:
        self._buf = self.rng.standard_normal(self._block).tolist()
        self._i = 0

    def _update(self, dt: float, h: float, V: float) -> None:
        su, sw, l_u, l_w, h_used = dryden_parameters(self.w20, h)
        self._su, self._sw, self.L_u, self.L_w = su, sw, l_u, l_w
        theta_u = V * dt / l_u
        self._a = math.exp(-theta_u)
        self._b = math.sqrt(-math.expm1(-2.0 * theta_u))
        self._v_coef = _second_order_coeffs(theta_u)  # L_v = L_u
        self._w_coef = _second_order_coeffs(V * dt / l_w)
        self._V, self._h, self._dt = V, h, dt
        self._tolV = self.rel_tol * V
        self._toll = self.rel_tol * h

    def sigmas(self, altitude_m: float) -> tuple[float, float, float]:
        """Stationary stds (sigma_u, sigma_v, sigma_w) in m/s at ``altitude_m``."""
        su, sw, *_ = dryden_parameters(self.w20, altitude_m)
        return su, su, sw

    def step(self, dt: float, altitude_m: float, airspeed_mps: float) -> tuple[float, float, float]:
        """Advance by ``dt`` seconds and return the gust ``(u, v, w)`` in m/s (mean-wind frame)."""
        V = airspeed_mps if airspeed_mps > V_MIN else V_MIN
        h = altitude_m if altitude_m > H_MIN_M else H_MIN_M
        if h > H_MAX_M:
            h = H_MAX_M
        if abs(V - self._V) > self._tolV or abs(h - self._h) > self._toll or dt != self._dt:
            self._update(dt, h, V)
        i = self._i
        if i + 5 > len(self._buf):
            self._refill()
            i = 0
        buf = self._buf
        n0 = buf[i]
        n1 = buf[i + 1]
        n2 = buf[i + 2]
        n3 = buf[i + 3]
        n4 = buf[i + 4]
        self._i = i + 5
        zu = self._a * self._zu + self._b * n0
        f11, f12, f21, f22, l11, l21, l22 = self._v_coef
        z1, z2 = self._zv1, self._zv2
        zv1 = f11 * z1 + f12 * z2 + l11 * n1
        zv2 = f21 * z1 + f22 * z2 + l21 * n1 + l22 * n2
        f11, f12, f21, f22, l11, l21, l22 = self._w_coef
        z1, z2 = self._zw1, self._zw2
        zw1 = f11 * z1 + f12 * z2 + l11 * n3
        zw2 = f21 * z1 + f22 * z2 + l21 * n3 + l22 * n4
        self._zu, self._zv1, self._zv2, self._zw1, self._zw2 = zu, zv1, zv2, zw1, zw2
        su = self._su
        return (
            su * zu,
            su * (0.5 * zv1 + _SQRT3_2 * zv2),
            self._sw * (0.5 * zw1 + _SQRT3_2 * zw2),
        )


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
    air (used for the frozen-turbulence time scaling; floored at 1 m/s).
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
        if isinstance(turbulence, str):
            key = turbulence.strip().lower()
            if key == "mean":
                w20 = float(mean_speed)
            elif key in TURBULENCE_PRESETS_W20:
                w20 = TURBULENCE_PRESETS_W20[key]
            else:
                allowed = ", ".join(repr(k) for k in [*TURBULENCE_PRESETS_W20, "mean"])
                raise ValueError(
                    f"Wind: turbulence = {turbulence!r} is invalid; allowed: {allowed} "
                    "or a float W20 in m/s"
                )
        else:
            w20 = float(turbulence)
            if not (math.isfinite(w20) and w20 >= 0.0):
                raise ValueError(
                    f"Wind: turbulence = {turbulence!r} is invalid; an explicit W20 must be "
                    "finite and >= 0 (m/s)"
                )
        self.mean_speed = float(mean_speed)
        self.direction_deg = float(direction_deg)
        self.w20 = w20
        d = math.radians(direction_deg)
        # downwind unit vector (where the air goes), ENU
        self._ex = -math.sin(d)
        self._ey = -math.cos(d)
        self.mean: tuple[float, float, float] = (
            self.mean_speed * self._ex,
            self.mean_speed * self._ey,
            0.0,
        )
        self.turbulence: DrydenTurbulence | None = None
        if w20 > 0.0:
            if rng is None:
                raise ValueError(
                    "Wind: rng = None is invalid when turbulence is on; pass a Generator"
                )
            self.turbulence = DrydenTurbulence(w20, rng, rel_tol=rel_tol)

    def sigmas(self, altitude_m: float) -> tuple[float, float, float]:
        """Gust stds (sigma_u, sigma_v, sigma_w) at ``altitude_m`` (zeros without turbulence)."""
        if self.turbulence is None:
            return 0.0, 0.0, 0.0
        return self.turbulence.sigmas(altitude_m)

    def step(self, dt: float, altitude_m: float, airspeed_mps: float) -> tuple[float, float, float]:
        """Advance by ``dt`` and return the wind velocity ``(wx, wy, wz)`` (m/s, ENU)."""
        turb = self.turbulence
        if turb is None:
            return self.mean
        u, v, w = turb.step(dt, altitude_m, airspeed_mps)
        ex = self._ex
        ey = self._ey
        mx, my, _ = self.mean
        # e_u = (ex, ey, 0), e_v = e_w x e_u = (-ey, ex, 0), e_w = (0, 0, 1)
        return (mx + u * ex - v * ey, my + u * ey + v * ex, w)


def drag_force(
    v: Sequence[float],
    v_wind: Sequence[float],
    c_d_lin: float | Sequence[float],
    c_d_quad: float | Sequence[float] = 0.0,
) -> tuple[float, float, float]:
    """Aerodynamic drag on the vehicle, per world axis.

    ``F_i = -c_lin_i * r_i - c_quad_i * |r_i| * r_i`` with ``r = v - v_wind`` the velocity relative
    to the air (component-wise magnitude, so each axis has its own effective area).  Coefficients
    are scalars or 3-sequences (N s/m and N s^2/m^2) and are set by the vehicle config, not here.
    A steady wind on a hovering vehicle (v = 0) gives ``F = c_lin w + c_quad |w| w``, pushing it
    downwind.
    """
    if isinstance(c_d_lin, (int, float)):
        cl0 = cl1 = cl2 = float(c_d_lin)
    else:
        cl0, cl1, cl2 = (float(c) for c in c_d_lin)
    if isinstance(c_d_quad, (int, float)):
        cq0 = cq1 = cq2 = float(c_d_quad)
    else:
        cq0, cq1, cq2 = (float(c) for c in c_d_quad)
    r0 = float(v[0]) - float(v_wind[0])
    r1 = float(v[1]) - float(v_wind[1])
    r2 = float(v[2]) - float(v_wind[2])
    return (
        -cl0 * r0 - cq0 * abs(r0) * r0,
        -cl1 * r1 - cq1 * abs(r1) * r1,
        -cl2 * r2 - cq2 * abs(r2) * r2,
    )
