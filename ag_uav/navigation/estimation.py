"""The estimator bank in the loop: GPS fixes → filters → the estimate the controller flies on.

:class:`EstimatorFeedback` plugs into the feedback seam of :mod:`ag_uav.engine.missions`. Every
control tick it asks the :class:`~ag_uav.vehicle.gps.GpsSensor` for a fix (one arrives at the
sensor's rate), predicts every filter one control period ahead, and updates all of them with the
very same fix. The
*primary* filter (``estimator.name``) is what the controller flies on; the *shadows*
(``estimator.shadow``) see identical fixes and are only scored, so comparisons are fair (common
random numbers). With ``estimator.name = "true"`` the controller flies on the truth and the
shadows are still scored.

With ``estimator.imu`` (default) the prediction is driven by the IMU, as in a loosely coupled
GNSS/INS: ``x̄ = F x + B â`` with ``B = [dt²/2, dt, 0]`` per axis and ``â = R̂ f̃ + g`` (the MEMS
accelerometer's specific force rotated by the attitude estimate, :mod:`ag_uav.vehicle.imu`; with
``imu.model = "ideal"`` the mean acceleration over the control period plus white noise), so the
estimate follows the vehicle's manoeuvres between fixes; without it, a GPS-only filter in the
loop adds enough lag to make the position loop oscillate (measured: 5 m control error).

Filters use the ``estimator.model`` motion model predicted at the control rate
(``dt = 1/control_hz``): by default ``"cvb"``, state ``[x, vx, bx, y, vy, by, z, vz, bz]`` with
the IMU input's slow error ``b`` estimated (see :mod:`estimators.models`); Q from the IMU's
figures (:func:`process_noise`). ``R = r_scale · diag(GPS nominal error variance)``, floored at
(1 cm)², and with ``gps.r_from_fix_type`` switched to the variance of the fix type the receiver
reports. By default the height channel of each fix comes from a radar altimeter
(``gps.altitude_source = "radar"``, white noise ``gps.radar_sigma_m``, height above the flat
ground), as on spray drones, which cannot fly 3 m above a crop on a GPS vertical with metres of
bias. They are initialised at the first fix with zero velocity, ``P0 = diag(R, 4 m²/s²)`` and
the bias states at the IMU's turn-on figures.

Scores per estimator (over the mission ticks, like the tracking error): ``estimate_rmse_m``
(horizontal |p̂ − p|), ``estimate_share`` (mean-square estimate error / mean-square tracking
error, horizontal: the part of the tracking error that the estimate explains if the two are
uncorrelated; can exceed 1), and ``update_us`` (mean wall time of one ``update`` call).
"""

from __future__ import annotations

import time
import warnings
from typing import Any

import numpy as np

from numkit import Layout, X, Y, Z

from .._jit import njit
from ..config import Config
from ..vehicle.mjcf import G
from .aiding import fuse_height, horizontal_sigma
from .feedback import Feedback
from .position_filters import R_FLOOR, make_filter, process_noise
from .receiver import make_gps

#: a consistency record's row (per update): the estimate's tick index, the NIS, the position
#: covariance P_pp (3 × 3, row-major)
CONS = Layout("j nis P:3x3")
C = CONS.at

class FilterBank:
    """What every estimator feedback shares: each control tick, predict every filter of
    ``self.filters`` one control period ahead (driven by the IMU's acceleration when
    ``self.imu``), update all of them with the same measurement ``z`` (timed, logged), and
    record each filter's position estimate for the scores.

    Needs the attributes ``filters``, ``pos_idx``, ``vel_idx``, ``dt``, ``imu``, ``imu_sigma``,
    ``imu_rng``, ``_v_prev``, ``est``, ``upd_ns``, ``n_upd``, ``log`` and ``primary``.
    """

    #: the loop passes the MEMS IMU's reading to ``update`` (``imu=(f̃, R̂)``)
    wants_imu = False

    def _setup_records(self) -> None:
        """Per-filter records for the scores: estimates per tick, update costs, consistency."""
        names = self.names
        self.est: dict[str, list[tuple[float, float, float]]] = {n: [] for n in names}
        self.upd_ns = dict.fromkeys(names, 0)
        self.n_upd = dict.fromkeys(names, 0)
        self.cons: dict[str, list[tuple[int, float, np.ndarray]]] = {n: [] for n in names}
        self._pp = np.ix_(self.pos_idx, self.pos_idx)

    def _setup_imu(self, cfg: Config, imu_seed) -> None:
        self.imu = cfg.estimator.imu
        self.wants_imu = self.imu and cfg.imu.model == "mems"
        self.imu_sigma = cfg.imu.vibration_sigma_mps2
        self.imu_rng = np.random.default_rng(imu_seed)
        self._v_prev = None
        self.dt = 1.0 / cfg.sim.control_hz

    def _imu_accel(self, v_true, imu=None) -> list[float] | None:
        """World-frame acceleration input of the prediction, or None without IMU aiding.

        MEMS (``imu = (f̃, R̂)`` from the loop): ``â = R̂ f̃ + g``. Ideal: the mean acceleration
        over the last control period (finite difference of the true velocity) plus white noise
        (None on the first tick)."""
        if not self.imu:
            return None
        if imu is not None:
            out = np.empty((1, 3))
            _world_accel(_row(imu[1], 9), _row(imu[0], 3), G, out)
            return out[0].tolist()
        pv = self._v_prev
        self._v_prev = v_true
        if pv is None:
            return None
        s, dt = self.imu_sigma, self.dt
        n = self.imu_rng.standard_normal(3) if s > 0 else (0.0, 0.0, 0.0)
        return [(v_true[i] - pv[i]) / dt + s * n[i] for i in range(3)]

    def _step_bank(self, t: float, z, v_true, imu=None):
        """Predict (+ IMU input ``B a``) and update every filter; the primary's (p, v)."""
        pi, vi = self.pos_idx, self.vel_idx
        a = self._imu_accel(v_true, imu)
        dt = self.dt
        hh = 0.5 * dt * dt
        for name, f in self.filters.items():
            f.predict()
            if a is not None:
                x = f.x
                for i in range(3):
                    x[pi[i]] += hh * a[i]
                    x[vi[i]] += dt * a[i]
            if z is not None:
                t0 = time.perf_counter_ns()
                f.update(z)
                self.upd_ns[name] += time.perf_counter_ns() - t0
                self.n_upd[name] += 1
                # consistency record: tick index of this estimate, NIS, position covariance
                self.cons[name].append((len(self.est[name]), float(getattr(f, "nis", np.nan)),
                                        f.P[self._pp].copy()))
                if self.log is not None and self.log.want_estimator(name, t):
                    x = f.x
                    self.log.estimator(t, name, x, np.diag(f.P), getattr(f, "y", None),
                                       pos=(x[pi[X]], x[pi[Y]], x[pi[Z]]))
            x = f.x
            self.est[name].append((float(x[pi[X]]), float(x[pi[Y]]), float(x[pi[Z]])))
        if self.primary not in self.filters:
            return None
        x = self.filters[self.primary].x
        return ((float(x[pi[X]]), float(x[pi[Y]]), float(x[pi[Z]])),
                (float(x[vi[X]]), float(x[vi[Y]]), float(x[vi[Z]])))

class EstimatorFeedback(FilterBank, Feedback):
    """GPS + primary estimator (+ shadows) behind the feedback seam."""

    def __init__(self, cfg: Config, seed: np.random.SeedSequence,
                 altimeter_seed: np.random.SeedSequence | None = None,
                 imu_seed: np.random.SeedSequence | None = None) -> None:
        self.cfg = cfg
        self.gps = make_gps(cfg, seed)
        var = np.asarray(self.gps.variance, dtype=float).reshape(-1)
        if var.size == 1:
            var = np.repeat(var, 3)
        var = np.where(np.isfinite(var), var, 1.0)  # alpha-stable: infinite variance
        self.r_diag = np.maximum(cfg.estimator.r_scale * var, R_FLOOR)
        self.radar = cfg.gps.altitude_source == "radar"
        if self.radar:
            self.radar_sigma = cfg.gps.radar_sigma_m
            self.radar_rng = np.random.default_rng(altimeter_seed)
            self.r_diag[Z] = max(self.radar_sigma**2, R_FLOOR)
        # R per reported fix type (RTK fixed / float / DGPS), when the preset has fix types
        self.r_by_fix: dict[str, np.ndarray] = {}
        if cfg.gps.r_from_fix_type and getattr(self.gps, "fix_types", ()):
            for mode in self.gps.fix_types:
                r = np.maximum(cfg.estimator.r_scale * np.asarray(self.gps.mode_variance(mode)),
                               R_FLOOR)
                if self.radar:
                    r[Z] = self.r_diag[Z]
                self.r_by_fix[mode] = np.diag(r)
        self._r_mode: str | None = None
        e = cfg.estimator
        self.primary = e.name
        self.name = e.name
        names = ([e.name] if e.name != "true" else []) + [s for s in e.shadow if s != e.name]
        self.names = names
        comps = tuple(getattr(self.gps, "config_components", ()))
        self.filters = {n: make_filter(n, cfg, self.r_diag, comps) for n in names}
        mdl = next(iter(self.filters.values())).model if self.filters else None
        self.pos_idx = list(mdl.pos_idx) if mdl is not None else [0, 2, 4]
        self.vel_idx = list(mdl.vel_idx) if mdl is not None else [1, 3, 5]
        self.n = mdl.n if mdl is not None else 6
        self.initialised = False
        self._setup_imu(cfg, imu_seed)
        self._setup_records()
        self.fixes: list[tuple[float, float, float, float]] = []
        self.log = None
        self._solo: BatchEstimatorFeedback | bool | None = None
        #: why this bank flies one vehicle at a time, if it cannot batch (None: it can)
        self.batch_note: str | None = None

    def initial_state(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x0, P0) at the first fix ``z``: position z, zero velocity, ``P0 = diag(R, 4 m²/s²)``
        and the bias states (``"cvb"``) at the IMU's turn-on figures."""
        x0 = np.zeros(self.n)
        x0[self.pos_idx] = z
        P0 = np.eye(self.n) * 4.0
        P0[self.pos_idx, self.pos_idx] = self.r_diag
        if self.cfg.estimator.model == "cvb":   # bias states: the IMU's turn-on figures
            bi = [i + 2 for i in self.pos_idx]
            _, _, bias_var0 = process_noise(self.cfg)
            P0[bi, bi] = bias_var0
        return x0, P0

    def _init(self, z: np.ndarray) -> None:
        x0, P0 = self.initial_state(z)
        for f in self.filters.values():
            f.x = x0.copy()
            f.P = P0.copy()
        self.initialised = True

    def measure(self, t: float, p_true) -> tuple[np.ndarray | None, np.ndarray | None]:
        """This tick's GNSS fix (None between fixes) with the radar altimeter's height, and the
        new R when the receiver's fix type changed (``gps.r_from_fix_type``), else None; logs
        and records the fix.  Shared by the per-vehicle and the batched paths."""
        z = self.gps.measure(t, p_true)
        if z is None:
            return None, None
        if self.radar:
            z[Z] = p_true[Z] + self.radar_sigma * self.radar_rng.standard_normal()
        R_new = None
        if self.r_by_fix:
            mode = self.gps.last_fix_type
            if mode != self._r_mode and mode in self.r_by_fix:
                self._r_mode = mode
                R_new = self.r_by_fix[mode]
        self.fixes.append((t, float(z[X]), float(z[Y]), float(z[Z])))
        if self.log is not None:  # what the receiver reports: its fix type and variance
            mode = self.gps.last_fix_type
            var = self.gps.reported_variance(mode)
            if self.radar:
                var = (var[0], var[1], self.radar_sigma**2)
            self.log.gps(t, z, var, mode, t_meas=t - self.gps.latency_s,
                         truth=self.gps.last_truth)  # the body centre (no antenna offset)
            self.log.set_truth(p_true)
        return z, R_new

    def update(self, t, p_true, v_true, imu=None):
        """One control tick of this vehicle alone.  A bank the batched kernels support flies as
        a :class:`BatchEstimatorFeedback` of one (the engine's batched path, so a vehicle's
        estimates are the same alone or in any batch); any other bank (e.g. a filter without a
        batched version) on its scalar filters (:meth:`FilterBank._step_bank`)."""
        if self._solo is None:  # once; a bank already refused by the engine is not tried again
            ok = type(self) is EstimatorFeedback and self.batch_note is None
            self._solo = ok and BatchEstimatorFeedback.try_batch([self], 1) or False
        if self._solo:
            return self._solo.update_one(t, p_true, v_true, imu)
        z, R_new = self.measure(t, p_true)
        if R_new is not None:
            for f in self.filters.values():
                f.R = R_new
        if not self.initialised:
            if z is None:
                return p_true, v_true  # no fix yet: nothing to fly on (only at t = 0)
            self._init(z)
            z = None
        pv = self._step_bank(t, z, v_true, imu)
        return (p_true, v_true) if pv is None else pv

    def scores(self, p_true: np.ndarray, p_ref: np.ndarray, mission: slice) -> dict[str, Any]:
        """Per-estimator scores over ``mission`` ticks (arrays aligned with the loop record).

        ``estimate_rmse_m`` / ``estimate_max_m``: horizontal |p̂ − p|. ``nees_mean``: mean of
        ``eᵀ P_pp⁻¹ e`` over the updates (3-D position error against the filter's position
        covariance; a consistent filter gives 3). ``nis_mean``: mean normalised innovation
        squared ``νᵀ S⁻¹ ν`` (3 when consistent; the PCA filters' ν is on the reconstructed
        fix). ``update_us``: mean wall time of one ``update`` call."""
        _sync_solo(self)
        out: dict[str, Any] = {}
        n = len(p_true)
        d = p_true[mission, :Z] - p_ref[mission, :Z]   # horizontal
        track_ms = float(np.mean(np.sum(d * d, axis=1))) if len(d) else float("nan")
        lo, hi, _ = mission.indices(n)
        for name in self.names:
            est = np.asarray(self.est[name], dtype=float).reshape(-1, 3)
            # the first tick (initialisation) records no estimate: align from the end
            full = np.full((n, 3), np.nan)
            m = min(len(est), n)
            off = n - m
            full[off:] = est[:m] if len(est) <= n else est[-n:]
            e = full[mission, :Z] - p_true[mission, :Z]
            ok = np.all(np.isfinite(e), axis=1)
            e2 = np.sum(e[ok] ** 2, axis=1)
            ms = float(np.mean(e2)) if ok.any() else float("nan")
            nees, nis = _nees_nis(self.cons[name], full, p_true, off, lo, hi, n)
            out[name] = {
                "estimate_rmse_m": round(float(np.sqrt(ms)), 4),
                "estimate_max_m": round(float(np.sqrt(np.max(e2))), 4) if e2.size else None,
                "estimate_share": round(ms / track_ms, 4) if track_ms > 0 else None,
                "nees_mean": round(float(np.mean(nees)), 3) if nees else None,
                "nis_mean": round(float(np.nanmean(nis)), 3) if nis else None,
                "update_us": round(self.upd_ns[name] / max(self.n_upd[name], 1) / 1e3, 2),
                "updates": self.n_upd[name],
                "flown": name == self.primary,
            }
        return out

    def summary(self) -> dict[str, Any]:
        _sync_solo(self)
        counts = getattr(self.gps, "fix_type_counts", None)
        return {"gps_preset": self.cfg.gps.preset, "gps_fixes": len(self.fixes),
                "gps_fix_types": dict(counts) if counts else None,
                "gps_rate_hz": self.gps.rate_hz,
                "estimator_r_diag_m2": [round(float(v), 5) for v in self.r_diag]}

    @classmethod
    def batch(cls, feedbacks: list[Any], n_max: int) -> BatchEstimatorFeedback | None:
        """The engine batch's banks as one :class:`BatchEstimatorFeedback` (see
        :meth:`BatchEstimatorFeedback.try_batch`), or None."""
        return BatchEstimatorFeedback.try_batch(feedbacks, n_max)


def _sync_solo(fb: Any) -> None:
    """Records of a vehicle flown alone through its batch of one (:meth:`EstimatorFeedback.update`)
    back into ``fb`` (for its ``scores``/``summary``)."""
    solo = getattr(fb, "_solo", None)  # BearingFeedback borrows scores()
    if solo:
        solo.finish(np.array([solo.k_next]))


def _nees_nis(cons: Any, full: np.ndarray, p_true: np.ndarray, off: int, lo: int, hi: int,
              n: int) -> tuple[list[float], list[float]]:
    """NEES ``eᵀ P⁻¹ e`` and NIS of the updates whose tick lies in ``[lo, hi)``. ``cons``: the
    consistency record, a list of ``(j, nis, P_pp)`` or an (M, :data:`CONS`) array of its
    rows; ``j`` + ``off`` is the update's tick."""
    if isinstance(cons, np.ndarray):
        arr = cons
    else:
        arr = np.array([[j, nis_j, *np.asarray(P).ravel()] for j, nis_j, P in cons],
                       dtype=float).reshape(-1, CONS.size)
    if not len(arr):
        return [], []
    k = off + arr[:, C.J].astype(np.int64)
    sel = (k >= lo) & (k < hi) & (k < n)
    k, nis, P = k[sel], arr[sel, C.NIS], arr[sel, C.P:C.P_END].reshape(-1, 3, 3)
    ev = full[k] - p_true[k]
    fin = np.all(np.isfinite(ev), axis=1)
    ev, P = ev[fin], P[fin]
    try:
        nees = np.einsum("ij,ij->i", ev, np.linalg.solve(P, ev[:, :, None])[:, :, 0])
    except np.linalg.LinAlgError:  # a singular P: skip that update, as one by one
        vals = []
        for e, Pi in zip(ev, P, strict=True):
            try:
                vals.append(float(e @ np.linalg.solve(Pi, e)))
            except np.linalg.LinAlgError:
                pass
        nees = np.asarray(vals)
    return nees.tolist(), nis.tolist()


class BatchEstimatorFeedback:
    """The estimator feedbacks of a whole engine batch, advanced together.

    Wraps N :class:`EstimatorFeedback` objects (built per run as for one mission: GNSS sensor,
    radar altimeter, R per fix type, filters) and runs their filters as one
    :class:`estimators.batched.BatchBank` (numba kernels over the batch axis). Per tick: the
    vehicles with a fix due ask their own :class:`~ag_uav.vehicle.gps.GpsSensor` (Python, at the fix
    rate only), each filter predicts with the IMU input ``â = R̂ f̃ + g`` and the vehicles with
    a fix update; the records (per-tick estimates, NEES/NIS inputs, update costs) are arrays
    and go back into the per-run objects at :meth:`finish`, so :meth:`EstimatorFeedback.scores`
    and ``summary`` work unchanged. The fix handling and initialisation are the per-run
    objects' own (:meth:`EstimatorFeedback.measure`, :meth:`EstimatorFeedback.initial_state`),
    and a vehicle flown alone by :meth:`EstimatorFeedback.update` is a batch of one of this
    class: its estimates are bit-identical alone, in any batch, or on the scalar filters
    (``tests/test_feedback_paths.py``).

    Updates go through the bank, where PCA-KF and PCA-MCKF share their PCA step; every
    :attr:`TIME_EVERY`-th fix tick each filter updates alone and is timed, which gives the
    per-filter ``update_us`` (the mean time of one vehicle's update in those ticks); the kernels
    are compiled (or loaded from numba's cache) before the first timed update
    (:func:`estimators.batched.warm_up`), so ``update_us`` does not count a one-time compile.
    """

    TIME_EVERY = 16

    @classmethod
    def try_batch(cls, feedbacks: list[Any], n_max: int) -> BatchEstimatorFeedback | None:
        """The batched bank when every feedback is an :class:`EstimatorFeedback` with the same
        filter names and IMU aiding and the batched kernels support its filters; else None
        (the engine then flies them one by one), with the reason in a ``RuntimeWarning`` and
        in each feedback's ``batch_note``."""
        if not feedbacks:
            return None
        f0 = feedbacks[0]
        reason = None
        kinds = {type(fb).__name__ for fb in feedbacks}
        if kinds != {"EstimatorFeedback"} or not all(type(fb) is EstimatorFeedback
                                                     for fb in feedbacks):
            reason = (f"{', '.join(sorted(kinds))}: only plain EstimatorFeedback banks are "
                      "batched")
        elif not f0.names:
            return None  # nothing to estimate: the controllers fly on the truth
        elif any(fb.names != f0.names or fb.primary != f0.primary or fb.imu != f0.imu
                 or fb.wants_imu != f0.wants_imu for fb in feedbacks):
            reason = "the vehicles' estimator banks differ (filters, primary or IMU aiding)"
        if reason is None:
            from estimators.batched import BatchBank

            try:
                bank = BatchBank.from_filters([fb.filters for fb in feedbacks])
            except ValueError as e:
                reason = str(e)
            else:
                return cls(feedbacks, bank, n_max)
        note = f"estimator bank flown one vehicle at a time (not batched): {reason}"
        warnings.warn(note, RuntimeWarning, stacklevel=2)
        for fb in feedbacks:
            fb.batch_note = note
        return None

    def __init__(self, feedbacks: list[EstimatorFeedback], bank: Any, n_max: int) -> None:
        self.fbs = feedbacks
        self.bank = bank
        self.N = N = len(feedbacks)
        f0 = feedbacks[0]
        self.names = list(f0.names)
        self.primary = f0.primary
        self.pos_idx = np.asarray(f0.pos_idx)
        self.vel_idx = np.asarray(f0.vel_idx)
        self.dt = f0.dt
        self.ideal_imu = f0.imu and not f0.wants_imu
        self.init = np.array([fb.initialised for fb in feedbacks], dtype=bool)
        self.next_t = np.array([fb.gps.next_fix_t for fb in feedbacks])
        self.every_tick = np.array([fb.gps.latency_s > 0.0 for fb in feedbacks], dtype=bool)
        self.z = np.zeros((N, 3))
        self.mask = np.zeros(N, dtype=bool)
        self.h = np.zeros(N)  # radar heights read without a GNSS fix (see _height)
        self.h_mask = np.zeros(N, dtype=bool)
        self.u = np.zeros((N, 3))
        self.p_out = np.zeros((N, 3))
        self.v_out = np.zeros((N, 3))
        n_fix = int(n_max * max(fb.gps.rate_hz for fb in feedbacks) * self.dt) + 4
        # tick-major (n_max, N, 3): one tick's rows contiguous (cache-friendly per-tick writes)
        self.est = {n: np.full((n_max, N, 3), np.nan) for n in self.names}
        # per update: tick, NIS, position covariance (3×3) — the NEES/NIS record
        self.cons = {n: np.zeros((N, n_fix, CONS.size)) for n in self.names}
        self.n_cons = np.zeros(N, dtype=np.int64)
        self.upd_ns = dict.fromkeys(self.names, 0)
        self.n_upd = dict.fromkeys(self.names, 0)
        self.n_timed = dict.fromkeys(self.names, 0)
        self.n_fix_ticks = 0
        self.k_next = 0  # ticks seen (the records grow past n_max when needed)
        self._act1 = np.ones(1, dtype=bool)
        from estimators.batched import warm_up

        warm_up(bank)  # compile / load the kernels before any timed update

    def _fix(self, i: int, t: float, p: np.ndarray) -> None:
        """Vehicle ``i``'s GNSS (and radar) at ``t`` (:meth:`EstimatorFeedback.measure`):
        initialise at the first fix, else stage the fix for this tick's update."""
        fb = self.fbs[i]
        pt = (float(p[X]), float(p[Y]), float(p[Z]))
        z, R_new = fb.measure(t, pt)
        self.next_t[i] = fb.gps.next_fix_t
        if z is None:
            if fb.radar and self.init[i]:  # no fix: the radar altimeter still reads
                self.h[i] = pt[Z] + fb.radar_sigma * fb.radar_rng.standard_normal()
                self.h_mask[i] = True
            return
        if R_new is not None:
            for bf in self.bank.filters.values():
                bf.R[i] = R_new
        if not self.init[i]:
            x0, P0 = fb.initial_state(z)
            for bf in self.bank.filters.values():
                bf.initialise([i], x0, P0)
            fb.initialised = self.init[i] = True
            return
        self.z[i] = z
        self.mask[i] = True

    def _grow(self, k: int) -> None:
        """Double the per-tick and per-update records when tick ``k`` or the next update does
        not fit (a batch of one flown by :meth:`EstimatorFeedback.update` has no n_max)."""
        for n in self.names:
            e = self.est[n]
            if k >= e.shape[0]:
                self.est[n] = np.concatenate([e, np.full_like(e, np.nan)], axis=0)
            c = self.cons[n]
            if int(self.n_cons.max()) >= c.shape[1]:
                self.cons[n] = np.concatenate([c, np.zeros_like(c)], axis=1)

    def update_one(self, t: float, p_true, v_true, imu=None):
        """:meth:`update` for a batch of one, with the per-vehicle arguments and result of
        :meth:`EstimatorFeedback.update` (``imu = (f̃, R̂)`` as sequences)."""
        p = np.array([p_true], dtype=float)
        v = np.array([v_true], dtype=float)
        imu_in = None if imu is None else (_row(imu[0], 3), _row(imu[1], 9))
        pf, vf = self.update(self.k_next, t, p, v, imu_in, self._act1)
        if not self.init[0]:
            return p_true, v_true
        return tuple(pf[0].tolist()), tuple(vf[0].tolist())

    def update(self, k: int, t: float, p: np.ndarray, v: np.ndarray, imu: tuple | None,
               act: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One control tick of every active vehicle; returns the (p, v) the controllers fly on
        (the primary filter's estimate; the truth before a vehicle's first fix)."""
        self.k_next = max(self.k_next, k + 1)
        if k >= self.est[self.names[0]].shape[0] or int(self.n_cons.max()) >= \
                self.cons[self.names[0]].shape[1]:
            self._grow(k)
        due = act & ((t >= self.next_t - 1e-9) | self.every_tick)
        self.mask[:] = False
        self.h_mask[:] = False
        if due.any():
            for i in np.flatnonzero(due):
                self._fix(int(i), t, p[i])
        run = act & self.init
        if imu is not None:
            f_m, Rh = imu[0], imu[1]
            _world_accel(Rh, f_m, G, self.u)
            u = self.u
        elif self.ideal_imu:
            u = self._ideal_accel(v, run)
        else:
            u = None
        mask = self.mask
        any_fix = mask.any()
        filters = self.bank.filters
        for bf in filters.values():
            bf.predict(u, run)
        if any_fix:
            rows = int(mask.sum())
            self.n_fix_ticks += 1
            if self.n_fix_ticks % self.TIME_EVERY == 1 or len(filters) == 1:
                # every TIME_EVERY-th update: each filter alone, timed (its update_us)
                for name, bf in filters.items():
                    t0 = time.perf_counter_ns()
                    bf.update(self.z, mask)
                    self.upd_ns[name] += time.perf_counter_ns() - t0
                    self.n_timed[name] += rows
            else:  # the bank: PCA-KF and PCA-MCKF share their PCA step (bit-identical)
                self.bank.update(self.z, mask)
            for name, bf in filters.items():
                self.n_upd[name] += rows
                _cons_record(self.cons[name], self.n_cons, k, mask, bf.nis, bf.P, self.pos_idx)
            self.n_cons[mask] += 1
            if any(fb.log is not None for fb in self.fbs):
                self._log(t, mask)
        if self.h_mask.any():
            self._height()
        for name, bf in filters.items():
            _est_record(self.est[name], k, run, bf.x, self.pos_idx)
        if self.primary not in self.bank.filters:
            return p, v
        bf = self.bank.filters[self.primary]
        _primary_out(bf.x, self.pos_idx, self.vel_idx, run, p, v, self.p_out, self.v_out)
        return self.p_out, self.v_out

    def _height(self) -> None:
        """The radar heights read without a fix (:func:`~ag_uav.navigation.aiding.fuse_height`),
        as autopilots fly on a range finder when the fix is lost."""
        iz = int(self.pos_idx[Z])
        for i in np.flatnonzero(self.h_mask):
            fuse_height(self.bank.filters.values(), i, self.h[i], self.fbs[i].radar_sigma ** 2, iz)

    def pos_sigma(self, out: np.ndarray) -> None:
        """Each vehicle's horizontal position 1σ (m) of the primary filter (NaN before its
        first fix): :func:`~ag_uav.navigation.aiding.horizontal_sigma`."""
        bf = self.bank.filters.get(self.primary)
        horizontal_sigma(None if bf is None else bf.P, int(self.pos_idx[X]), int(self.pos_idx[Y]),
                         self.init, out)

    def _ideal_accel(self, v: np.ndarray, run: np.ndarray) -> np.ndarray | None:
        """The ideal IMU (``imu.model = "ideal"``), per vehicle as :meth:`FilterBank._imu_accel`."""
        out = self.u
        any_u = False
        for i in np.flatnonzero(run):
            a = self.fbs[i]._imu_accel(tuple(v[i].tolist()))
            if a is None:
                out[i] = 0.0
            else:
                out[i] = a
                any_u = True
        return out if any_u else None

    def _log(self, t: float, mask: np.ndarray) -> None:
        pi = self.pos_idx
        for i in np.flatnonzero(mask):
            log = self.fbs[i].log
            if log is None:
                continue
            for name, bf in self.bank.filters.items():
                if log.want_estimator(name, t):
                    x = bf.x[i]  # float64 vectors go into the message as raw bytes
                    y = bf.y[i] if getattr(bf, "y", None) is not None else None
                    xl = x.tolist()
                    log.estimator(t, name, x, np.diagonal(bf.P[i]).copy(), y,
                                  pos=(xl[pi[X]], xl[pi[Y]], xl[pi[Z]]))

    def finish(self, flown: np.ndarray) -> None:
        """Hand the records back to the per-run feedbacks (for their ``scores``/``summary``)
        and the filters' final states to their scalar objects."""
        for i, fb in enumerate(self.fbs):
            n = int(flown[i])
            nc = int(self.n_cons[i])
            for name, bf in self.bank.filters.items():
                fb.est[name] = np.ascontiguousarray(self.est[name][:n, i])
                fb.cons[name] = self.cons[name][i, :nc]
                # the mean time of one row's update in the timed (one filter at a time) ticks
                fb.upd_ns[name] = self.upd_ns[name] * nc / max(self.n_timed[name], 1)
                fb.n_upd[name] = nc
                bf.to_filter(i, fb.filters[name])
            fb.initialised = bool(self.init[i])


# ------------------------------------------------------------------------ kernels of the bank


def _row(a, n: int) -> np.ndarray:
    """One vehicle's sequence as a (1, n) float64 row for the kernels below."""
    return np.asarray(a, dtype=float).reshape(1, n)


@njit(cache=True)
def _world_accel(R, f, g, out):  # pragma: no cover
    """â = R̂ f̃ + g (world frame, z up): the IMU input of the filters' prediction."""
    for i in range(R.shape[0]):
        for r in range(3):
            out[i, r] = (R[i, 3 * r + X] * f[i, X] + R[i, 3 * r + Y] * f[i, Y]
                         + R[i, 3 * r + Z] * f[i, Z])   # row r of R̂ f̃
        out[i, Z] -= g


@njit(cache=True)
def _est_record(est, k, run, x, pos):  # pragma: no cover
    for i in range(run.shape[0]):
        if run[i]:
            for j in range(3):
                est[k, i, j] = x[i, pos[j]]


@njit(cache=True)
def _cons_record(cons, n_cons, k, mask, nis, P, pos):  # pragma: no cover
    for i in range(mask.shape[0]):
        if mask[i]:
            r = cons[i, n_cons[i]]
            r[C.J] = k
            r[C.NIS] = nis[i]
            for a in range(3):
                for b in range(3):
                    r[C.P + 3 * a + b] = P[i, pos[a], pos[b]]


@njit(cache=True)
def _primary_out(x, pos, vel, run, p, v, p_out, v_out):  # pragma: no cover
    for i in range(run.shape[0]):
        for j in range(3):
            if run[i]:
                p_out[i, j] = x[i, pos[j]]
                v_out[i, j] = x[i, vel[j]]
            else:
                p_out[i, j] = p[i, j]
                v_out[i, j] = v[i, j]
