"""Linear motion models for the estimator bank.

State ordering
--------------
Every model stacks one block per axis, the derivatives of that axis kept together::

    CV ("cv"):  [px, vx, py, vy, pz, vz]            (per axis: position, velocity)
    CA ("ca"):  [px, vx, ax, py, vy, ay, pz, vz, az] (per axis: position, velocity, acceleration)
    CVB ("cvb"): [px, vx, bx, py, vy, by, pz, vz, bz] (per axis: position, velocity, input bias)

so the paper's eq 8 (2-D CV, ``Ts = 0.05``) is exactly ``transition("cv", 2, 0.05)``.
The measurement matrix picks the positions (``H[i, i*order] = 1``): GPS gives position only.

Axes
----
``dim`` is 1, 2, 3 or ``"2d+alt"``.  ``"2d+alt"`` is three axes (x, y horizontal and z = altitude)
whose vertical axis carries its own process and measurement noise (``q_alt``, ``r_alt``), as GPS
vertical error and vertical manoeuvres differ from the horizontal ones.  Otherwise ``q`` and ``r``
may be scalars (same for all axes) or one value per axis.

Process noise
-------------
``q_form="continuous"`` (default): continuous white noise on the highest derivative with spectral
density ``q`` (m²/s³ for CV = white acceleration, m²/s⁵ for CA = white jerk), integrated exactly
over ``dt`` (Bar-Shalom, Li, Kirubarajan 2001, §6.2.2 / §6.2.3)::

    CV:  q * [[dt³/3, dt²/2],
              [dt²/2, dt   ]]
    CA:  q * [[dt⁵/20, dt⁴/8, dt³/6],
              [dt⁴/8,  dt³/3, dt²/2],
              [dt³/6,  dt²/2, dt   ]]

``q_form="discrete"``: piecewise-constant white acceleration (CV) / acceleration increment (CA)
with variance ``q`` (m²/s⁴ resp. m²/s⁶ per step) entering through Γ (§6.3.2 / §6.3.3)::

    CV:  Γ = [dt²/2, dt]ᵀ,           Q = q Γ Γᵀ
    CA:  Γ = [dt²/2, dt, 1]ᵀ,        Q = q Γ Γᵀ

``q_form="paper"``: the diagonal Q of the paper's eq 9, ``diag(q dt²/4, q)`` per CV axis
(``q = 0.025, dt = 0.05`` gives eq 9's 1.5625e-5 and 0.025).  It is not a discretisation of any
continuous model; it is provided to reproduce the paper's numerical setup.

Input bias (``"cvb"``)
---------------------
For a prediction driven by a measured acceleration ``ã = a + b + w_a`` (an IMU's specific force
rotated into the world frame, plus gravity) as the known input ``B ã`` with ``B = [dt²/2, dt, 0]``
per axis, the state carries the input's slowly varying error ``b`` (accelerometer bias and the
gravity an attitude error projects, in the world frame) so that it is estimated, not averaged::

    ṗ = v,   v̇ = ã − b − w_a,   ḃ = w_b          (w_a PSD q, w_b PSD q_bias)
    F = [[1, dt, −dt²/2], [0, 1, −dt], [0, 0, 1]]
    Q = q [[dt³/3, dt²/2, 0], [dt²/2, dt, 0], [0, 0, 0]]
        + q_bias [[dt⁵/20, dt⁴/8, −dt³/6], [dt⁴/8, dt³/3, −dt²/2], [−dt³/6, −dt²/2, dt]]

(the exact discretisation; the second block is the CA block with ``a = −b``; Groves 2013,
*Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems*, §14.2, for the
same bias states in a loosely coupled filter). Only ``q_form = "continuous"`` is defined.

``R`` is ``diag(r)`` per measured axis (variances in m²).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from numkit import Layout, Z

#: one axis of the "cvb" model's state: position, velocity, the input's bias
CVB = Layout("p v b").at

__all__ = [
    "LinearModel",
    "axis_count",
    "measurement_matrix",
    "motion_model",
    "paper_numerical_model",
    "process_noise",
    "state_labels",
    "transition",
]

_ORDER = {"cv": 2, "ca": 3, "cvb": 3}
Dim = int | str


def _order(kind: str) -> int:
    try:
        return _ORDER[kind.lower()]
    except (KeyError, AttributeError):
        raise ValueError(f"unknown motion model {kind!r}; allowed: 'cv', 'ca', 'cvb'") from None


def axis_count(dim: Dim) -> int:
    """Number of axes for ``dim`` in {1, 2, 3, "2d+alt"}."""
    if dim in (1, 2, 3):
        return int(dim)
    if isinstance(dim, str) and dim.lower() in ("2d+alt", "2d+z", "2+alt"):
        return 3
    raise ValueError(f"unknown dim {dim!r}; allowed: 1, 2, 3, '2d+alt'")


def _per_axis(value: float | Sequence[float], n_axes: int, name: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.size == 1:
        return np.full(n_axes, float(arr[0]))
    if arr.size != n_axes:
        raise ValueError(f"{name} needs 1 or {n_axes} values, got {arr.size}")
    return arr.astype(float)


def _axis_values(dim: Dim, value, alt_value, name: str) -> np.ndarray:
    n_axes = axis_count(dim)
    vals = _per_axis(value, n_axes, name)
    if isinstance(dim, str) and alt_value is not None:
        vals[Z] = float(alt_value)
    return vals


def transition(kind: str, dim: Dim, dt: float) -> np.ndarray:
    """State transition F for CV/CA with ``dim`` axes (block diagonal, one block per axis)."""
    order = _order(kind)
    if order == 2:
        blk = np.array([[1.0, dt], [0.0, 1.0]])
    elif kind.lower() == "cvb":
        blk = np.array([[1.0, dt, -0.5 * dt * dt], [0.0, 1.0, -dt], [0.0, 0.0, 1.0]])
    else:
        blk = np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    return np.kron(np.eye(axis_count(dim)), blk)


def _q_block(order: int, dt: float, q: float, form: str) -> np.ndarray:
    if form == "continuous":
        if order == 2:
            m = [[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]
        else:
            m = [
                [dt**5 / 20, dt**4 / 8, dt**3 / 6],
                [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                [dt**3 / 6, dt**2 / 2, dt],
            ]
        return q * np.array(m)
    if form == "discrete":
        g = np.array([dt**2 / 2, dt]) if order == 2 else np.array([dt**2 / 2, dt, 1.0])
        return q * np.outer(g, g)
    if form == "paper":
        if order != 2:
            raise ValueError("q_form='paper' is defined for the CV model only")
        return np.diag([q * dt * dt / 4, q])
    raise ValueError(f"unknown q_form {form!r}; allowed: 'continuous', 'discrete', 'paper'")


def _cvb_block(dt: float, q: float, q_bias: float, form: str) -> np.ndarray:
    if form != "continuous":
        raise ValueError("the 'cvb' model is defined with q_form='continuous' only")
    m = np.zeros((3, 3))
    pv = slice(CVB.P, CVB.V_END)
    m[pv, pv] = _q_block(2, dt, q, form)   # the (p, v) block of white acceleration noise
    cb = _q_block(3, dt, q_bias, form) * np.array([[1, 1, -1], [1, 1, -1], [-1, -1, 1]])
    return m + cb


def process_noise(
    kind: str,
    dim: Dim,
    dt: float,
    q: float | Sequence[float],
    q_form: str = "continuous",
    q_alt: float | None = None,
    q_bias: float | Sequence[float] = 0.0,
) -> np.ndarray:
    """Process noise Q (see the module docstring for the three forms)."""
    order = _order(kind)
    qs = _axis_values(dim, q, q_alt, "q")
    qb = _per_axis(q_bias, qs.size, "q_bias")
    n = order * qs.size
    Q = np.zeros((n, n))
    for i, qi in enumerate(qs):
        sl = slice(i * order, (i + 1) * order)
        if kind.lower() == "cvb":
            Q[sl, sl] = _cvb_block(dt, qi, qb[i], q_form)
        else:
            Q[sl, sl] = _q_block(order, dt, qi, q_form)
    return Q


def measurement_matrix(kind: str, dim: Dim) -> np.ndarray:
    """H that measures the position of every axis."""
    order = _order(kind)
    n_axes = axis_count(dim)
    H = np.zeros((n_axes, order * n_axes))
    H[np.arange(n_axes), np.arange(n_axes) * order] = 1.0
    return H


def state_labels(kind: str, dim: Dim) -> list[str]:
    """Names of the state components in order, e.g. ['px', 'vx', 'py', 'vy']."""
    order = _order(kind)
    axes = "xyz"[: axis_count(dim)]
    names = "pvb" if kind.lower() == "cvb" else "pva"[:order]
    return [f"{d}{a}" for a in axes for d in names]


@dataclass
class LinearModel:
    """F, Q, H, R of a linear-Gaussian motion model plus index bookkeeping."""

    F: np.ndarray
    Q: np.ndarray
    H: np.ndarray
    R: np.ndarray
    kind: str
    dim: Dim
    dt: float
    labels: list[str] = field(default_factory=list)

    @property
    def order(self) -> int:
        return _order(self.kind)

    @property
    def n(self) -> int:
        return self.F.shape[0]

    @property
    def m(self) -> int:
        return self.H.shape[0]

    @property
    def pos_idx(self) -> np.ndarray:
        """Indices of the positions in the state vector."""
        return np.arange(axis_count(self.dim)) * self.order

    @property
    def vel_idx(self) -> np.ndarray:
        """Indices of the velocities in the state vector."""
        return self.pos_idx + 1

    def state(self, pos: Sequence[float], vel: Sequence[float] | None = None) -> np.ndarray:
        """Build a state vector from per-axis positions (and velocities)."""
        x = np.zeros(self.n)
        x[self.pos_idx] = pos
        if vel is not None:
            x[self.vel_idx] = vel
        return x


def motion_model(
    kind: str = "cv",
    dim: Dim = 2,
    dt: float = 0.05,
    q: float | Sequence[float] = 1.0,
    r: float | Sequence[float] = 1.0,
    q_form: str = "continuous",
    q_alt: float | None = None,
    r_alt: float | None = None,
    q_bias: float | Sequence[float] = 0.0,
) -> LinearModel:
    """CV/CA/CVB model with position measurements; see the module docstring for every
    argument."""
    kind = kind.lower()
    rs = _axis_values(dim, r, r_alt, "r")
    return LinearModel(
        F=transition(kind, dim, dt),
        Q=process_noise(kind, dim, dt, q, q_form, q_alt, q_bias),
        H=measurement_matrix(kind, dim),
        R=np.diag(rs),
        kind=kind,
        dim=dim,
        dt=float(dt),
        labels=state_labels(kind, dim),
    )


def paper_numerical_model() -> LinearModel:
    """F, Q, H, R of Candan & Li eqs 8-11 (2-D CV, Ts = 0.05 s, R = diag(10, 100) m²)."""
    mdl = motion_model("cv", 2, 0.05, q=0.025, r=[10.0, 100.0], q_form="paper")
    mdl.Q = np.diag([1.562e-05, 0.025, 1.562e-05, 0.025])  # printed values of eq 9
    return mdl
