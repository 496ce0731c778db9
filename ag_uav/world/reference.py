"""Time-parameterised flight reference along a :class:`~ag_uav.world.plan.CoveragePlan`.

Construction (all precomputed once; the per-tick lookup is an index plus one fused interpolation):

1. **Geometry.** Waypoints = optional vertical climb from the start point (``z0`` → ``altitude``),
   then the plan's polyline at ``altitude``. At each vertex with deflection φ:
   φ ≥ ``stop_angle_deg`` → a *stop* (rest-to-rest through the corner, the way spray drones fly
   square headland corners); otherwise a circular *fillet* tangent to both edges, with tangent
   length t = min(ℓ_in/2, ℓ_out/2, t_dev), t_dev = e·tan(φ/2)/(sec(φ/2) − 1) so the fillet stays
   within ``max_deviation`` = e of the corner, radius r = t / tan(φ/2). Densely sampled plan arcs
   (U-turn semicircles) thus become chains of arcs of their own radius.
2. **Speed along arc length s.** v_lim(s) = min(cap, sqrt(a_lat/κ(s))), 0 at stops and ends, with
   a_lat = ``lat_frac``·a; a forward and a backward pass with tangential acceleration
   a_t = a (lines) or a·sqrt(1 − lat_frac²) (arcs) give the fastest profile with
   |a| = sqrt(a_t² + a_n²) ≤ a (piecewise-constant s̈ on a ds grid, v² linear in s; the classic
   "forward–backward" time-optimal profile along a fixed path, e.g. Verscheure et al. 2009).
   Each stop has a dwell ``dwell`` ≥ ``jerk_window``.
3. **Jerk limiting.** The raw trajectory p_raw(t) = P(s(t)) has continuous velocity but steps in
   acceleration (profile switches, curvature steps at arc ends). It is smoothed by a moving
   average of width W = ``jerk_window``: p_W(t) = (1/W)∫_{t−W/2}^{t+W/2} p_raw, so
   v_W = (p_raw(t+W/2) − p_raw(t−W/2))/W and a_W = (v_raw(t+W/2) − v_raw(t−W/2))/W: a_W is the
   mean of a_raw over the window, so |a_W| ≤ sup|a_raw| ≤ a, and |jerk| ≤ 2a/W. The price is a
   cut inside curves of ≈ a_n W²/24 (< 1 cm here). Because every stop has a dwell ≥ W, p_W still
   passes exactly through each stop corner at rest, so the velocity stays continuous there.
4. **Outputs** on a grid at ``rate`` Hz (v_W, a_W in closed form from the piecewise-quadratic
   s(t); p_W by trapezoidal integration on a dt/5 grid; P, T interpolated on a 5 cm s-grid). The
   realised max |a| is checked and, should it exceed ``a_max`` (grid effects), the internal limit
   is scaled down and the profile rebuilt.
5. **Yaw** = travel heading (continuous through filleted turns and U-turn arcs; at a stop the
   heading change is spread by a raised-cosine ramp of width ≥ (π/2)|Δψ|/``yaw_rate_max``
   centred on the dwell). The start climb and the end hover hold the adjacent heading.

The sprayer flag is the plan segment's ``spray`` (legs and headland laps on; turns, transits,
climb and end hover off); ``seg`` is the plan segment index, −1 during the climb and end hover.
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np

from numkit import Layout
from numkit.axes import XY, X, Y, Z

from .plan import CoveragePlan

__all__ = ["RefSample", "Reference", "ReferenceOptions"]

#: ticks per piece of the output grid's build (its fine grid: ``_sub`` × this many points)
_CHUNK = 1 << 14
REF_ROW = Layout("pos:3 vel:3 acc:3")  #: a row of the output grid (world ENU)
_POS, _VEL, _ACC = REF_ROW.slice("pos"), REF_ROW.slice("vel"), REF_ROW.slice("acc")
_Line = namedtuple("_Line", "kind a b seg cap stop")  # a primitive of the path: a line a → b
_Arc = namedtuple("_Arc", "kind a c r phi u_in seg0 seg1 cap")  # an arc from a about centre c


class RefSample(NamedTuple):
    """Reference at one time. ``pos``/``vel``/``acc`` are read-only (3,) arrays (views)."""

    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    yaw: float
    yaw_rate: float
    spray: bool
    seg: int


def _unit(v: np.ndarray) -> tuple[np.ndarray, float]:
    n = float(np.linalg.norm(v))
    return (v / n if n > 0 else v * 0.0), n


def _forward_backward(vlim: np.ndarray, two_a_ds: np.ndarray) -> np.ndarray:
    """Fastest speed profile under ``vlim`` with v[0] = 0 and v²[i+1] − v²[i] bounded by
    ``two_a_ds[i]`` (= 2 a_t ds) both ways: a forward pass (accelerate) then a backward one
    (brake). Scalar loops over pieces of :data:`_CHUNK` samples (Python floats, held a piece at
    a time)."""
    n = len(vlim)
    v = np.empty(n)
    v[0] = 0.0
    vi = 0.0
    for a in range(0, n - 1, _CHUNK):
        b = min(n - 1, a + _CHUNK)
        lims, tw = vlim[a + 1:b + 1].tolist(), two_a_ds[a:b].tolist()
        out = [0.0] * (b - a)
        for q in range(b - a):
            w = vi * vi + tw[q]
            lim = lims[q]
            vi = lim if lim * lim <= w else math.sqrt(w)
            out[q] = vi
        v[a + 1:b + 1] = out
    for b in range(n - 1, 0, -_CHUNK):  # indices b-1 … a, with v[b] final
        a = max(0, b - _CHUNK)
        vs, tw = v[a:b + 1].tolist(), two_a_ds[a:b].tolist()
        for q in range(b - a - 1, -1, -1):
            w = vs[q + 1] * vs[q + 1] + tw[q]
            if vs[q] * vs[q] > w:
                vs[q] = math.sqrt(w)
        v[a:b] = vs[:-1]
    return v


@dataclass(frozen=True)
class ReferenceOptions:
    """The options of :class:`Reference`, declared once (module docstring): cruise ``speed``
    (m/s); spray ``altitude`` (m above the ground plane z = 0); ``a_max``, the bound on
    |acceleration| (m/s², horizontal and vertical alike); ``takeoff``: start on the ground at
    ``z0`` (m) below the plan start and climb first at ``climb_speed`` (m/s) at most;
    ``hover_time`` at the end (s); ``rate``, the output grid rate (Hz; ``sample`` interpolates
    linearly between grid points); ``jerk_window``, the moving-average width W of the time law
    (s; jerk ≤ ~2·a_max/W); corners turning by ``stop_angle_deg`` or more are flown
    rest-to-rest; ``max_deviation``, the largest distance a corner fillet may cut from the plan
    (m); ``lat_frac``, the share of ``a_max`` given to centripetal acceleration in curves;
    ``yaw_rate_max``, the yaw rate that sizes the yaw ramps at stops (rad/s); ``ds``, the
    arc-length grid step (m); ``landing``: end with a vertical descent to ``z_land`` (m; a
    little below the body height resting on the skids, so the vehicle settles at a low
    vertical speed) at ``climb_speed``, and at ``land_speed`` (m/s) in the last
    ``flare_height`` metres, with a stop in between (the descent, like the climb, has ``seg``
    −1 and no spray); ``seg_speeds``: optional per-plan-segment speed caps (m/s; None =
    ``speed``), e.g. a faster transit to and from the base.
    """

    speed: float = 5.0
    altitude: float = 3.0
    a_max: float = 1.5
    takeoff: bool = True
    climb_speed: float = 1.5
    hover_time: float = 5.0
    z0: float = 0.0
    rate: float = 100.0
    jerk_window: float = 0.3
    stop_angle_deg: float = 60.0
    max_deviation: float = 0.25
    lat_frac: float = 0.7
    yaw_rate_max: float = math.radians(90.0)
    ds: float = 0.05
    landing: bool = False
    z_land: float = 0.0
    land_speed: float = 0.3
    flare_height: float = 0.6
    seg_speeds: list[float | None] | None = None


class Reference:
    """Smooth, flyable reference along a coverage plan (see module docstring).

    Args:
        plan: the coverage plan.
        options: the options (:class:`ReferenceOptions`; its defaults when omitted).
        **changes: any :class:`ReferenceOptions` field by name, over ``options`` (an unknown
            name is a TypeError).
    """

    def __init__(self, plan: CoveragePlan, options: ReferenceOptions | None = None,
                 **changes: Any) -> None:
        o = replace(options or ReferenceOptions(), **changes)
        for nm, val in (("speed", o.speed), ("a_max", o.a_max), ("rate", o.rate),
                        ("climb_speed", o.climb_speed), ("ds", o.ds)):
            if not (math.isfinite(val) and val > 0):
                raise ValueError(f"{nm} must be > 0, got {val}")
        if o.jerk_window < 0 or o.hover_time < 0:
            raise ValueError("jerk_window and hover_time must be ≥ 0")
        self.plan = plan
        self.speed = float(o.speed)
        self.altitude = float(o.altitude)
        self.a_max = float(o.a_max)
        self.rate = float(o.rate)
        self.dt = 1.0 / self.rate
        self._sub = 5
        step = 2.0 * self.dt / self._sub
        self.window = round(float(o.jerk_window) / step) * step
        self.dwell = max(1.2 * self.window, 0.2)
        self.hover_time = float(o.hover_time)
        self.lat_frac = float(o.lat_frac)
        self.yaw_rate_max = float(o.yaw_rate_max)
        self._ds = float(o.ds)
        self._landing = bool(o.landing)
        self._z_land = float(o.z_land)
        self._land_speed = float(o.land_speed)
        self._flare = float(o.flare_height)
        self._seg_speeds = o.seg_speeds
        self._build_geometry(o.takeoff, float(o.z0), float(o.climb_speed),
                             math.radians(o.stop_angle_deg), float(o.max_deviation))
        a_int = self.a_max
        for _ in range(6):
            self._build_time_law(a_int)
            self._build_outputs()
            amax = self._max_norm(_ACC)
            if amax <= self.a_max * (1.0 + 1e-6):
                break
            a_int *= 0.995 * self.a_max / amax
        self.a_internal = a_int
        self._finalise()

    # ------------------------------------------------------------------ geometry
    def _build_geometry(self, takeoff, z0, climb_speed, stop_angle, max_dev):
        """The path: its vertices, the lines and rounded corners between them (stops where
        the turn is sharper than ``stop_angle`` or the path climbs), the dense arc-length grid
        and the heading along it."""
        P, eseg, ecap = self._vertices(takeoff, z0, climb_speed)
        prims = self._primitives(P, eseg, ecap, stop_angle, max_dev)
        # dense arc-length samples; every primitive contributes both end points (duplicates at
        # junctions carry the tangent/curvature of each side). Sized first, then written.
        self._dense(prims)
        self.length = float(self._s[-1])
        self._heading()

    def _vertices(self, takeoff, z0, climb_speed) -> tuple[np.ndarray, list[int], list[float]]:
        """The path's vertices (take-off, the plan's points at altitude, the landing), each
        edge's plan segment (−1: climb or descent) and speed cap."""
        plan = self.plan
        pts: list[np.ndarray] = []
        eseg: list[int] = []
        ecap: list[float] = []
        s0 = plan.segments[0].points[0]
        if takeoff:
            pts += [np.array([s0[0], s0[1], z0]), np.array([s0[0], s0[1], self.altitude])]
            eseg.append(-1)
            ecap.append(climb_speed)
        else:
            pts.append(np.array([s0[0], s0[1], self.altitude]))
        speeds = self._seg_speeds or [None] * len(plan.segments)
        for j, seg in enumerate(plan.segments):
            cap_j = self.speed if speeds[j] is None else float(speeds[j])
            for q in seg.points:
                p = np.array([q[0], q[1], self.altitude])
                if np.linalg.norm(p - pts[-1]) > 1e-6:
                    pts.append(p)
                    eseg.append(j)
                    ecap.append(cap_j)
        if self._landing:
            z_flare = self._z_land + self._flare
            if pts[-1][Z] > z_flare + 1e-6:
                pts.append(np.array([pts[-1][X], pts[-1][Y], z_flare]))
                eseg.append(-1)
                ecap.append(climb_speed)
            pts.append(np.array([pts[-1][0], pts[-1][1], self._z_land]))
            eseg.append(-1)
            ecap.append(self._land_speed)
        return np.array(pts), eseg, ecap

    def _primitives(self, P: np.ndarray, eseg: list[int], ecap: list[float], stop_angle: float,
                    max_dev: float) -> list[tuple]:
        """Lines and corner arcs through the vertices ``P`` (sets :attr:`n_stops`)."""
        n = len(P)
        if n < 2:
            raise ValueError("plan path is degenerate")
        prims: list[tuple] = []
        cur = P[0]
        n_stops = 0
        for i in range(1, n - 1):
            u_in, l_in = _unit(P[i] - P[i - 1])
            u_out, l_out = _unit(P[i + 1] - P[i])
            phi = math.acos(max(-1.0, min(1.0, float(u_in @ u_out))))
            if phi < 1e-7:
                prims.append(_Line("line", cur, P[i], eseg[i - 1], ecap[i - 1], False))
                cur = P[i]
                continue
            if phi >= stop_angle or u_in[Z] != 0.0 or u_out[Z] != 0.0:
                prims.append(_Line("line", cur, P[i], eseg[i - 1], ecap[i - 1], True))
                cur = P[i]
                n_stops += 1
                continue
            half = 0.5 * phi
            t_dev = max_dev * math.tan(half) / (1.0 / math.cos(half) - 1.0)
            t = min(0.5 * l_in, 0.5 * l_out, t_dev)
            r = t / math.tan(half)
            a_pt = P[i] - t * u_in
            prims.append(_Line("line", cur, a_pt, eseg[i - 1], ecap[i - 1], False))
            bis, _ = _unit(u_out - u_in)
            c = P[i] + bis * (r / math.cos(half))
            prims.append(_Arc("arc", a_pt, c, r, phi, u_in, eseg[i - 1], eseg[i],
                              min(ecap[i - 1], ecap[i])))
            cur = P[i] + t * u_out
        prims.append(_Line("line", cur, P[-1], eseg[-1], ecap[-1], True))
        self.n_stops = n_stops
        return prims

    def _heading(self) -> None:
        """The heading along s (unwrapped): its jump-free part and the jumps at stops."""
        txy = self._T[:, XY]
        nrm = np.hypot(txy[:, 0], txy[:, 1])
        psi = np.full(len(nrm), np.nan)
        ok = nrm > 1e-6
        psi[ok] = np.arctan2(txy[ok, 1], txy[ok, 0])
        if not np.any(ok):
            psi[:] = 0.0
        else:  # fill vertical parts (climb) with the nearest following/previous heading
            idx = np.where(ok, np.arange(len(psi)), len(psi))
            nxt = np.minimum.accumulate(idx[::-1])[::-1]
            fill = ~ok & (nxt < len(psi))
            psi[fill] = psi[nxt[fill]]
            idx2 = np.where(ok | fill, np.arange(len(psi)), -1)
            prv = np.maximum.accumulate(idx2)
            psi[np.isnan(psi)] = psi[prv[np.isnan(psi)]]
        psi = np.unwrap(psi)
        # jumps happen only across zero-length (duplicate) intervals at stop vertices
        dpsi = np.diff(psi)
        dsv = np.diff(self._s)
        jump = (dsv < 1e-12) & (np.abs(dpsi) > 1e-9)
        jump_idx = np.where(jump)[0]
        self._jump_s = self._s[jump_idx]
        self._jump_d = dpsi[jump_idx]
        corr = np.concatenate([[0.0], np.cumsum(np.where(jump, dpsi, 0.0))])
        self._psi_smooth = psi - corr
        self._psi0 = float(psi[0])

    def _dense(self, prims: list[tuple]) -> None:
        """The arc-length grid (step ≤ ``ds``) of the primitives: s, P, T, K, speed cap, plan
        segment, stop flag, in arrays of the total size (no per-primitive copies)."""
        ds = self._ds
        sized: list[tuple[tuple, float, int]] = []  # (primitive, length, m); m < 0: no samples
        for pr in prims:
            ln = _unit(pr.b - pr.a)[1] if pr.kind == "line" else pr.r * pr.phi  # length
            m = -1 if pr.kind == "line" and ln < 1e-9 else max(2, math.ceil(ln / ds))
            sized.append((pr, ln, m))
        n = sum(m + 1 for _, _, m in sized if m > 0)
        S, P, T, K = np.empty(n), np.empty((n, 3)), np.empty((n, 3)), np.zeros((n, 3))
        cap, seg, stop = np.empty(n), np.empty(n, dtype=int), np.zeros(n, bool)
        s_acc = 0.0
        k = 0
        for pr, ln, m in sized:
            if m < 0:  # a zero-length line: its stop flag goes to the previous sample
                if pr.stop and k:
                    stop[k - 1] = True
                continue
            sl = slice(k, k + m + 1)
            if pr.kind == "line":
                _, a, b, sg, cp, st = pr
                f = np.linspace(0.0, 1.0, m + 1)
                S[sl] = s_acc + f * ln
                P[sl] = a + f[:, None] * (b - a)
                T[sl] = _unit(b - a)[0]
                seg[sl] = sg
                stop[k + m] = st
            else:
                _, a, c, r, phi, u_in, sg0, sg1, cp = pr
                th = np.linspace(0.0, phi, m + 1)
                e1 = (a - c) / r
                cth, sth = np.cos(th)[:, None], np.sin(th)[:, None]
                pos = c + r * (cth * e1 + sth * u_in)
                S[sl] = s_acc + th * r
                P[sl] = pos
                T[sl] = -sth * e1 + cth * u_in
                K[sl] = (c - pos) / (r * r)
                seg[sl] = np.where(th < 0.5 * phi, sg0, sg1)
            cap[sl] = cp
            s_acc += ln
            k += m + 1
        stop[0] = stop[-1] = True
        self._s, self._P, self._T, self._K, self._dP = S, P, T, K, P[1:] - P[:-1]
        self._cap, self._seg_s, self._stop = cap, seg, stop

    # ------------------------------------------------------------------ time law
    def _build_time_law(self, a_int: float):
        s, K, cap, stop = self._s, self._K, self._cap, self._stop
        kap = np.linalg.norm(K, axis=1)
        a_lat = self.lat_frac * a_int
        with np.errstate(divide="ignore"):
            vlim = np.minimum(cap, np.where(kap > 1e-12, np.sqrt(a_lat / np.maximum(kap, 1e-300)),
                                            np.inf))
        vlim[stop] = 0.0
        ds = np.diff(s)
        curved = (kap[:-1] > 1e-12) | (kap[1:] > 1e-12)
        at = np.where(curved, a_int * math.sqrt(max(1.0 - self.lat_frac**2, 0.01)), a_int)
        v_arr = _forward_backward(vlim, 2.0 * at * ds)
        # per-interval acceleration and duration
        with np.errstate(divide="ignore", invalid="ignore"):
            dv2 = v_arr[1:] ** 2 - v_arr[:-1] ** 2
            acc = np.where(ds > 0, dv2 / (2.0 * np.maximum(ds, 1e-300)), 0.0)
            vsum = v_arr[:-1] + v_arr[1:]
            dur = np.where(ds > 0, 2.0 * ds / np.maximum(vsum, 1e-300), 0.0)
        bad = (ds > 0) & (vsum < 1e-9)
        if np.any(bad):  # two stops one grid step apart: rest-to-rest at a_t
            dur[bad] = 2.0 * np.sqrt(ds[bad] / at[bad])
            acc[bad] = 0.0
        dwell = np.where(stop[:-1], self.dwell, 0.0)
        dwell[0] = self.window  # rest before the first move
        # knots: node i reached at tk[i]; departs at tk[i] + dwell[i]
        tk = np.concatenate([[0.0], np.cumsum(dwell + dur)])
        self._tk, self._tdep, self._v, self._acc_i = tk, tk[:-1] + dwell, v_arr, acc
        # integral of s over time, at knots
        tau = dur
        seg_int = (s[:-1] * (dwell + tau) + v_arr[:-1] * tau**2 / 2 + acc * tau**3 / 6)
        self._Sk = np.concatenate([[0.0], np.cumsum(seg_int)])
        self._t_end_raw = float(tk[-1])
        self.duration = self._t_end_raw + 0.5 * self.window + self.hover_time

    def _raw(self, t: np.ndarray, pos_only: bool = False):
        """s, ṡ and ∫s dt of the un-smoothed time law (vectorised; clamps outside), or s."""
        tk, s = self._tk, self._s
        t = np.asarray(t, float)
        i = np.clip(np.searchsorted(tk, t, side="right") - 1, 0, len(tk) - 2)
        tc = np.clip(t, 0.0, None)
        tau = np.clip(tc - self._tdep[i], 0.0, None)
        dur = tk[i + 1] - self._tdep[i]
        tau = np.minimum(tau, dur)
        si, vi, ai = s[i], self._v[i], self._acc_i[i]
        pos = si + vi * tau + 0.5 * ai * tau**2
        after, before = t > tk[-1], t < 0   # beyond the ends: at rest at s_end (s_0)
        if any_after := np.any(after):
            pos = np.where(after, s[-1], pos)
        if any_before := np.any(before):
            pos = np.where(before, s[0], pos)
        if pos_only:
            return pos
        vel = np.where(after | before, 0.0, vi + ai * tau)
        dw = np.minimum(tc - tk[i], self._tdep[i] - tk[i])
        integ = self._Sk[i] + si * dw + si * tau + vi * tau**2 / 2 + ai * tau**3 / 6
        if any_after:
            integ = np.where(after, self._Sk[-1] + s[-1] * (t - tk[-1]), integ)
        if any_before:
            integ = np.where(before, s[0] * t, integ)
        return pos, vel, integ

    def _smoothed(self, t: np.ndarray):
        w = self.window
        if w <= 0:
            pos, vel, _ = self._raw(t)
            i = np.clip(np.searchsorted(self._tk, t, side="right") - 1, 0, len(self._tk) - 2)
            moving = (t > self._tdep[i]) & (t <= self._tk[-1])
            return pos, vel, np.where(moving, self._acc_i[i], 0.0)
        (p1, v1, i1), (p0, v0, i0) = self._raw(t + 0.5 * w), self._raw(t - 0.5 * w)
        return (i1 - i0) / w, (p1 - p0) / w, (v1 - v0) / w

    def _interp_s(self, sq: np.ndarray):
        s = self._s
        i = np.clip(np.searchsorted(s, sq, side="right") - 1, 0, len(s) - 2)
        h = s[i + 1] - s[i]
        f = np.where(h > 0, (sq - s[i]) / np.where(h > 0, h, 1.0), 0.0)
        f = np.clip(f, 0.0, 1.0)[:, None]
        return i, f

    # ------------------------------------------------------------------ outputs
    def _path_at(self, sq: np.ndarray, tangent: bool = True):
        """Position P(s) and unit tangent T(s) (or None) by interpolation on the s-grid."""
        i, f = self._interp_s(np.clip(sq, 0.0, self.length))
        P = self._P[i] + f * self._dP[i]
        if not tangent:
            return P, None
        T = self._T[i] + f * (self._T[i + 1] - self._T[i])
        T /= np.maximum(np.linalg.norm(T, axis=1, keepdims=True), 1e-12)
        return P, T

    def _build_outputs(self):
        """Box-filter the raw 3-D trajectory p_raw(t) = P(s(t)) over the window W:
        p_W = (1/W)∫p_raw, v_W = (p_raw(t+W/2) − p_raw(t−W/2))/W,
        a_W = (v_raw(t+W/2) − v_raw(t−W/2))/W. Hence |a_W| ≤ sup|a_raw| ≤ a and |jerk| ≤ 2a/W.

        Computed in pieces of :data:`_CHUNK` ticks (the running integral of p_raw carried from
        one piece to the next), so the working memory is bounded whatever the mission's length;
        what is kept is the output grid itself (pos, vel, acc; the plan segment and the smooth
        part of the yaw)."""
        self._n = n = int(math.floor(self.duration * self.rate + 1e-9)) + 1
        self._R = np.empty((n, REF_ROW.size))
        self._seg = np.empty(n, dtype=np.int32)   # plan segment (−1: climb, end hover)
        self._yaw_u = np.empty(n)
        carry = np.zeros(3)
        for a in range(0, n, _CHUNK):
            b = min(n, a + _CHUNK)
            t = np.arange(a, b) * self.dt
            if self.window <= 0:
                sw = self._outputs_unsmoothed(t, a, b)
            else:
                sw, carry = self._outputs_smoothed(t, a, b, carry)
            self._progress(sw, a, b)

    def _outputs_unsmoothed(self, t: np.ndarray, a: int, b: int) -> np.ndarray:
        """W = 0: p, v, a of the raw time law on ticks [a, b); returns the arc length."""
        sr, vr, _ = self._raw(t)
        P, T = self._path_at(sr)
        i, f = self._interp_s(np.clip(sr, 0.0, self.length))
        K = self._K[i] + f * (self._K[i + 1] - self._K[i])
        j = np.clip(np.searchsorted(self._tk, t, side="right") - 1, 0, len(self._tk) - 2)
        moving = (t > self._tdep[j]) & (t <= self._tk[-1])
        ar = np.where(moving, self._acc_i[j], 0.0)
        self._R[a:b, _POS] = P
        self._R[a:b, _VEL] = vr[:, None] * T  # v = ṡ T
        self._R[a:b, _ACC] = ar[:, None] * T + (vr**2)[:, None] * K  # a = s̈ T + ṡ² K
        return np.clip(sr, 0.0, self.length)

    def _outputs_smoothed(self, t: np.ndarray, a: int, b: int,
                          carry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """p_W, v_W, a_W on ticks [a, b). p_W by trapezoidal integration on a fine grid of step
        dt/m (W/2 is a whole number nh of steps): with C(j) = ∫ p_raw up to fine point j,
        p_W(k) = (C(km + 2nh) − C(km))/W; ``carry`` is C(am), the next piece's is C(bm).
        Returns the box-averaged arc length (progress, for segment, spray and yaw) and C(bm)."""
        w = self.window
        h = 0.5 * w
        sp, vp, ip = self._raw(t + h)
        sm, vm, im = self._raw(t - h)
        Pp, Tp = self._path_at(sp)
        Pm, Tm = self._path_at(sm)
        self._R[a:b, _VEL] = (Pp - Pm) / w  # v_W = (p(t + W/2) − p(t − W/2)) / W
        self._R[a:b, _ACC] = (vp[:, None] * Tp - vm[:, None] * Tm) / w  # a_W likewise from v
        m = self._sub
        dtf = self.dt / m
        nh = int(round(h / dtf))
        hi = max((b - 1) * m + 2 * nh, b * m)  # fine points a·m … hi
        tf = np.arange(a * m - nh, hi - nh + 1) * dtf
        Pf, _ = self._path_at(self._raw(tf, pos_only=True), tangent=False)
        cum = np.cumsum(np.vstack([carry[None], 0.5 * (Pf[1:] + Pf[:-1]) * dtf]), axis=0)
        k = np.arange(b - a) * m
        self._R[a:b, _POS] = (cum[k + 2 * nh] - cum[k]) / (2 * nh * dtf)
        sw = (ip - im) / w   # _smoothed(t)'s progress, from the same two raw samples
        return np.clip(sw, 0.0, self.length), cum[(b - a) * m].copy()

    def _progress(self, sw: np.ndarray, a: int, b: int) -> None:
        """Plan segment and the smooth part of the yaw on ticks [a, b) from the progress sw."""
        i, _ = self._interp_s(sw)
        seg = self._seg_s[i]
        seg[sw >= self.length - 1e-9] = -1
        self._seg[a:b] = seg
        f = np.clip((sw - self._s[i]) / np.maximum(self._s[i + 1] - self._s[i], 1e-12), 0, 1)
        self._yaw_u[a:b] = self._psi_smooth[i] + f * (self._psi_smooth[i + 1]
                                                      - self._psi_smooth[i])

    def _max_norm(self, cols: slice, diff: bool = False) -> float:
        """max over the grid of |R[:, cols]| (or of its first difference / dt), piece by
        piece."""
        out = 0.0
        for a in range(0, self._n, _CHUNK):
            x = self._R[a:min(self._n, a + _CHUNK + (1 if diff else 0)), cols]
            if diff:
                x = np.diff(x, axis=0) / self.dt
            if len(x):
                out = max(out, float(np.max(np.linalg.norm(x, axis=1))))
        return out

    def _finalise(self):
        n, seg = self._n, self._seg
        spray_of = np.array([s.spray for s in self.plan.segments] + [False], bool)
        self._spray = spray_of[seg]  # seg == -1 picks the trailing False
        # yaw: smooth part + raised-cosine ramps at stops
        yaw = self._yaw_u
        if len(self._jump_s):
            # time at the middle of each stop's dwell (raw time law, symmetric under smoothing)
            node = np.searchsorted(self._s, self._jump_s, side="left")
            tmid = 0.5 * (self._tk[node] + self._tdep[node])
            for tm, d in zip(tmid.tolist(), self._jump_d.tolist(), strict=True):
                wk = max(0.5, 0.5 * math.pi * abs(d) / self.yaw_rate_max)
                j0 = max(0, int((tm - 0.5 * wk) * self.rate))
                j1 = min(n, int((tm + 0.5 * wk) * self.rate) + 2)
                x = np.clip((np.arange(j0, j1) * self.dt - (tm - 0.5 * wk)) / wk, 0.0, 1.0)
                yaw[j0:j1] += d * (0.5 - 0.5 * np.cos(math.pi * x))
                yaw[j1:] += d
        self._R.setflags(write=False)
        self.max_acc, self.max_speed = self._max_norm(_ACC), self._max_norm(_VEL)
        self.max_jerk = self._max_norm(_ACC, diff=True) if n > 1 else 0.0
        # the arc-length grid and the time law are not needed once the grid is built
        for name in ("_s", "_P", "_dP", "_T", "_K", "_cap", "_stop", "_seg_s", "_psi_smooth", "_tk",
                     "_tdep", "_v", "_acc_i", "_Sk"):
            setattr(self, name, None)

    # ------------------------------------------------------------------ public API
    @property
    def times(self) -> np.ndarray:
        """Output grid times (s)."""
        return np.arange(self._n) * self.dt

    @property
    def positions(self) -> np.ndarray:
        return self._R[:, _POS]

    @property
    def velocities(self) -> np.ndarray:
        return self._R[:, _VEL]

    @property
    def accelerations(self) -> np.ndarray:
        return self._R[:, _ACC]

    @property
    def yaws(self) -> np.ndarray:
        """Yaw on the grid, wrapped to [-π, π)."""
        return (self._yaw_u + math.pi) % (2 * math.pi) - math.pi

    @property
    def spray_flags(self) -> np.ndarray:
        return self._spray

    @property
    def seg_indices(self) -> np.ndarray:
        return self._seg

    @property
    def initial_position(self) -> np.ndarray:
        return self._R[0, _POS].copy()

    @property
    def nbytes(self) -> int:
        """Bytes held by the output grid (what the reference keeps after it is built)."""
        return int(self._R.nbytes + self._yaw_u.nbytes + self._seg.nbytes + self._spray.nbytes)

    def _yaw_rate_at(self, j: np.ndarray | int) -> np.ndarray:
        """``np.gradient(yaw, dt)`` at the grid points ``j``, worked out where asked (not kept)."""
        j, n = np.asarray(j), self._n
        hi, lo = np.minimum(j + 1, n - 1), np.maximum(j - 1, 0)
        end = (j == 0) | (j == n - 1)
        return (self._yaw_u[hi] - self._yaw_u[lo]) / np.where(end, self.dt, 2.0 * self.dt)

    def sample(self, t: float) -> RefSample:
        """Reference at time ``t`` (s); clamps to [0, duration]. Linear interpolation between
        grid points for pos/vel/acc/yaw; nearest grid point for spray/seg/yaw_rate."""
        x = t * self.rate
        if x <= 0.0:
            i, f = 0, 0.0
        elif x >= self._n - 1:
            i, f = self._n - 1, 0.0
        else:
            i = int(x)
            f = x - i
        if f > 1.0 - 1e-6:  # snap to the grid (times accumulated as t += dt drift slightly)
            i, f = i + 1, 0.0
        if f < 1e-6:
            row = self._R[i]
            yaw = float((self._yaw_u[i] + math.pi) % (2 * math.pi) - math.pi)
        else:
            row = self._R[i] + f * (self._R[i + 1] - self._R[i])
            y0, y1 = float(self._yaw_u[i]), float(self._yaw_u[i + 1])
            yu = y0 + f * (y1 - y0)
            yaw = (yu + math.pi) % (2 * math.pi) - math.pi
        j = i + 1 if f >= 0.5 else i
        return RefSample(row[_POS], row[_VEL], row[_ACC], yaw, float(self._yaw_rate_at(j)),
                         bool(self._spray[j]), int(self._seg[j]))

    def sample_all(self, times) -> dict[str, np.ndarray]:
        """Vectorised :meth:`sample`: dict of arrays pos (N,3), vel, acc, yaw, yaw_rate, spray,
        seg."""
        x = np.clip(np.asarray(times, float) * self.rate, 0.0, self._n - 1)
        i = np.minimum(np.floor(x).astype(int), self._n - 1)
        f = (x - i)[:, None]
        i1 = np.minimum(i + 1, self._n - 1)
        r0 = self._R[i]
        row = r0 + f * (self._R[i1] - r0)
        j = np.minimum(np.where(f[:, 0] >= 0.5, i + 1, i), self._n - 1)
        yu = self._yaw_u[i] + f[:, 0] * (self._yaw_u[i1] - self._yaw_u[i])
        return {
            "pos": row[:, _POS],
            "vel": row[:, _VEL],
            "acc": row[:, _ACC],
            "yaw": (yu + math.pi) % (2 * math.pi) - math.pi,
            "yaw_rate": self._yaw_rate_at(j),
            "spray": self._spray[j],
            "seg": self._seg[j].astype(np.int64),
        }

    def cross_track(self, points_xy, seg_idx) -> np.ndarray:
        """Signed horizontal distance (m) of ``points_xy`` (N, 2+) from the planned polyline of
        segment ``seg_idx`` (int, or (N,) ints); positive = left of the direction of travel.
        NaN where ``seg_idx`` is −1 (climb / end hover)."""
        return cross_track(self.plan, points_xy, seg_idx)

    def spray_stretches(self) -> list[np.ndarray]:
        """The reference's own spraying stretches (xy polylines), e.g. for a nominal coverage."""
        sp = self._spray
        out = []
        edges = np.flatnonzero(np.diff(np.concatenate([[0], sp.astype(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if b - a >= 1:
                out.append(self._R[a:b, _POS][:, XY])
        return out

    def summary(self) -> str:
        return (f"reference: {self.duration:.1f} s, path {self.length:.0f} m, "
                f"max |v| {self.max_speed:.2f} m/s, max |a| {self.max_acc:.3f} m/s², "
                f"max |j| {self.max_jerk:.2f} m/s³, {self.n_stops} stops")


def cross_track(plan: CoveragePlan, points_xy, seg_idx) -> np.ndarray:
    """Signed distance of points to the polyline of plan segment(s) ``seg_idx`` (left > 0)."""
    q = np.atleast_2d(np.asarray(points_xy, float))[:, XY]
    n = len(q)
    segs = np.broadcast_to(np.asarray(seg_idx, int), (n,))
    out = np.full(n, np.nan)
    for k in np.unique(segs):
        if k < 0 or k >= len(plan.segments):
            continue
        m = segs == k
        pts = plan.segments[int(k)].points
        a, b = pts[:-1], pts[1:]
        ab = b - a
        l2 = np.einsum("ij,ij->i", ab, ab)
        l2 = np.where(l2 > 0, l2, 1.0)
        qq = q[m][:, None, :]
        tpar = np.clip(np.einsum("nij,ij->ni", qq - a[None], ab) / l2, 0.0, 1.0)
        proj = a[None] + tpar[..., None] * ab[None]
        d = qq - proj
        dist2 = np.einsum("nij,nij->ni", d, d)
        j = np.argmin(dist2, axis=1)
        r = np.arange(len(j))
        cr = ab[j, 0] * (qq[r, 0, 1] - a[j, 1]) - ab[j, 1] * (qq[r, 0, 0] - a[j, 0])
        out[m] = np.sign(cr) * np.sqrt(dist2[r, j])
    return out

