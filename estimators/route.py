"""Route-constrained Kalman filter: virtual measurements from a known route (Zhou et al. 2024).

Zhou, Su, Qiu, He, Rao, "Prediction of UAV positions using particle swarm optimisation-based
Kalman filter", Int. J. Robotics and Automation (DOI 10.2316/J.2024.206-1060), §3.

A cooperative UAV flies a pre-planned polyline route.  While GPS fixes arrive the filter is a
plain KF (the paper's eq 21: H_i = H).  When no fix arrives (outage, or pure prediction) the
route itself is used as a *virtual sensor* (eqs 16-18, 22): for the active segment with start
a, unit direction d and an orthonormal basis N of the directions normal to d (one row in 2-D,
two in 3-D), the pseudo-measurement

    y_c = N a,      H_c = N · [position selector],      R_c = r_virtual · I

says "the position lies on the segment's line", with a small variance ``r_virtual`` (m²).
The paper writes three cross-product rows per segment (eq 15); in 3-D they have rank 2 (a line
has two normal directions), so stacking them fuses the same information twice with a singular
noise-free part.  N uses exactly the two independent normal directions.

Active segment
--------------
The paper selects the segment by x ranges (eq 13: x_a ≤ x ≤ x_b), which fails for legs that run
in −x (x_b < x_a) or along y (x_a = x_b).  Here the segment is chosen by the **along-track
parameter** s = dᵀ(p̂ − a) of the estimate: the active segment advances while s exceeds its
length, or while the estimate is nearer the next segment than the current one (a vehicle that
cuts a corner never reaches its end); progress is monotone along the route, and a first call
without history takes the nearest segment, ties going to the later one
(:meth:`Route.locate`).

Turns (``turn``)
----------------
At a switch from segment i to i+1 during prediction, the paper's filter keeps its velocity
(``turn="project"``): only the pseudo-measurement on the new line pulls the estimate over, and
through the position–velocity correlations it removes the velocity component normal to the new
segment, so the predicted along-route speed becomes |v| cos(turn angle) — zero after a 90° turn
(the estimate stalls at the corner).  ``turn="rotate"`` (not in the paper) rotates position
offset from the corner, velocity, acceleration and their covariance blocks by the rotation that
maps d_i onto d_{i+1}: the vehicle is predicted to fly the turn at the same speed.

Innovation gates (``gate``)
---------------------------
- ``"chi2"`` (standard): accept when d² = νᵀ S⁻¹ ν ≤ χ²_m(p), ``p = gate_prob``.
- ``"paper"`` (eq 24-25 test): accept when ‖S‖₂ ≥ χ · νᵀν (‖S‖₂ the spectral norm = largest
  eigenvalue of S).  It compares the innovation's Euclidean length with the *largest* variance of
  S only, so it is loose in the well-determined directions of an anisotropic S and mixes units
  when S stacks positions and velocities.  ``paper_chi`` defaults to 1/χ²_m(p), which makes the
  two tests agree when S = s·I.
- ``None``: no gate.
A rejected update leaves x, P unchanged (eqs 28-29).  ``recover_after`` consecutive rejected
*fixes* force the next fix through (a lock-out guard: after a long outage the filter, not the
sensor, is more likely wrong).  ``gate_virtual`` applies the gate to the pseudo-measurements
too (what the paper's flow chart does; it lets the filter ignore the route when the vehicle has
left it, the paper's "intrusion" case).

Interface
---------
As every filter of the bank (``predict()``, ``update(z) -> bool``, ``x``, ``P``, ``y``, ``S``,
``K``, ``nis``), except that ``update(None)`` (no fix) is *not* a no-op when ``virtual`` is
``"outage"`` or ``"always"``: it fuses the route pseudo-measurement (:meth:`constrain`) and
returns ``False`` (no fix was fused).  ``last`` says what the last update did: ``"fix"``,
``"fix-rejected"``, ``"virtual"``, ``"virtual-rejected"`` or ``"none"``.

Also here: :func:`singer_model`, the Singer manoeuvring-target model the paper uses (eqs 2-10).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import linalg, stats

from numkit import Layout, X, Y, Z

from .kf import KF, joseph

#: one axis of the Singer model's state: position, velocity, acceleration
SG = Layout("p v a").at

__all__ = ["Route", "RouteConstrainedKF", "RouteOptions", "chi2_gate", "paper_gate", "singer_model"]

_dot = np.dot


# ------------------------------------------------------------------------------------ models
def singer_model(dt: float, lam: float | Sequence[float], sigma_a: float | Sequence[float],
                 dim: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Singer model (Singer 1970; the paper's eqs 2-10) discretised exactly.

    Per axis, state [p, v, a] with ṗ = v, v̇ = a, ȧ = −λ a + w, E[w(t)w(τ)] = 2 λ σ_a² δ(t−τ)
    (σ_a = RMS manoeuvre acceleration).  Φ = exp(A dt) (eq 7); Q = ∫₀^dt Φ(s) G q Gᵀ Φ(s)ᵀ ds by
    Van Loan's method.  Axes are stacked as in :mod:`estimators.models` ("ca" ordering:
    [px, vx, ax, py, vy, ay, ...]).  ``lam`` → 0 with σ_a² λ fixed tends to the CA model.
    Returns (F, Q).
    """
    lams = np.broadcast_to(np.asarray(lam, dtype=float), (dim,))
    sig = np.broadcast_to(np.asarray(sigma_a, dtype=float), (dim,))
    F = np.zeros((3 * dim, 3 * dim))
    Q = np.zeros_like(F)
    for i in range(dim):
        lm = float(lams[i])
        A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -lm]])
        q = 2.0 * lm * float(sig[i]) ** 2
        n = SG.SIZE
        Gq = np.zeros((n, n))
        Gq[SG.A, SG.A] = q                  # G q Gᵀ: white noise on the acceleration
        M = np.zeros((2 * n, 2 * n))        # Van Loan: M = [[−A, G q Gᵀ], [0, Aᵀ]]
        M[:n, :n] = -A
        M[:n, n:] = Gq
        M[n:, n:] = A.T
        E = linalg.expm(M * dt)
        Phi = E[n:, n:].T                   # Φ = (lower-right block)ᵀ
        Qi = Phi @ E[:n, n:]                # Q = Φ · (upper-right block)
        sl = slice(3 * i, 3 * i + 3)
        F[sl, sl] = Phi
        Q[sl, sl] = 0.5 * (Qi + Qi.T)
    return F, Q


# ------------------------------------------------------------------------------------- route
def _normals(d: np.ndarray) -> np.ndarray:
    """Orthonormal rows spanning the complement of unit vector ``d`` (2-D: 1 row, 3-D: 2)."""
    if d.size == 2:
        return np.array([[-d[1], d[0]]])
    # the last right singular vectors of d as a 1×3 matrix span its null space
    _, _, vt = np.linalg.svd(d.reshape(1, 3))
    N = vt[1:]
    # deterministic orientation: first normal horizontal when possible
    h = np.array([-d[1], d[0], 0.0])
    if np.linalg.norm(h) > 1e-9:
        n1 = h / np.linalg.norm(h)
        n2 = np.cross(d, n1)
        N = np.vstack([n1, n2 / np.linalg.norm(n2)])
    return N


def _rotation_between(u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Proper rotation R with R u = w for unit vectors u, w (2-D or 3-D)."""
    c = float(np.clip(u @ w, -1.0, 1.0))
    if u.size == 2:
        s = float(u[0] * w[1] - u[1] * w[0])
        return np.array([[c, -s], [s, c]])
    v = np.cross(u, w)
    sv = float(np.linalg.norm(v))
    if sv < 1e-12:
        if c > 0:
            return np.eye(3)
        k = _normals(u)[0]  # U-turn: half turn about an axis normal to u
        return 2.0 * np.outer(k, k) - np.eye(3)
    vx = np.array([[0.0, -v[Z], v[Y]], [v[Z], 0.0, -v[X]], [-v[Y], v[X], 0.0]])  # [v]×
    return np.eye(3) + vx + vx @ vx * ((1.0 - c) / (sv * sv))


class Route:
    """A polyline route (K ≥ 2 waypoints in 2-D or 3-D); zero-length segments are dropped.

    Attributes: ``a``, ``b`` (S, d) segment starts and ends, ``dirs`` (S, d) unit directions,
    ``lengths`` (S,), ``normals`` list of (d−1, d) orthonormal normal bases, ``cum`` (S+1,)
    arc length at the segment starts.
    """

    def __init__(self, waypoints) -> None:
        pts = np.asarray(waypoints, dtype=float)
        if pts.ndim != 2 or pts.shape[1] not in (2, 3):
            raise ValueError(f"waypoints must be (K, 2) or (K, 3), got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("waypoints must be finite")
        keep = [0]
        for i in range(1, len(pts)):
            if np.linalg.norm(pts[i] - pts[keep[-1]]) > 1e-9:
                keep.append(i)
        pts = pts[keep]
        if len(pts) < 2:
            raise ValueError("a route needs at least two distinct waypoints")
        self.points = pts
        self.dim = pts.shape[1]
        self.a = pts[:-1].copy()
        self.b = pts[1:].copy()
        seg = self.b - self.a
        self.lengths = np.linalg.norm(seg, axis=1)
        self.dirs = seg / self.lengths[:, None]
        self.normals = [_normals(d) for d in self.dirs]
        self.cum = np.concatenate([[0.0], np.cumsum(self.lengths)])

    @property
    def n_segments(self) -> int:
        return len(self.lengths)

    @property
    def length(self) -> float:
        return float(self.cum[-1])

    def along(self, i: int, p) -> float:
        """Along-track parameter s = dᵢᵀ(p − aᵢ) in metres (0 at aᵢ, ``lengths[i]`` at bᵢ)."""
        return float(self.dirs[i] @ (np.asarray(p, dtype=float)[: self.dim] - self.a[i]))

    def cross(self, i: int, p) -> np.ndarray:
        """Cross-track offsets Nᵢ(p − aᵢ) (1 value in 2-D, 2 in 3-D)."""
        return self.normals[i] @ (np.asarray(p, dtype=float)[: self.dim] - self.a[i])

    def distance(self, i: int, p) -> float:
        """Distance from p to segment i (clamped projection)."""
        p = np.asarray(p, dtype=float)[: self.dim]
        s = min(max(self.along(i, p), 0.0), self.lengths[i])
        return float(np.linalg.norm(p - (self.a[i] + s * self.dirs[i])))

    def locate(self, p, hint: int | None = None) -> int:
        """Active segment for position ``p`` by the along-track rule.

        With ``hint`` (the current segment) the index only advances: i → i+1 while the along-track
        parameter of p on segment i exceeds its length, or p is closer to segment i+1 than to
        segment i (a vehicle that cuts a corner never passes its end).  Without, the nearest
        segment (clamped projection), ties (e.g. exactly at a corner) going to the later one.
        """
        if hint is None:
            dist = np.array([self.distance(i, p) for i in range(self.n_segments)])
            best = float(dist.min())
            return int(np.flatnonzero(dist <= best + 1e-9)[-1])
        i = int(min(max(hint, 0), self.n_segments - 1))
        while self.passed(i, p):
            i += 1
        return i

    def passed(self, i: int, p) -> bool:
        """Whether p has left segment i for segment i+1 (the advance rule of :meth:`locate`)."""
        if i >= self.n_segments - 1:
            return False
        return self.along(i, p) > self.lengths[i] or self.distance(i + 1, p) < self.distance(i, p)

    def point_at(self, s: float) -> np.ndarray:
        """Point at arc length ``s`` from the start (clamped to the route)."""
        s = min(max(float(s), 0.0), self.length)
        i = int(min(np.searchsorted(self.cum, s, side="right") - 1, self.n_segments - 1))
        return self.a[i] + (s - self.cum[i]) * self.dirs[i]

    def turn_rotation(self, i: int) -> np.ndarray:
        """Rotation mapping the direction of segment i onto that of segment i+1."""
        return _rotation_between(self.dirs[i], self.dirs[i + 1])


# ------------------------------------------------------------------------------------- gates
def chi2_gate(nis: float, m: int, prob: float) -> bool:
    """Standard χ² innovation gate: accept when d² = νᵀS⁻¹ν ≤ χ²_m(prob)."""
    return bool(nis <= stats.chi2.ppf(prob, m))


def paper_gate(nu: np.ndarray, S: np.ndarray, chi: float) -> bool:
    """Zhou et al.'s test (before eq 25): accept when ‖S‖₂ ≥ χ · νᵀν (‖·‖₂ spectral norm)."""
    return bool(np.linalg.norm(S, 2) >= chi * float(nu @ nu))


# ------------------------------------------------------------------------------------ filter
@dataclass(frozen=True)
class RouteOptions:
    """The options of :class:`RouteConstrainedKF`, declared once (meanings there)."""

    r_virtual: float = 1e-4
    virtual: str = "outage"
    turn: str = "project"
    gate: str | None = None
    gate_prob: float = 0.9999
    paper_chi: float | None = None
    gate_virtual: bool = True
    recover_after: int | None = 20
    segment: int | None = None


class RouteConstrainedKF(KF):
    """KF with route pseudo-measurements during outages and an innovation gate.

    Parameters
    ----------
    F, H, Q, R : as :class:`estimators.kf.KF` (H, R: the real sensor); ``x0``, ``P0`` (keywords)
        too.
    route : :class:`Route` or waypoints (K, d).
    pos_idx : indices of the route's d coordinates in the state (e.g. [0, 3, 6] for a 3-D
        Singer/CA state, [0, 2] for x, y of a 3-D CV state with a 2-D route).
    vel_idx, acc_idx : indices of velocity / acceleration (needed for ``turn="rotate"``).
    options : :class:`RouteOptions` (its defaults when omitted); each of its fields may be
        given by name instead (keywords over ``options``):
    r_virtual : variance (m²) of the route pseudo-measurement.
    virtual : "outage" (paper: only when no fix arrives), "always" (also after every fix) or
        "never" (a gated KF).
    turn : "project" (paper) or "rotate" (see the module docstring).
    gate : None, "chi2" or "paper"; ``gate_prob`` the χ² probability, ``paper_chi`` the paper's
        χ (default 1/χ²_m(gate_prob)); ``gate_virtual`` gates the pseudo-measurements too.
    recover_after : after this many consecutive rejected fixes the next fix is fused ungated
        (``None``: never).
    segment : initial active segment (default: located from x0 at the first update).
    """

    def __init__(self, F, H, Q, R, route, pos_idx: Sequence[int],
                 vel_idx: Sequence[int] | None = None, acc_idx: Sequence[int] | None = None, *,
                 options: RouteOptions | None = None, **changes) -> None:
        x0, P0 = changes.pop("x0", None), changes.pop("P0", None)
        o = replace(options or RouteOptions(), **changes)  # TypeError names a bad keyword
        super().__init__(F, H, Q, R, x0=x0, P0=P0)
        self.route = route if isinstance(route, Route) else Route(route)
        d = self.route.dim
        self.pos_idx = np.asarray(pos_idx, dtype=int)
        if self.pos_idx.shape != (d,):
            raise ValueError(f"pos_idx needs {d} indices for a {d}-D route")
        self.vel_idx = None if vel_idx is None else np.asarray(vel_idx, dtype=int)
        self.acc_idx = None if acc_idx is None else np.asarray(acc_idx, dtype=int)
        if o.virtual not in ("outage", "always", "never"):
            raise ValueError(f"virtual must be 'outage', 'always' or 'never', got {o.virtual!r}")
        if o.turn not in ("project", "rotate"):
            raise ValueError(f"turn must be 'project' or 'rotate', got {o.turn!r}")
        if o.turn == "rotate" and self.vel_idx is None:
            raise ValueError("turn='rotate' needs vel_idx")
        if o.gate not in (None, "chi2", "paper"):
            raise ValueError(f"gate must be None, 'chi2' or 'paper', got {o.gate!r}")
        if not o.r_virtual > 0:
            raise ValueError("r_virtual must be > 0")
        self.r_virtual = float(o.r_virtual)
        self.virtual = o.virtual
        self.turn = o.turn
        self.gate = o.gate
        self.gate_prob = float(o.gate_prob)
        self.paper_chi = o.paper_chi
        self.gate_virtual = bool(o.gate_virtual)
        self.recover_after = o.recover_after
        self.segment = o.segment
        self.n_rejected = 0  # consecutive rejected fixes
        self.rejected_fixes = 0
        self.rejected_virtual = 0
        self.last = "none"
        self._thr: dict[int, float] = {}

    # -------------------------------------------------------------------------- helpers
    def position(self) -> np.ndarray:
        return self.x[self.pos_idx]

    def _threshold(self, m: int) -> float:
        if m not in self._thr:
            self._thr[m] = float(stats.chi2.ppf(self.gate_prob, m))
        return self._thr[m]

    def _accept(self, nu: np.ndarray, S: np.ndarray, nis: float) -> bool:
        if self.gate is None:
            return True
        thr = self._threshold(nu.size)
        if self.gate == "chi2":
            return nis <= thr
        chi = self.paper_chi if self.paper_chi is not None else 1.0 / thr
        return paper_gate(nu, S, chi)

    def _fuse(self, z: np.ndarray, H: np.ndarray, R: np.ndarray, gated: bool) -> bool | None:
        """Joseph-form update with (H, R); None: invalid, False: gated out, True: fused."""
        P, x = self.P, self.x
        PHT = _dot(P, H.T)
        S = _dot(H, PHT) + R
        Si = np.linalg.inv(S)
        nu = z - _dot(H, x)
        nis = float(_dot(nu, _dot(Si, nu)))
        if not math.isfinite(nis):
            return None
        if gated and not self._accept(nu, S, nis):
            self.y, self.S, self.nis = nu, S, nis
            return False
        K = _dot(PHT, Si)
        self.x = x + _dot(K, nu)
        self.P = joseph(P, K, H, R)
        self.y, self.S, self.K, self.nis = nu, S, K, nis
        return True

    def _advance(self, rotate: bool) -> int:
        """Update the active segment from the estimate (rotating the state on a switch)."""
        rt = self.route
        if self.segment is None:
            self.segment = rt.locate(self.position())
            return self.segment
        i = self.segment
        while rt.passed(i, self.position()):
            if rotate:
                self._rotate_turn(i)
            i += 1
            self.segment = i
        return i

    def _rotate_turn(self, i: int) -> None:
        """Rotate position about the corner bᵢ, velocity and acceleration onto segment i+1."""
        Rm = self.route.turn_rotation(i)
        n = self.n
        T = np.eye(n)
        x = self.x.copy()
        b = self.route.b[i]
        for idx in (self.pos_idx, self.vel_idx, self.acc_idx):
            if idx is None:
                continue
            T[np.ix_(idx, idx)] = Rm
        x[self.pos_idx] = b + Rm @ (x[self.pos_idx] - b)
        for idx in (self.vel_idx, self.acc_idx):
            if idx is not None:
                x[idx] = Rm @ x[idx]
        self.x = x
        self.P = T @ self.P @ T.T

    def virtual_measurement(self, i: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(y_c, H_c) of segment i (default: the active one): N a = N p."""
        i = self.segment if i is None else i
        if i is None:
            i = self.route.locate(self.position())
        N = self.route.normals[i]
        Hc = np.zeros((N.shape[0], self.n))
        Hc[:, self.pos_idx] = N
        return N @ self.route.a[i], Hc

    # ------------------------------------------------------------------------- interface
    def constrain(self) -> bool:
        """Fuse the route pseudo-measurement of the active segment; True if accepted."""
        self._advance(rotate=self.turn == "rotate")
        yc, Hc = self.virtual_measurement()
        ok = self._fuse(yc, Hc, self.r_virtual * np.eye(yc.size), gated=self.gate_virtual)
        if ok:
            self.last = "virtual"
            return True
        self.rejected_virtual += 1
        self.last = "virtual-rejected"
        return False

    def update(self, z) -> bool:
        """Fuse fix ``z`` (gated); with no fix, fuse the route pseudo-measurement instead."""
        zf = None if z is None else np.asarray(z, dtype=float).reshape(-1)
        if zf is None or not np.all(np.isfinite(zf)):
            if self.virtual != "never":
                self.constrain()
            else:
                self.last = "none"
            return False
        self._advance(rotate=False)
        force = self.recover_after is not None and self.n_rejected >= self.recover_after
        ok = self._fuse(zf, self._H, self._R, gated=not force)
        if ok is None:
            self.last = "none"
            return False
        if not ok:
            self.n_rejected += 1
            self.rejected_fixes += 1
            self.last = "fix-rejected"
            return False
        self.n_rejected = 0
        self.last = "fix"
        if self.virtual == "always":
            y, S, K, nis = self.y, self.S, self.K, self.nis
            self.constrain()
            self.y, self.S, self.K, self.nis = y, S, K, nis
            self.last = "fix"
        return True
