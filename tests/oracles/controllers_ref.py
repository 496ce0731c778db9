"""Hand-written reference implementations (test oracles) of the controller laws.

Written independently of the product's compiled row functions (:mod:`controllers.axis`,
:mod:`controllers.attitude`, :mod:`controllers.cascade`), in plain Python / numpy, straight
from the equations:

* :class:`RefAxis`: the PID / fuzzy-PID axis law with derivative memory, derivative filter,
  derivative on measurement, integral clamp, output clamp and conditional integration
  (Åström & Hägglund, *Advanced PID Control*, 2006, §3.5);
* :func:`ref_phi`: the fuzzy PD core over all nine rules (firing strengths of every rule,
  then the type reducer) with :func:`km_reduce`, the generic Karnik–Mendel reducer by
  enumeration of every switch point (Mendel, *Uncertain Rule-Based Fuzzy Systems*, 2017);
* :func:`ref_thrust_attitude`, :func:`ref_torque`: thrust vectoring and the geometric attitude
  law (Lee, Leok & McClamroch, CDC 2010) in numpy vector algebra;
* :func:`ref_mix`: the X mixer with its saturation priority;
* :class:`RefCascade`: the position cascade made of the above.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


# ------------------------------------------------------------------------- fuzzy core (9 rules)
def km_reduce(y: Sequence[float], f_lower: Sequence[float],
              f_upper: Sequence[float]) -> tuple[float, float]:
    """Exact Karnik–Mendel type reduction by enumerating every switch point; (y_l, y_r).

    Sort the consequents ascending, then
    y_l = min_k [Σ_{i<k} f̄_i y_i + Σ_{i>=k} f_i y_i] / [Σ_{i<k} f̄_i + Σ_{i>=k} f_i] and
    y_r = max_k (same with f and f̄ swapped); zero denominators are skipped.
    """
    rows = sorted(zip(y, f_lower, f_upper, strict=True), key=lambda r: r[0])
    if not rows:
        raise ValueError("no rules")
    y_l, y_r = math.inf, -math.inf
    for k in range(len(rows) + 1):
        nl = dl = nr = dr = 0.0
        for i, (yi, lo, up) in enumerate(rows):
            wl, wr = (up, lo) if i < k else (lo, up)
            nl += wl * yi
            dl += wl
            nr += wr * yi
            dr += wr
        if dl > 0.0:
            y_l = min(y_l, nl / dl)
        if dr > 0.0:
            y_r = max(y_r, nr / dr)
    if not (math.isfinite(y_l) and math.isfinite(y_r)):
        raise ValueError("no rule fires")
    return y_l, y_r


def _umf(x: float) -> tuple[float, float, float]:
    """Upper MFs N, Z, P (triangles (-1.8, -1, 0), (-1, 0, 1), (0, 1, 1.8)) on [-1, 1]."""
    return max(0.0, -x), 1.0 - abs(x), max(0.0, x)


def rules(E: float, dE: float, cm: float, h_e: Sequence[float],
          h_de: Sequence[float]) -> tuple[list[float], list[float], list[float]]:
    """Consequents, lower and upper firing strengths of the nine rules (product t-norm)."""
    E = min(1.0, max(-1.0, E))
    dE = min(1.0, max(-1.0, dE))
    table = (-1.0, -cm, 0.0, cm, 1.0)
    ue, ud = _umf(E), _umf(dE)
    y, lo, up = [], [], []
    for i in range(3):
        for j in range(3):
            f = ue[i] * ud[j]
            y.append(table[i + j])
            up.append(f)
            lo.append(h_e[i] * h_de[j] * f)
    return y, lo, up


def ref_phi(E: float, dE: float, cm: float, reducer: str = "t1",
            h_e: Sequence[float] = (1.0, 1.0, 1.0), h_de: Sequence[float] = (1.0, 1.0, 1.0),
            zeta: float = 0.5) -> float:
    """Φ(E, dE): "t1" (weighted average of the upper firing), "km", "nt", "bmm" or "zeta"."""
    y, lo, up = rules(E, dE, cm, h_e, h_de)
    sl = sum(f * v for f, v in zip(lo, y, strict=True))
    su = sum(f * v for f, v in zip(up, y, strict=True))
    dl, du = sum(lo), sum(up)
    if reducer == "t1":
        return su / du
    if reducer == "km":
        yl, yr = km_reduce(y, lo, up)
        return 0.5 * (yl + yr)
    if reducer == "nt":
        return (sl + su) / (dl + du)
    if reducer == "bmm":
        return 0.5 * sl / dl + 0.5 * su / du
    if reducer == "zeta":
        return (zeta * sl + (1.0 - zeta) * su) / (dl + du)
    raise ValueError(reducer)


# ------------------------------------------------------------------------------ the axis law
class RefAxis:
    """One axis controller. ``kind`` "pid" (gains Kp, Ki, Kd) or a fuzzy core name ("t1",
    "km", "nt", "bmm", "zeta"; gains Ke, Kd, K0, K1 and the core's cm, heights, zeta)."""

    def __init__(self, kind: str, gains: Sequence[float], *, cm: float = 0.5,
                 h_e: Sequence[float] = (1.0, 1.0, 1.0), h_de: Sequence[float] = (1.0, 1.0, 1.0),
                 zeta: float = 0.5, derivative: str = "error", i_limit: float | None = None,
                 u_limit: float | tuple[float, float] | None = None, d_tau: float = 0.0) -> None:
        self.kind, self.g = kind, tuple(float(x) for x in gains)
        self.cm, self.h_e, self.h_de, self.zeta = cm, tuple(h_e), tuple(h_de), zeta
        self.on_meas = derivative == "measurement"
        self.i_limit, self.d_tau = i_limit, d_tau
        if u_limit is None:
            self.umin, self.umax = -math.inf, math.inf
        elif isinstance(u_limit, tuple | list):
            self.umin, self.umax = float(u_limit[0]), float(u_limit[1])
        else:
            self.umin, self.umax = -abs(u_limit), abs(u_limit)
        self.reset()

    def reset(self, integral: float = 0.0) -> None:
        self.prev: float | None = None
        self.filt = 0.0
        self.integral = integral
        self.E = self.dE = self.U = self.u = 0.0

    def _derivative(self, e: float, dt: float, y: float | None, rate: float | None) -> float:
        x = -y if (self.on_meas and y is not None) else e
        prev, self.prev = self.prev, x
        if rate is not None:
            return rate
        if prev is None:
            return 0.0
        d = (x - prev) / dt
        if self.d_tau > 0.0:
            self.filt = self.filt + dt / (self.d_tau + dt) * (d - self.filt)
            d = self.filt
        return d

    def update(self, e: float, dt: float, y: float | None = None,
               rate: float | None = None) -> float:
        de = self._derivative(e, dt, y, rate)
        if self.kind == "pid":
            kp, ki, kd = self.g
            u_rest, dI, K = kp * e + kd * de, dt * e, ki
        else:
            ke, kd, k0, k1 = self.g
            self.E = min(1.0, max(-1.0, ke * e))
            self.dE = min(1.0, max(-1.0, kd * de))
            self.U = ref_phi(self.E, self.dE, self.cm, self.kind, self.h_e, self.h_de, self.zeta)
            u_rest, dI, K = k0 * self.U, dt * self.U, k1
        I0 = self.integral
        I = I0 + dI  # noqa: E741
        if self.i_limit is not None and K != 0.0:
            imax = self.i_limit / abs(K)
            I = min(imax, max(-imax, I))  # noqa: E741
        u = u_rest + K * I
        if (u > self.umax and K * (I - I0) > 0.0) or (u < self.umin and K * (I - I0) < 0.0):
            I = I0  # noqa: E741  conditional integration
            u = u_rest + K * I
        self.integral = I
        self.u = min(self.umax, max(self.umin, u))
        return self.u


# --------------------------------------------------------------------- attitude and the mixer
def ref_thrust_attitude(a: Sequence[float], yaw: float, mass: float, g: float,
                        tilt_max: float) -> tuple[np.ndarray, float, float]:
    """(R_d 3×3, |f|, tilt): f = m(a + g e3), f_z >= 0.2 m g, horizontal part scaled to the tilt
    limit; b3 = f/|f|, b2 = b3 × (cos ψ, sin ψ, 0) normalised, b1 = b2 × b3."""
    f = mass * np.array([a[0], a[1], a[2] + g])
    f[2] = max(f[2], 0.2 * mass * g)
    fh = math.hypot(f[0], f[1])
    if fh > f[2] * math.tan(tilt_max):
        f[:2] *= f[2] * math.tan(tilt_max) / fh
        fh = f[2] * math.tan(tilt_max)
    b3 = f / np.linalg.norm(f)
    b2 = np.cross(b3, [math.cos(yaw), math.sin(yaw), 0.0])
    b2 /= np.linalg.norm(b2)
    return np.column_stack([np.cross(b2, b3), b2, b3]), float(np.linalg.norm(f)), \
        math.atan2(fh, f[2])


def ref_torque(R: np.ndarray, omega: Sequence[float], R_d: np.ndarray, J: Sequence[float],
               kR: Sequence[float], kw: Sequence[float]) -> np.ndarray:
    """τ = −kR e_R − kw ω + ω × Jω, e_R = ½ vee(R_dᵀR − RᵀR_d)."""
    M = R_d.T @ R - R.T @ R_d
    eR = 0.5 * np.array([M[2, 1], M[0, 2], M[1, 0]])
    w = np.asarray(omega, float)
    return -np.asarray(kR) * eR - np.asarray(kw) * w + np.cross(w, np.asarray(J) * w)


def ref_mix(Ainv: np.ndarray, fmax: float, T: float, tau: Sequence[float]) -> tuple[list, bool]:
    """(rotor thrusts, saturated): f = Ainv [T, τ]; if outside [0, f_max]: keep the largest
    yaw fraction that fits, else shift the collective, else clip the yaw-free allocation."""
    f = Ainv @ np.array([T, *tau])
    if f.min() >= 0.0 and f.max() <= fmax:
        return list(f), False
    f0 = Ainv @ np.array([T, tau[0], tau[1], 0.0])
    if f0.min() >= 0.0 and f0.max() <= fmax:
        s = 1.0
        for a, b in zip(f0, f, strict=True):
            if b > fmax:
                s = min(s, (fmax - a) / (b - a))
            elif b < 0.0:
                s = min(s, -a / (b - a))
        return list(f0 + s * (f - f0)), True
    if f0.max() - f0.min() <= fmax:
        return list(f0 + (-f0.min() if f0.min() < 0.0 else fmax - f0.max())), True
    return list(np.clip(f0, 0.0, fmax)), True


class RefCascade:
    """Position cascade: per-axis law on e = p_ref − p with rate v_ref − v, clip to ±a_limit,
    feed-forward, thrust vectoring, collective T = |f| (R_d e3)·(R e3) >= 0, torques, mixer."""

    def __init__(self, axes: Sequence[RefAxis], mass: float, g: float, J: Sequence[float],
                 kR: Sequence[float], kw: Sequence[float], Ainv: np.ndarray, f_max: float,
                 tilt_max: float, ff: float, a_limit: float) -> None:
        self.axes, self.mass, self.g = list(axes), mass, g
        self.J, self.kR, self.kw, self.Ainv, self.f_max = J, kR, kw, np.asarray(Ainv), f_max
        self.tilt_max, self.ff, self.a_limit = tilt_max, ff, a_limit
        self.saturated = False

    def update(self, p, v, R, omega, p_ref, v_ref, a_ref, yaw, dt) -> list[float]:
        lim = self.a_limit
        acc = [min(lim, max(-lim, ax.update(p_ref[k] - p[k], dt, p[k], v_ref[k] - v[k])))
               + self.ff * a_ref[k] for k, ax in enumerate(self.axes)]
        R = np.asarray(R, float).reshape(3, 3)
        R_d, fn, self.tilt = ref_thrust_attitude(acc, yaw, self.mass, self.g, self.tilt_max)
        T = max(0.0, fn * float(R_d[:, 2] @ R[:, 2]))
        tau = ref_torque(R, omega, R_d, self.J, self.kR, self.kw)
        f, self.saturated = ref_mix(self.Ainv, self.f_max, T, tau)
        return f
