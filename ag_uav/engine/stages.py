"""The engine's stages: each owns its state and advances the whole batch by one control tick.

A tick, in order (:func:`ag_uav.engine.loop.fly`): :class:`Guard` (state rows → pose, crash and
ground checks, the reference row) → :class:`Sensing` (MEMS IMU, attitude estimate) →
:class:`Feedback` (truth, the batched estimator bank or a per-vehicle adapter) →
:class:`Control` (the batched cascade) → :class:`Spraying` (the spray job) →
:class:`Disturbance` (wind and drag) → :class:`Depositing` (the dose on the ground, observed
only) → :class:`Recorder` → observers (logs, renders, hooks)
→ physics (:mod:`ag_uav.engine.physics`). The stages share one :class:`Batch` of per-vehicle
arrays (leading axis N); each law they run is a batched kernel that never mixes rows.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from numkit import X, Y, Z

from ..world.deposition import S_ON
from .kernels import (
    ACTIVE,
    BOX,
    CRASHED,
    IMU_REC,
    NEAR_GROUND,
    NONFINITE,
    RC,
    GuardRows,
    PoseRows,
    RefRows,
    hold_on_ground,
    imu_record,
    tick_in,
    tick_out,
    zeros_touched,
)
from .physics import ground_contact
from .reftable import RefTable

#: the loop record's columns (one row per control tick); a frame with more than four rotors
#: records rotors 4, 5, ... after them (:func:`rec_motors`)
REC_COLUMNS = ("px", "py", "pz", "vx", "vy", "vz", "rx", "ry", "rz", "fx", "fy", "fz", "seg",
               "spray", "f0", "f1", "f2", "f3", "wx", "wy", "wz")


def rec_motors(rec: np.ndarray) -> np.ndarray:
    """The rotor commands (n, rotors) of a loop record (:data:`REC_COLUMNS`)."""
    if rec.shape[1] == len(REC_COLUMNS):
        return rec[:, RC.F:RC.F_END]
    return np.concatenate([rec[:, RC.F:RC.F_END], rec[:, len(REC_COLUMNS):]], axis=1)
#: the MEMS IMU record's keys in the log (measured f, gyro, attitude error)
IMU_KEYS = ("imu.fx", "imu.fy", "imu.fz", "imu.wx", "imu.wy", "imu.wz", "imu.att_err_x",
            "imu.att_err_y", "imu.att_err_z")


@dataclass
class Batch:
    """The per-vehicle arrays every stage reads and writes (row i = vehicle i)."""

    dt: float
    S: np.ndarray                 # (N, ns) full physics state
    sens: np.ndarray              # (N, nsensordata)
    n_ticks: np.ndarray           # (N,) ticks each flight flies
    airborne: np.ndarray          # (N,) lift-off latch
    hover_z: np.ndarray           # (N,)
    box: np.ndarray               # (N, 5) bounding box x0, y0, x1, y1, z_max
    ref: RefTable                 # the reference rows, a block of ticks at a time
    ref_ids: np.ndarray           # (N,) each vehicle's row of ref.tab
    n_max: int                    # ticks of the longest flight
    notes: list[list[str]]
    n_rot: int = 4                # rotors (actuators) of every vehicle of the batch
    sub: np.ndarray | None = None  # (N, nsub, nsensordata): the last period's sub-steps
    act: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        N = len(self.S)
        z3 = lambda: np.zeros((N, 3))  # noqa: E731
        self.act = np.ones(N, dtype=bool)
        self.p, self.v, self.omega = z3(), z3(), z3()
        self.rp, self.rv, self.ra = z3(), z3(), z3()
        self.p_fb, self.v_fb = z3(), z3()
        self.quat, self.R = np.zeros((N, 4)), np.zeros((N, 9))
        self.yaw = np.zeros(N)
        self.spray = np.zeros(N, dtype=bool)
        self.code = np.zeros(N, dtype=np.int8)
        self.low = np.zeros(N, dtype=bool)
        self.flown = np.zeros(N, dtype=np.int64)
        self.f = np.zeros((N, self.n_rot))
        self.xf, self.w = z3(), z3()
        self.Rc, self.om = self.R, self.omega      # what the controller flies on
        self.imu_in: tuple | None = None
        self.crash_reason: list[str | None] = [None] * N
        self.crash_time: list[float | None] = [None] * N

    @property
    def n(self) -> int:
        return len(self.S)


def _crash_text(code: int, t: float) -> str:
    if code == NONFINITE:
        return "diverged: non-finite state"
    if code == BOX:
        return f"left the bounding box at t={t:.2f}s"
    return f"tilt > 80 deg at t={t:.2f}s"


class Guard:
    """Start of a tick: state rows → pose; non-finite, tilt, bounding box and ground contacts
    end a vehicle's flight with its reason; the reference row of every active vehicle."""

    COS_TILT = math.cos(math.radians(80.0))

    def __init__(self, b: Batch, vehicles: Sequence[Any], iq: int, iv: int) -> None:
        self.b, self.iq, self.iv = b, iq, iv
        self.models = [v.model for v in vehicles]
        self.contact_data = [mujoco.MjData(m) for m in self.models]
        self.skids = [set(v.skid_geoms) for v in vehicles]
        self.ground = [v.ground_geom for v in vehicles]
        #: tick_in's arguments (engine.kernels: declared by name, passed as plain tuples)
        self.rows = (tuple(GuardRows(b.act, b.n_ticks, b.box, b.code, b.airborne, b.hover_z,
                                     b.low)),
                     tuple(PoseRows(b.p, b.v, b.quat, b.R, b.omega)),
                     tuple(RefRows(b.ref.tab, b.ref.k0, b.ref_ids, b.rp, b.rv, b.ra, b.yaw,
                                   b.spray)))

    def start(self, k: int, t: float) -> bool:
        """False when no vehicle is left to fly."""
        b = self.b
        guard, pose, ref = self.rows
        if k >= b.ref.end:
            b.ref.at(k)
        flags = tick_in(k, b.S, self.iq, self.iv, self.COS_TILT, guard, pose, ref)
        ended = False
        if flags & CRASHED:
            for i in np.flatnonzero(b.code):
                self._end(i, _crash_text(int(b.code[i]), t), t)
            b.code[:] = 0
            ended = True
        if flags & NEAR_GROUND:
            for i in np.flatnonzero(b.low):
                why = ground_contact(self.models[i], self.contact_data[i], b.S[i],
                                     self.ground[i], self.skids[i], b.v[i], t)
                if why:
                    self._end(i, why, t)
                    ended = True
        return bool(flags & ACTIVE) and not (ended and not b.act.any())

    def end(self, i: int, why: str, t: float) -> None:
        """End vehicle ``i``'s flight at ``t`` with the reason ``why``."""
        self._end(i, why, t)

    def _end(self, i: int, why: str, t: float) -> None:
        b = self.b
        b.crash_reason[i], b.crash_time[i] = why, t
        b.act[i] = False


class Sensing:
    """The MEMS IMU (accelerometer and gyro from MuJoCo's sensors, with their errors) and the
    attitude estimate the controller flies on; without the IMU, the true attitude and rates.
    With ``increments`` each sample integrates the control period's physics sub-steps
    (:meth:`~ag_uav.vehicle.sensors_batched.BatchImu.integrate`)."""

    def __init__(self, b: Batch, imu: Any, att: Any, accel_adr: int, gyro_adr: int,
                 increments: bool = False) -> None:
        self.b, self.imu, self.att = b, imu, att
        self.ia, self.ig = accel_adr, gyro_adr
        self.fa = slice(accel_adr, accel_adr + IMU_REC.width["f"])   # the sensors' 3-vectors
        self.fg = slice(gyro_adr, gyro_adr + IMU_REC.width["om"])
        #: the IMU integrates the period's sub-steps (``imu.sampling = "increments"``; the
        #: physics then keeps them in ``b.sub``), else reads the last sub-step's sensors
        self.increments = increments and imu is not None
        # tick-major (n_max, N, 9): one tick's rows are contiguous (the per-tick writes stay in
        # cache lines the physics step did not evict); a vehicle's record is copied out at the
        # end. float32: a record for plots and checks (7 significant digits), half the memory
        self.rec = (zeros_touched((b.n_max, b.n, IMU_REC.size), np.float32) if imu is not None
                    else None)
        self.now = np.zeros((b.n, IMU_REC.size))   # the tick's row in full precision (the log's)

    def step(self, k: int) -> None:
        b = self.b
        if self.imu is None:
            return
        sens = b.sens
        if self.increments:   # the rates at the period's end: the state's (Guard, b.omega)
            f, w = self.imu.integrate(b.sub, self.ia, self.ig, b.omega, b.act)
        else:
            f, w = sens[:, self.fa], sens[:, self.fg]
        f_m, b.om = self.imu.measure(f, w, b.act)
        b.Rc = self.att.apply(b.R, b.act)
        imu_record(self.rec, self.now, k, b.act, f_m, b.om, self.att.last)
        b.imu_in = (f_m, b.Rc, b.om)

    def row(self, i: int) -> np.ndarray | None:
        """Vehicle ``i``'s IMU row of the current tick (a view, written in place), or None."""
        return None if self.rec is None else self.now[i]


class Feedback:
    """What the controller flies on: the truth, one batched object for the whole batch
    (:meth:`ag_uav.navigation.feedback.Feedback.batch`) or each vehicle's feedback in turn.
    On the skids the horizontal part is the reference's (no horizontal position control before
    lift-off, as autopilots do: an estimate a metre off must not tip the vehicle over)."""

    def __init__(self, b: Batch, feedbacks: Sequence[Any], all_true: bool,
                 imu: Any = None) -> None:
        self.b, self.fbs, self.all_true = b, list(feedbacks), all_true
        self.bank = None
        if not all_true:
            self.bank = type(self.fbs[0]).batch(self.fbs, b.n_max)
            tap = getattr(self.bank, "truth_tap", None)
            if tap is not None:  # the sensor models' and the scores' truth (never fed back)
                tap(b.R, b.omega)
            tap = getattr(self.bank, "imu_tap", None)
            if tap is not None and imu is not None:  # the IMU's walked biases (scores only)
                tap(imu.walked)
            notes = [getattr(fb, "batch_note", None) for fb in self.fbs]
            if self.bank is None and (len(self.fbs) > 1 or any(notes)):
                self._say_per_vehicle()

    def _say_per_vehicle(self) -> None:
        """In every run's notes; a warning unless the feedback class already gave one (its
        ``batch_note``)."""
        note = next((n for n in (getattr(fb, "batch_note", None) for fb in self.fbs) if n), None)
        msg = ("feedback flies one vehicle at a time: "
               f"{note or type(self.fbs[0]).__name__ + ' has no batched form'}")
        if note is None:
            warnings.warn(msg, RuntimeWarning, stacklevel=4)
        for notes in self.b.notes:
            notes.append(msg)

    def step(self, k: int, t: float) -> None:
        """``p_fb``, ``v_fb`` of every active vehicle; a feedback that estimates the attitude
        too returns it third ((N, 9) row-major body → world), and the controller flies on it
        instead of the sensing stage's attitude; one that estimates the gyro bias returns the
        corrected body rates fourth ((N, 3): ω̃ − b̂_g), and the rate loop flies on them, as an
        autopilot's does, instead of the raw gyro."""
        b = self.b
        if self.all_true:
            pf, vf = b.p, b.v
        else:
            out = (self.bank.update(k, t, b.p, b.v, b.imu_in, b.act) if self.bank is not None
                   else self._per_vehicle(t))
            pf, vf, *more = out   # (p, v[, R[, ω̃ − b̂_g]])
            if len(more) > 0:
                b.Rc = more[0]
            if len(more) > 1:
                b.om = more[1]
        hold_on_ground(b.act, b.airborne, pf, vf, b.rp, b.rv, b.p_fb, b.v_fb)

    def _per_vehicle(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        b = self.b
        p_fb, v_fb = b.p.copy(), b.v.copy()
        for i in np.flatnonzero(b.act):
            pt = (float(b.p[i, X]), float(b.p[i, Y]), float(b.p[i, Z]))
            vt = (float(b.v[i, X]), float(b.v[i, Y]), float(b.v[i, Z]))
            if b.imu_in is not None:
                f_m, Rc, om = b.imu_in
                pf, vf = self.fbs[i].update(t, pt, vt, (f_m[i].tolist(), tuple(Rc[i].tolist()),
                                                        om[i].tolist()))
            else:
                pf, vf = self.fbs[i].update(t, pt, vt)
            p_fb[i], v_fb[i] = pf, vf
        return p_fb, v_fb

    def finish(self) -> None:
        if self.bank is not None:
            self.bank.finish(self.b.flown)


#: the automatic failsafe bound's floor and ceiling (m)
FAILSAFE_FLOOR_M = 1.0
FAILSAFE_CEILING_M = 5.0  # PX4 COM_POS_FS_EPH default: the horizontal error that fails position


def failsafe_bound(cfg: Any, gps: Any) -> float:
    """``gps.failsafe_sigma_m`` (m); ``"auto"``: the receiver's horizontal 1σ of one fix of its
    worst type (its nominal level without fix types), ``sqrt(var_x + var_y)`` of
    :meth:`~ag_uav.vehicle.gps.GpsSensor.spread_variance`, clipped to
    [:data:`FAILSAFE_FLOOR_M`, :data:`FAILSAFE_CEILING_M`] (rtk-m350: 1.24 m, its DGPS;
    standalone 2.04 m; rtk, sbas: the 1 m floor; the paper-scale presets, 10.5 m, and
    alpha-stable, whose spread stands in for its infinite variance: the 5 m ceiling). Always
    finite: the dead-reckoned 1σ grows without bound once the fixes stop, so the failsafe
    engages in every outage long enough. A filter fed fixes stays below one fix's error (the
    default INS under DGPS fixes: under 0.3 m; the paper-scale presets: the INS under 1.1 m,
    the ideal-attitude chain under 2.1 m once airborne)."""
    v = cfg.gps.failsafe_sigma_m
    if v != "auto":
        return float(v)
    if gps is None:
        return FAILSAFE_FLOOR_M
    modes = (None, *getattr(gps, "fix_types", ()))
    worst = max(math.sqrt(x + y) for x, y, _ in (gps.spread_variance(m) for m in modes))
    return min(FAILSAFE_CEILING_M, max(FAILSAFE_FLOOR_M, worst))


def failsafe_warning(cfg: Any) -> str | None:
    """One line when an explicit ``gps.failsafe_sigma_m`` lies above
    :data:`FAILSAFE_CEILING_M` with the failsafe on (else None): reachable only after the dead
    reckoning has drifted that far, so with the fix lost the vehicle sprays on for a long time
    (the default INS's 1σ on the default mission: about 3 m 12 s after the last fix, 10 m
    after 20 s)."""
    v = cfg.gps.failsafe_sigma_m
    if v == "auto" or cfg.gps.failsafe == "off" or float(v) <= FAILSAFE_CEILING_M:
        return None
    return (f"gps.failsafe_sigma_m = {float(v):g} m is above {FAILSAFE_CEILING_M:g} m: with "
            "the GNSS fix lost the vehicle flies on dead reckoning until its position 1-sigma "
            "reaches it (\"auto\" derives a bound in [1, 5] m from the receiver)")


class Failsafe:
    """The autopilot's position failsafe (``gps.failsafe``): in flight, once the flown
    estimate's horizontal position 1σ (the feedback bank's ``pos_sigma``) passes
    ``gps.failsafe_sigma_m``, the vehicle stops spraying, brakes at :attr:`BRAKE_MPS2`, holds
    where it stopped (``hold``: for ``gps.failsafe_hold_s``), then descends there at
    :attr:`DESCENT_MPS`, the last metre at :attr:`CRAWL_MPS`; on the ground (within 0.1 m of
    its resting height, settled) its flight ends. The check runs at 10 Hz; the reason, the time
    and the landing time go into the run's notes and summary (``failsafe``,
    ``failsafe_time_s``, ``failsafe_landed_s``). All of it flies on the estimate: without a fix
    the hover drifts with the dead reckoning."""

    DESCENT_MPS = 0.7  # PX4 MPC_LAND_SPEED default
    CRAWL_MPS = 0.3  # the last metre (PX4 MPC_LAND_CRWL default)
    BRAKE_MPS2 = 2.0  # horizontal deceleration to the hold (PX4 MPC_ACC_HOR is 3 m/s²)
    CHECK_HZ = 10.0

    def __init__(self, b: Batch, bank: Any, cfgs: Sequence[Any]) -> None:
        self.b, self.bank = b, bank
        n = b.n
        self.mode = [c.gps.failsafe for c in cfgs]
        self.on = np.array([m != "off" for m in self.mode])
        self.bound = np.array([failsafe_bound(c, getattr(fb, "gps", None))
                               for c, fb in zip(cfgs, getattr(bank, "fbs", [None] * n),
                                                strict=True)])
        self.hold_s = np.array([c.gps.failsafe_hold_s if m == "hold" else 0.0
                                for c, m in zip(cfgs, self.mode, strict=True)])
        self.every = max(1, round(1.0 / (self.CHECK_HZ * b.dt)))
        self.sig = np.full(n, np.nan)
        self.engaged = np.zeros(n, dtype=bool)
        self.n_engaged = 0  # engaged.sum(), kept as a count (no array reduction per tick)
        self.t_land = np.full(n, np.inf)
        self.at = np.zeros((n, 3))
        self.zr = np.zeros(n)  # the descending height reference
        self.v0 = np.zeros((n, 3))  # the horizontal velocity it brakes from
        self.t0 = np.zeros(n)
        self.info: list[dict[str, Any] | None] = [None] * n
        self.loss = GnssLoss(b, getattr(bank, "fbs", [None] * n))
        for c, notes in zip(cfgs, b.notes, strict=True):
            w = failsafe_warning(c)
            if w is not None:
                notes.append(w)

    def step(self, k: int, t: float) -> None:
        b = self.b
        if k % self.every == 0:
            self.loss.check(t)
            self.bank.pos_sigma(self.sig)
            over = self.sig > self.bound   # NaN (no fix yet) compares False, silently
            if over.any():
                for i in np.flatnonzero(self.on & ~self.engaged & b.act & b.airborne & over):
                    self._engage(int(i), t)
        if self.n_engaged:
            for i in np.flatnonzero(self.engaged & b.act):
                self._fly(int(i), t)

    def _engage(self, i: int, t: float) -> None:
        b = self.b
        self.engaged[i] = True
        self.n_engaged += 1
        v0 = b.v_fb[i].copy()
        v0[Z] = 0.0
        tb = math.sqrt(v0[X] * v0[X] + v0[Y] * v0[Y]) / self.BRAKE_MPS2
        self.at[i] = b.p_fb[i]
        self.v0[i] = v0
        self.t0[i] = t
        self.zr[i] = b.p_fb[i, Z]
        self.t_land[i] = t + max(self.hold_s[i], tb)
        why = (f"GNSS failsafe ({self.mode[i]}) at t={t:.1f}s: horizontal position 1-sigma "
               f"{self.sig[i]:.2f} m > gps.failsafe_sigma_m = {self.bound[i]:.3g} m")
        self.info[i] = {"failsafe": why, "failsafe_time_s": round(t, 2),
                        "failsafe_landed_s": None}
        b.notes[i].append(why)

    def _brake(self, i: int, t: float) -> None:
        """The reference of a stop at :attr:`BRAKE_MPS2` from the velocity at the engagement,
        then a hold where it stopped."""
        b, v0 = self.b, self.v0[i]
        sp = math.sqrt(v0[X] * v0[X] + v0[Y] * v0[Y])
        s = min(t - self.t0[i], sp / self.BRAKE_MPS2)
        a = self.BRAKE_MPS2 / sp if sp > 0.0 else 0.0  # per unit of v0
        f = s - 0.5 * a * s * s
        b.rp[i] = self.at[i] + f * v0
        b.rv[i] = (1.0 - a * s) * v0
        b.ra[i] = -a * v0 if s < sp / self.BRAKE_MPS2 else 0.0
        b.rp[i, Z] = self.zr[i]

    def _fly(self, i: int, t: float) -> None:
        """Brake, hold, then descend; the flight ends on the ground."""
        b = self.b
        self._brake(i, t)
        b.spray[i] = False
        if t < self.t_land[i]:
            return
        ground = b.hover_z[i]
        speed = self.DESCENT_MPS if self.zr[i] > ground + 1.0 else self.CRAWL_MPS
        self.zr[i] = max(self.zr[i] - speed * b.dt, ground - 0.5)
        b.rp[i, Z] = self.zr[i]
        b.rv[i, Z] = -speed if self.zr[i] > ground - 0.5 else 0.0
        if b.p[i, Z] < ground + 0.1 and abs(b.v[i, Z]) < 0.2:
            self.info[i]["failsafe_landed_s"] = round(t, 2)
            b.notes[i].append(f"GNSS failsafe: landed at t={t:.1f}s")
            b.act[i] = False


class GnssLoss:
    """Every GNSS loss of every vehicle, whatever ``gps.failsafe`` says: checked with the
    failsafe (10 Hz), a receiver that has delivered no fix for :attr:`LOSS_S` (or two fix
    intervals of a slower receiver) has lost the fix: ``losses[i]`` gets an episode
    ``{"lost_s", "last_fix_s", "regained_s"}`` (``regained_s`` None while lost) and the run's
    notes a line at the loss and at the next fix. PX4's EKF2 calls GNSS intermittent after
    the same 1 s without a sample (2 × ``GNSS_MAX_INTERVAL``)."""

    LOSS_S = 1.0

    def __init__(self, b: Batch, fbs: Sequence[Any]) -> None:
        self.b = b
        self.gps = [getattr(fb, "gps", None) for fb in fbs]
        self.rows = [i for i, g in enumerate(self.gps) if g is not None]
        self.gap = np.array([max(self.LOSS_S, 2.0 / g.rate_hz) if g is not None else np.inf
                             for g in self.gps])
        self.last = np.full(b.n, np.nan)
        self.down = np.zeros(b.n, dtype=bool)   # lost, not regained yet
        self.losses: list[list[dict[str, Any]]] = [[] for _ in range(b.n)]

    def check(self, t: float) -> None:
        if not self.rows:
            return
        last = self.last
        was = last.copy()
        last[self.rows] = [np.nan if (x := self.gps[i].last_fix_time) is None else x
                           for i in self.rows]
        back = self.down & (last > was)
        new = ~self.down & self.b.act & (t - last > self.gap)  # NaN (no fix yet): False
        for i in np.flatnonzero(back).tolist():
            ep = self.losses[i][-1]
            ep["regained_s"] = round(float(last[i]), 2)
            self.b.notes[i].append(f"GNSS regained at t={last[i]:.2f}s after "
                                   f"{last[i] - ep['last_fix_s']:.1f} s without a fix")
            self.down[i] = False
        for i in np.flatnonzero(new).tolist():
            self.losses[i].append({"lost_s": round(t, 2), "last_fix_s": round(float(last[i]), 2),
                                   "regained_s": None})
            self.b.notes[i].append(f"GNSS lost at t={t:.1f}s: no fix since "
                                   f"t={last[i]:.2f}s")
            self.down[i] = True


class Control:
    """The batched flight-controller cascade (:class:`controllers.batched.BatchCascade`)."""

    def __init__(self, b: Batch, cascade: Any) -> None:
        self.b, self.bc = b, cascade

    def step(self) -> None:
        b = self.b
        b.f = self.bc.update((b.p_fb, b.v_fb, b.Rc, b.om), (b.rp, b.rv, b.ra, b.yaw), b.dt,
                             active=b.act)

    def set_mass(self, i: int, total: float, J: Sequence[float]) -> None:
        """The spray job's mass changes reach the controller's model of the vehicle."""
        self.bc.mass[i] = total
        self.bc.J[i] = J


_NO_ROWS = np.zeros(0, np.int64)
_NO_LITRES = np.zeros(0)
_NO_NOZZLES = np.zeros((0, 1))


class Spraying:
    """The spray job (:class:`ag_uav.engine.spray_batched.BatchSprayer`): nozzles, tank, battery
    and sorties; a vehicle landed at the base gets zero thrust and a reset controller."""

    def __init__(self, b: Batch, sprayer: Any, control: Control, act_adr: int,
                 n_act: int = 4) -> None:
        self.b, self.spr, self.control, self.ia = b, sprayer, control, act_adr
        self.na = n_act  # every rotor's actuator state: the energy counts them all

    def step(self, k: int, t: float) -> None:
        b = self.b
        on, reset = self.spr.step(k, t, b.p[:, Z], b.v[:, X], b.v[:, Y], b.spray, b.f,
                                  b.S[:, self.ia:self.ia + self.na], b.act)
        b.spray[:] = on
        if np.count_nonzero(reset):  # every tick: cheaper than reset.any()
            self.control.bc.reset_rows(np.flatnonzero(reset))

    def settle(self, k: int, t: float, depositing: Depositing | None) -> None:
        """After the nozzle model: the tank draws what each vehicle's nozzles let out and the
        nozzles are on while the valve is open (what the record, the coverage and the log
        see), so the tank, the coverage and the dose follow one flow."""
        b = self.b
        if depositing is not None:
            for rows, dep in depositing.groups:
                self.spr.draw(k, t, rows, dep.out, dep.st, S_ON, b.spray, b.act)
        else:
            self.spr.draw(k, t, _NO_ROWS, _NO_LITRES, _NO_NOZZLES, 0, b.spray, b.act)


class Disturbance:
    """Wind (mean + Dryden turbulence) as a drag force, held over the control period. With
    ``meander`` (N, M) the mean wind's direction of row i is turned by ``meander[i, j]``
    radians from tick j·``every`` on (:func:`ag_uav.world.forecast.meander_angles`; a tick
    count of the flight's own, so a row turns alike in any batch)."""

    def __init__(self, b: Batch, wind: Any, c_lin: np.ndarray, c_quad: np.ndarray,
                 meander: np.ndarray | None = None, every: int = 1) -> None:
        self.b, self.wind, self.c_lin, self.c_quad = b, wind, c_lin, c_quad
        self.meander, self.every = meander, every

    def step(self, k: int = 0) -> None:
        b = self.b
        if self.meander is not None and k % self.every == 0:
            self.wind.turn(self.meander[:, min(k // self.every, self.meander.shape[1] - 1)])
        b.w, b.xf = self.wind.step_drag(b.dt, b.p[:, Z], b.v, self.c_lin, self.c_quad, b.act)


class Depositing:
    """What lands on the ground (:mod:`ag_uav.world.deposition`): each vehicle's nozzles (valve
    delays, pressure lag, minimum speed) on the spray job's nozzle command ``b.spray`` (the plan,
    gated by the tank and the height window), the droplets carried by the downwash of the actual
    rotor thrust (the actuator states) and the wind with its gust ``b.w``, splatted onto the
    vehicle's dose map. Its litres are the ones the tank draws (:meth:`Spraying.settle`).

    ``groups``: (rows, :class:`~ag_uav.world.deposition.DepositionBatch`) for the vehicles that
    share a deposition config and a ground grid; each row is stepped by the one row function, so
    a vehicle's dose does not depend on the batch it flies in."""

    def __init__(self, b: Batch, groups: list[tuple[np.ndarray, Any]], act_adr: int,
                 n_act: int) -> None:
        self.b, self.groups, self.ia, self.na = b, groups, act_adr, n_act
        self.where = {int(i): (dep, j) for rows, dep in groups for j, i in enumerate(rows)}

    def step(self) -> None:
        b = self.b
        for rows, dep in self.groups:
            dep.step_rows(b.dt, rows, (b.p, b.v, b.R, b.S, b.w, b.spray, b.act), self.ia,
                          self.na)

    def of(self, i: int) -> tuple[Any, int] | None:
        """(the DepositionBatch, its row) of vehicle ``i``, or None without a dose map."""
        return self.where.get(i)

    def dose_map(self, i: int) -> Any:
        """Vehicle ``i``'s :class:`~ag_uav.world.deposition.DoseMap` (pending splats done)."""
        hit = self.where.get(i)
        return None if hit is None else hit[0].dose_map(hit[1])


class Recorder:
    """Row ``k`` of every active vehicle's record (:data:`REC_COLUMNS`), as arrays (tick-major:
    ``rec[k, i]``; :meth:`of` gives vehicle ``i``'s own contiguous copy). With ``capture``, also
    the initial physics state and what the physics was handed each tick (rotor commands and
    applied force), so that the physics alone can be replayed (``ag-uav bench``)."""

    def __init__(self, b: Batch, capture: bool = False) -> None:
        self.b = b
        extra = max(0, b.n_rot - 4)  # rotors past the fourth: after the wind
        self.rec = zeros_touched((b.n_max, b.n, len(REC_COLUMNS) + extra))  # tick-major
        self.s0 = b.S.copy() if capture else None
        self.controls = zeros_touched((b.n_max, b.n, b.n_rot + 3)) if capture else None

    def step(self, k: int) -> None:
        b = self.b
        # RecordRow's fields, as a plain tuple (b.f is the controller's new array each tick)
        tick_out(self.rec, k, b.act, b.flown,
                 (b.p, b.v, b.rp, b.p_fb, b.w, b.f, b.spray, b.ref.tab, b.ref.k0, b.ref_ids))
        if self.controls is not None:
            self.controls[k, :, :b.n_rot] = b.f
            self.controls[k, :, b.n_rot:] = b.xf

    def of(self, i: int, n: int) -> np.ndarray:
        return np.ascontiguousarray(self.rec[:n, i])
