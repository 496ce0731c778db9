"""Bridging GPS outages with the coverage path: route-constrained estimation in the loop.

:class:`RouteConstrainedFeedback` is an :class:`~ag_uav.navigation.estimation.EstimatorFeedback`
with one more filter, ``"route-kf"`` (:class:`estimators.route.RouteConstrainedKF`), that knows the
planned coverage path (:attr:`ag_uav.world.plan.CoveragePlan.path`, the 2-D polyline of all
segments). While fixes arrive it is the plain KF of the bank (same model, R, IMU-aided prediction;
no gate, no pseudo-measurements), so it differs from ``"kf"`` only during outages.  When no fix has
arrived for ``outage_after_s`` (default 0.5 s, five missed fixes at 10 Hz) it fuses, every
control tick, the pseudo-measurement "the horizontal position is on the active planned segment"
(normal offset 0, variance ``r_virtual``; Zhou et al. 2024's virtual sensor), the segment being
tracked from take-off by the along-track rule.  Height is not constrained (the radar altimeter
or the IMU carries it).  The pseudo-measurement is χ²-gated (p = 0.9999), so if the vehicle is
really off the path the filter ignores the path instead of dragging the estimate onto it.

``route-kf`` can be the primary (what the controller flies on: ``primary="route-kf"``) or a
shadow scored beside the others.  :class:`OutageGps` forces deterministic outage windows
(e.g. 10 s on a sweep leg) on top of the configured GPS sensor;
:func:`ag_uav.jobs.experiments.outage.leg_outage` picks such a window from the mission's reference;
:func:`outage_cross_track` scores a run.

Usage (not wired into ``simulate``'s config; pass it as the feedback)::

    fb = RouteConstrainedFeedback.for_config(cfg, primary="route-kf", outages=[(40.0, 50.0)])
    res = simulate(cfg, feedback=fb)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from estimators.route import Route, RouteConstrainedKF
from numkit import X, Y, Z

from ..config import Config
from ..seeds import seed_sequences
from ..world.mission import build_field, build_plan
from ..world.plan import CoveragePlan
from .estimation import EstimatorFeedback

__all__ = ["OutageGps", "RouteConstrainedFeedback", "outage_cross_track", "plan_for"]

ROUTE_NAME = "route-kf"


class OutageGps:
    """Wraps a :class:`~ag_uav.vehicle.gps.GpsSensor`: no fixes inside the given [t0, t1) windows.

    The wrapped sensor is still called every tick (its error stream advances as without the
    outage), so runs with and without the forced outage share all other random draws.
    """

    def __init__(self, gps: Any, windows: Sequence[tuple[float, float]]) -> None:
        self.gps = gps
        self.windows = [(float(a), float(b)) for a, b in windows]

    def __getattr__(self, name: str) -> Any:
        return getattr(self.gps, name)

    def in_outage(self, t: float) -> bool:
        return any(a <= t < b for a, b in self.windows)

    def measure(self, t: float, p_true_xyz) -> np.ndarray | None:
        z = self.gps.measure(t, p_true_xyz)
        return None if self.in_outage(t) else z


def plan_for(cfg: Config) -> CoveragePlan:
    """The coverage plan ``simulate(cfg)`` flies (same field and planner call)."""
    return build_plan(cfg, build_field(cfg))


class RouteConstrainedFeedback(EstimatorFeedback):
    """EstimatorFeedback + a route-constrained KF fed the coverage path during outages.

    Parameters
    ----------
    cfg, seed, altimeter_seed, imu_seed : as :class:`EstimatorFeedback`.
    plan : the coverage plan (its ``path`` is the route).
    primary : what the controller flies on: ``cfg.estimator.name`` (default) or "route-kf".
    outages : forced GPS outage windows [(t0, t1), ...] in sim seconds.
    r_virtual : pseudo-measurement variance (m²); default (0.3 m)², about the cross-track
        tracking error of the vehicle on a leg.
    outage_after_s : fix timeout after which the route is used.
    """

    def __init__(self, cfg: Config, seed: np.random.SeedSequence,
                 altimeter_seed: np.random.SeedSequence | None = None,
                 imu_seed: np.random.SeedSequence | None = None, *, plan: CoveragePlan,
                 primary: str | None = None, outages: Sequence[tuple[float, float]] = (),
                 r_virtual: float = 0.09, outage_after_s: float = 0.5,
                 gate_prob: float = 0.9999) -> None:
        super().__init__(cfg, seed, altimeter_seed, imu_seed)
        if outages:
            self.gps = OutageGps(self.gps, outages)
        self.route = Route(plan.path)
        base = self._template()
        pi, vi = base.model.pos_idx, base.model.vel_idx
        rf = RouteConstrainedKF(base.F, base.H, base.Q, base.R, self.route,
                                [int(pi[0]), int(pi[1])], [int(vi[0]), int(vi[1])],
                                r_virtual=r_virtual, virtual="never", gate_virtual=True,
                                gate=None, gate_prob=gate_prob, recover_after=None, segment=0,
                                x0=base.x, P0=base.P)
        self.route_filter = rf
        self.filters[ROUTE_NAME] = rf
        if ROUTE_NAME not in self.names:
            self.names.append(ROUTE_NAME)
        self.est[ROUTE_NAME] = []
        self.upd_ns[ROUTE_NAME] = 0
        self.n_upd[ROUTE_NAME] = 0
        self.cons[ROUTE_NAME] = []
        if primary is not None:
            if primary not in self.filters and primary != "true":
                raise ValueError(f"primary {primary!r}: not one of {list(self.filters)}")
            self.primary = self.name = primary
        self.outage_after_s = float(outage_after_s)
        self.gate_prob = float(gate_prob)
        self.n_virtual = 0
        self.n_virtual_rejected = 0
        self._last_fix_t: float | None = None

    @classmethod
    def for_config(cls, cfg: Config, **kw) -> RouteConstrainedFeedback:
        """Build with the same seed streams and plan as ``simulate(cfg)`` would use."""
        ss = seed_sequences(cfg.seed)
        plan = kw.pop("plan", None) or plan_for(cfg)
        return cls(cfg, ss["gps"], ss["altimeter"], ss["imu"], plan=plan, **kw)

    def _template(self):
        """A KF of the bank with this run's model (F, H, Q, R) to copy into the route filter."""
        from .estimation import make_filter

        return make_filter("kf", self.cfg, self.r_diag)

    def _init(self, z: np.ndarray) -> None:
        super()._init(z)
        self._last_fix_t = None

    def update(self, t, p_true, v_true, imu=None):
        n_fix = len(self.fixes)
        p, v = super().update(t, p_true, v_true, imu)
        if len(self.fixes) > n_fix:
            self._last_fix_t = t
            return p, v
        rf = self.route_filter
        if not self.initialised or self._last_fix_t is None:
            return p, v
        if t - self._last_fix_t < self.outage_after_s:
            return p, v
        # outage: fuse the planned path (gated) — after the bank's predict + IMU input
        rf.gate = "chi2"
        ok = rf.constrain()
        rf.gate = None
        self.n_virtual += 1
        self.n_virtual_rejected += 0 if ok else 1
        x = rf.x
        pi, vi = self.pos_idx, self.vel_idx
        pos = (float(x[pi[X]]), float(x[pi[Y]]), float(x[pi[Z]]))
        if self.est[ROUTE_NAME]:
            self.est[ROUTE_NAME][-1] = pos
        if self.primary == ROUTE_NAME:
            return pos, (float(x[vi[X]]), float(x[vi[Y]]), float(x[vi[Z]]))
        return p, v

    def summary(self) -> dict[str, Any]:
        out = super().summary()
        out.update(route_virtual_updates=self.n_virtual,
                   route_virtual_rejected=self.n_virtual_rejected)
        return out


# ------------------------------------------------------------------------------------ scoring
def outage_cross_track(res: Any, window: tuple[float, float], plan: CoveragePlan | None = None,
                       est: np.ndarray | None = None) -> dict[str, float]:
    """Peak and RMS horizontal distance of the flown track (and of ``est``, (T, 3) aligned
    with ``res.t``, if given) from the planned path inside ``window``."""
    import shapely

    plan = plan or res.plan
    line = shapely.LineString(plan.path)
    sel = (res.t >= window[0]) & (res.t < window[1])

    def dist(xy):
        pts = shapely.points(xy[:, 0], xy[:, 1])
        return shapely.distance(line, pts)

    d = dist(res.p_true[sel, :Z])   # horizontal
    out = {"peak_cross_track_m": float(d.max()), "rms_cross_track_m": float(np.sqrt(np.mean(d**2)))}
    if est is not None:
        e = np.asarray(est)[sel, :Z] - res.p_true[sel, :Z]
        out["peak_estimate_error_m"] = float(np.max(np.hypot(e[:, 0], e[:, 1])))
    return out
