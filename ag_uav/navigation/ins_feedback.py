"""The drone navigates on the INS (``estimator.nav = "ins"``, the default).

:class:`InsFeedback` is one run's navigation: the receiver (:class:`~ag_uav.vehicle.gps.GpsSensor`
with its fix types, the :class:`~ag_uav.vehicle.gps.ReceiverReport` of an honest receiver, the
receiver's velocity and dual-antenna heading, the radar altimeter) and the filter settings; the
engine flies a whole batch of them as one :class:`BatchInsFeedback`
(:meth:`InsFeedback.batch`), whose filters are ONE :class:`estimators.ins.BatchINS`: per vehicle
the flown rule (``estimator.name``) and the shadows (``estimator.shadow``), all fed the very same
IMU samples and fixes (common random numbers). It returns ``(p, v, R)``: the controller flies on
the INS position, velocity and attitude.

**What reads the truth.** Only the sensor models, as the physical sensors do: the receiver
(position, velocity and heading at the antenna, ``latency_s`` old) and the radar (slant range)
read the true state from a ring of the last ``D + 1`` ticks; the IMU reading comes from the
engine's MEMS IMU (``f̃``, ``ω̃``). The filter reads only those measurements. The true attitude
and body rate reach the bank through :meth:`BatchInsFeedback.truth_tap` (the engine hands it
its state arrays once), for the heading/antenna sensors and for the scores; nothing read there
is fed back but through the sensors (``tests/test_ins_feedback.py`` flies a mission with the
truth replaced by NaN after take-off: the sensors drop out and the INS coasts).

**Latency and delayed fusion.** A fix delivered at tick k reports the antenna state at tick
``k − D``, ``D = round(gps.latency_s · control_hz)`` (the latency is rounded to whole control
periods), tagged with its age ``D·Δt``; the INS fuses it on its delayed horizon
(:mod:`estimators.ins`). The radar has no latency (age 0).

**Initialisation on the ground** (at the vehicle's first fix with the accelerometer at rest,
``| |f̃| − g | < 0.5 m/s²``: the first tick's reading, before the skids' contact settles, is not;
usually the second fix, 0.1 s): position = the
fix less the lever arm, velocity 0, roll and pitch levelled from the accelerometer sample
(``φ = atan2(f̃_y, f̃_z)``, ``θ = atan2(−f̃_x, √(f̃_y² + f̃_z²))``), yaw from the first
heading, biases 0; ``P0`` = the fix's variance, (0.1 m/s)², (1°)² tilt, (2°)² yaw, and the IMU's
turn-on bias figures (``[imu]``). Before the first fix the output is the radar height, zero
velocity and the levelled attitude (on the skids the engine holds the horizontal part at the
reference).

**R.** Position (``estimator.ins_r_source``): ``"reported"`` (the default) from the
receiver's reported accuracy, as a real filter gets it: hAcc² on both horizontal axes, vAcc²
on the height (:func:`~.receiver.reported_acc`: the reported type's variance times the honest
receiver's calibration error ``s²``, one draw per reported-type episode, or per run on presets
without fix types), floored at (1 cm)², its configured Gauss–Markov share
(``estimator.ins_gnss_gm_share``, τ ``estimator.ins_gnss_gm_tau_s``) considered or inflated
per ``estimator.ins_gnss_colour`` (:func:`~.receiver.reported_r`); ``"truth"``:
``max(r_scale · variance, (1 cm)²)`` of the error generator's white and Gauss–Markov parts
for the reported type (``gps.r_from_fix_type``; else the preset's nominal), times ``s²``,
the Gauss–Markov part considered or inflated by `receiver.colour_factor` over
``estimator.ins_gnss_window_s``; velocity ``gps.velocity_sigma_mps²``, heading
``gps.heading_sigma_deg²``, radar ``gps.radar_sigma_m²``.

**Gate** (PX4 EKF2's innovation test, common to the four rules: ``estimator.ins_gate_sigma``,
``estimator.ins_gate_reset_s``; :func:`estimators.ins.gate_ratio`): every fix's position,
velocity and heading is tested before its update; a rejected one is not fused, counted
(summary ``gate_rejected`` per filter, ``ins_counters``) and its verdict kept per fix. After
``ins_gate_reset_s`` with neither a position nor a velocity fused, or twice that with no
position, a rejected fix resets the position to the receiver (``gate_resets``). Behind the gate
the step latch (``estimator.ins_gate_latch_s``; :mod:`estimators.ins`) holds the fixes of a
step the gate caught and fuses them relative to it (``gate_latched``, counted in
``gate_rejected`` too; ``ins_counters``: ``gnss_fused_relative``, ``gate_latch_releases``).

**Rates.** The rate loop flies on the gyro less the flown filter's gyro-bias estimate (the
fourth output of :meth:`BatchInsFeedback.update`), as an autopilot's does.

**Range aid** (PX4 EKF2's conditional range aid, ``EKF2_RNG_CTRL = 1``, with its defaults
``EKF2_RNG_A_HMAX`` = 5 m and ``EKF2_RNG_A_VMAX`` = 1 m/s: ``estimator.ins_range_aid_m``,
``estimator.ins_range_aid_mps``; 0 m = off): while the radar's last reading is below 5 m and the
fix's horizontal velocity below 1 m/s (take-off, landing, hover), the fix's height gets the
variance :data:`NOT_FUSED_VAR` (σ = 1 km: its gain is ~10⁻¹⁰, the height is not fused) and the
radar is the height source; the horizontal position, the velocity and the heading are fused as
always. The decision reads sensors only (the radar and the receiver's velocity), so every filter
of the bank gets the same fix. Counted in the summary's ``range_aid_fixes``. Without it the
GNSS height rules the landing: a DGPS episode the honest receiver reports as RTK fixed moves the
estimate by decimetres at 1 m height (the 38 ha job's sixth landing hit the ground at 1.2 m/s;
docs/ins.md). PX4's innovation-consistency check of the range before switching is left out:
the ground here is flat at z = 0, the datum of the fixes too.

**Scores** (per filter, over the mission ticks): horizontal position error RMS / max, 3-D
velocity error RMS, tilt error (angle between the true and estimated body z axes) RMS / max,
yaw error RMS, and at every GNSS fix the NEES of the 15-state error (the core state against the
truth at the core's tick) and of each 3-state block on its marginal covariance
(``nees_pos/vel/att/ba/bg_mean``), with the NIS of the fix's position, velocity and heading
updates (``nis_mean``, ``nis_vel_mean``, ``nis_yaw_mean``; a rejected part has none) and of the
radar over the flight (``nis_radar_mean``). Every state's truth: position and velocity of the
IMU (the body origin) from the engine's state; attitude from the engine's rotation (the error
``Log(q̂* ⊗ q)``); the biases are the IMU's **walked** biases of that tick, read from the
engine's IMU (:attr:`~ag_uav.vehicle.sensors_batched.BatchImu.walked`, through
:meth:`BatchInsFeedback.imu_tap`), or, for a bank flown without it, from a twin of that IMU
(the same seed stream and block, the same draws: :meth:`ImuSensor.walk_block`). A fix whose
core P is not positive definite (its Cholesky fails) has no NEES: it is left out of the mean
and counted (``nees15_not_pd``; the report says so). With the honest receiver's false fixes:
the share of false-fix epochs the gate rejected (``false_fixes_rejected``) and the peak
horizontal error from each episode's first false fix to 10 s after its last
(``false_fix_peak_m``).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from estimators.ins import BatchINS, INSConfig
from numkit import X, Y, Z
from numkit.geometry import euler_to_quat, quat_to_rot_flat

from ..config import Config, ConfigError
from ..vehicle.gps import ReceiverReport, derive_seed
from .aiding import horizontal_sigma
from .feedback import Feedback
from .ins_kernels import (
    BLOCKS,
    ERRORS,
    FIX_DUE,
    GN,
    IM,
    NOT_INITIALISED,
    NR,
    NREC,
    RG,
    RING_WIDTH,
    RN,
    BankView,
    Outputs,
    Scores,
    SensorRows,
    outputs,
    radar_rows,
    tick_in,
)
from .nees_stats import chi2_band, effective_n, finite_mean, finite_rms_max
from .receiver import colour_factor, reported_acc, reported_r, truth_r

_chi2_band, _mean = chi2_band, finite_mean   # the scores' statistics (nees_stats)
#: the variance (m², σ = 1 km) that keeps a fix's height out of the update under range aid
NOT_FUSED_VAR = 1e6
DEG = math.pi / 180.0
#: IMU → GNSS antenna (body axes, m): the antenna mast above the IMU (engineering judgement for
#: an M350-class airframe; the filter is given the same installed value, as it is calibrated)
ANTENNA = (0.0, 0.0, 0.3)
#: IMU → radar altimeter (body axes, m)
RADAR = (0.0, 0.0, -0.1)
INS_RULES = ("kf", "mckf", "pca-kf", "pca-mckf")


def ins_config(cfg: Config) -> INSConfig:
    """The INS's settings from the run config (IMU figures at the control rate, latency,
    MCKF σ, kernel and recovery, PCA window)."""
    from .receiver import gnss_latency_s

    e, im = cfg.estimator, cfg.imu
    rec = None if e.ins_recovery == "none" else e.ins_recovery
    lat = gnss_latency_s(cfg)
    # the process noise's margins (the white-noise variances × ins_q_accel / ins_q_gyro)
    ma, mg = math.sqrt(e.ins_q_accel), math.sqrt(e.ins_q_gyro)
    return INSConfig.from_imu(
        cfg.sim.control_hz, accel_nd_ug=im.accel_noise_density_ug * ma,
        gyro_nd_mdps=im.gyro_noise_density_mdps * mg, vibration=im.vibration_sigma_mps2 * ma,
        accel_rw=max(im.accel_bias_rw, 1e-6), gyro_rw_dps=max(im.gyro_bias_rw, 1e-6),
        lever_arm=ANTENNA, radar_offset=RADAR, delay_s=lat,
        delayed=lat > 0, sigma=e.sigma, mckf_kernel=e.mckf_kernel,
        max_iter=e.max_iter, recovery=rec,
        pca_window=e.window, pca_mode=e.pca_mode,
        gate_sigma=e.ins_gate_sigma if e.ins_gate_sigma > 0 else math.inf,
        gate_reset_s=e.ins_gate_reset_s if e.ins_gate_reset_s > 0 else math.inf,
        gate_latch_s=e.ins_gate_latch_s if e.ins_gate_latch_s >= 0 else math.inf,
        coning=im.sampling == "increments")


def ins_bank_key(cfg: Config) -> tuple:
    """What an INS bank takes from its first vehicle for all (the filter settings, the radar's
    source, rate and noise, the IMU bias figures of the initial covariance): runs whose keys
    differ cannot share a :class:`BatchInsFeedback` (``batch_key`` keeps them apart)."""
    g, im = cfg.gps, cfg.imu
    return (repr(ins_config(cfg)), g.altitude_source, g.radar_hz, g.radar_sigma_m,
            im.accel_bias_mg, im.gyro_bias_dps)


class InsFeedback(Feedback):
    """One run's INS navigation (see the module docstring); flown through
    :class:`BatchInsFeedback`."""

    name = "ins"
    wants_imu = True

    def __init__(self, cfg: Config, seeds: dict[str, np.random.SeedSequence]) -> None:
        from ..vehicle.imu import ImuSensor
        from .receiver import gnss_latency_s, make_gps

        e, g = cfg.estimator, cfg.gps
        self.cfg = cfg
        self.primary = self.name = e.name
        self.names = ([e.name] if e.name != "true" else []) + [s for s in e.shadow
                                                               if s != e.name]
        bad = [n for n in self.names if n not in INS_RULES]
        if bad:
            raise ConfigError(f"estimator.nav = \"ins\": {', '.join(bad)} is not an INS GNSS "
                              f"update rule ({', '.join(INS_RULES)}); use estimator.nav = "
                              "\"ideal-attitude\" for it")
        if cfg.imu.model != "mems" or not e.imu:
            raise ConfigError("estimator.nav = \"ins\" needs the MEMS IMU (imu.model = "
                              "\"mems\", estimator.imu = true); use estimator.nav = "
                              "\"ideal-attitude\" otherwise")
        self.gps = make_gps(cfg, seeds["gps"])
        self.gps.latency_s = 0.0     # the latency is applied from the truth ring (exact ticks)
        self.dt = 1.0 / cfg.sim.control_hz
        self.D = int(round(gnss_latency_s(cfg) / self.dt))  # gps.overrides' latency wins
        spare = seeds["spare4"]
        self.report = None
        if g.receiver == "honest" and self.gps.fix_types:
            self.report = ReceiverReport(
                self.gps.rate_hz, derive_seed(spare, "receiver"),
                per_hour=g.false_fix_per_hour, mean_s=g.false_fix_mean_s,
                bias_m=g.false_fix_bias_m, calibration_sigma=g.accuracy_calibration_sigma,
                report_lag_s=g.fix_type_report_lag_s)
        self.aux_rng = np.random.default_rng(derive_seed(spare, "gnss_aux"))
        self._aux: list[float] = []
        self._aux_j = 0
        self.age_s = self.D * self.dt   # every fix's age (s): the latency in whole ticks
        self.radar = g.altitude_source == "radar"
        self.radar_rng = np.random.default_rng(seeds["altimeter"])
        self._setup_r(cfg, spare)   # R and the considered variance (module docstring, "R")
        #: the Gauss-Markov variance (3 floats) of the last fix (consider: the position
        #: covariance the INS reports is its P plus this; zero otherwise)
        self.cvar = [0.0, 0.0, 0.0]
        self.var_v = g.velocity_sigma_mps**2
        self.var_yaw = (g.heading_sigma_deg * DEG) ** 2
        #: the velocity and heading noise's standard deviations (m/s, rad)
        self.sig_v, self.sig_yaw = g.velocity_sigma_mps, g.heading_sigma_deg * DEG
        # scoring only: a twin of the engine's IMU (the same seed stream and block), whose
        # walk_block() gives the walked biases sample by sample: the bias states' truth
        self.imu_twin = ImuSensor(cfg.imu, cfg.sim.control_hz, seeds["imu"])
        self.bias0 = self.imu_twin.bias0
        self.fixes = 0
        #: whether the last fix was a false fix, and the ticks of the false fixes delivered to
        #: the filters (scores: the gate's rejections of them)
        self.last_false = False
        self.false_k: list[int] = []
        #: range aid (module docstring): radar range and horizontal speed limits, and the fixes
        #: whose height it kept out of the filter
        self.aid_m, self.aid_mps = e.ins_range_aid_m, e.ins_range_aid_mps
        self.range_aid_fixes = 0
        self.aid_on: np.ndarray | None = None  # set by the batch (a view of its flags)
        #: forced GNSS outages (t0, t1): no position, velocity or heading inside (the radar
        #: goes on), e.g. ``ag-uav experiment ins-nav --what outage``
        self.outages: list[tuple[float, float]] = []
        self.log = None
        self.series: dict[str, Any] | None = None
        self.rec: dict[str, Any] = {}
        self.att: dict[str, float] = {}

    def _setup_r(self, cfg: Config, spare: np.random.SeedSequence) -> None:
        """R and the considered variance per reported fix type, from the generator
        (``"truth"``) and from the receiver's report (``"reported"``; module docstring,
        "R")."""
        e, g = cfg.estimator, cfg.gps
        self.colour = e.ins_gnss_colour
        self.n_window = max(1, int(round(e.ins_gnss_window_s * self.gps.rate_hz)))
        self.var_nominal = truth_r(self.gps, None, self.colour, self.n_window, e.r_scale)
        self.var_by_type = ({m: truth_r(self.gps, m, self.colour, self.n_window, e.r_scale)
                             for m in self.gps.fix_types}
                            if g.r_from_fix_type else {})
        # the same as Python floats for fix() (R per reported type)
        self._var_nominal_list = self.var_nominal[0].tolist()
        self._var_lists = {m: vp.tolist() for m, (vp, _) in self.var_by_type.items()}
        self._cv_nominal_list = self.var_nominal[1].tolist()
        self._cv_lists = {m: cv.tolist() for m, (_, cv) in self.var_by_type.items()}
        #: ins_r_source = "reported": the receiver's report per type (a finite spread for
        #: alpha-stable), the configured split, and on presets without fix types one
        #: calibration error per run (as ReceiverReport draws one per reported-type episode)
        self.r_reported = e.ins_r_source == "reported"
        self._acc = {m: list(self.gps.spread_variance(m))
                     for m in (None, *(self.gps.fix_types if g.r_from_fix_type else ()))}
        rho = math.exp(-1.0 / (self.gps.rate_hz * e.ins_gnss_gm_tau_s))
        self._r_args = (self.colour, e.ins_gnss_gm_share, colour_factor(rho, self.n_window),
                        e.r_scale)
        self.scale0 = 1.0
        if self.r_reported and g.receiver == "honest" and self.report is None:
            cal = np.random.default_rng(derive_seed(spare, "accuracy")).standard_normal()
            self.scale0 = math.exp(g.accuracy_calibration_sigma * cal)

    def fix(self, t: float, p_ant, v_ant, yaw: float) -> list[float] | None:
        """The receiver's fix of this tick from the delayed antenna truth (position, velocity,
        heading), as one GNSS input row (``GIN``, a list; None: no fix due, or lost). Python
        floats: numpy's per-call cost would dominate at one vehicle (the same bits)."""
        z = self.gps.measure_xyz(t, p_ant)
        if z is None or (self.outages and any(a <= t < b for a, b in self.outages)):
            return None
        true_type = self.gps.last_fix_type
        rep, scale = true_type, 1.0
        zx, zy, zz = z
        self.last_false = False
        if self.report is not None:
            bias, rep, scale = self.report.step(true_type)
            if self.report.in_false:   # a false fix carries its bias
                zx, zy, zz = zx + bias[X], zy + bias[Y], zz + bias[Z]
                self.last_false = bool(bias.any())
            else:   # the bias is zero (added, as it always was: -0.0 becomes 0.0)
                zx, zy, zz = zx + 0.0, zy + 0.0, zz + 0.0
        s2, rs = scale * scale, scale
        if self.r_reported:   # module docstring, "R"
            vp, cv = reported_r(reported_acc(self._acc.get(rep, self._acc[None]),
                                             s2 * self.scale0 * self.scale0), *self._r_args)
            rs = 1.0
            if self.colour == "consider":
                self.cvar = cv
        else:
            vp = self._var_lists.get(rep, self._var_nominal_list)
            if self.colour == "consider":   # else the considered variance stays zero
                cv = self._cv_lists.get(rep, self._cv_nominal_list)
                self.cvar = [cv[X] * s2, cv[Y] * s2, cv[Z] * s2]
        nx, ny, nz, n_yaw = self._aux4()
        sv = self.sig_v
        self.fixes += 1
        if self.log is not None:  # the reported type and its variance (times the calibration)
            v, c2 = self.gps.reported_variance(rep), scale * scale * self.scale0 ** 2
            self.log.gps(t, np.array((zx, zy, zz)), (v[X] * c2, v[Y] * c2, v[Z] * c2), rep,
                         t_meas=t - self.age_s, truth=p_ant)  # the antenna, age_s ago
        vv, row = self.var_v, [0.0] * GN.SIZE   # the row's fields by name (GIN)
        row[GN.AGE], row[GN.P:GN.P_END] = self.age_s, (zx, zy, zz)
        row[GN.V:GN.V_END] = v_ant[X] + sv * nx, v_ant[Y] + sv * ny, v_ant[Z] + sv * nz
        row[GN.YAW] = yaw + self.sig_yaw * n_yaw
        row[GN.VAR_P:GN.VAR_P_END] = vp[X] * rs * rs, vp[Y] * rs * rs, vp[Z] * rs * rs
        row[GN.VAR_V:GN.VAR_V_END], row[GN.VAR_YAW] = (vv, vv, vv), self.var_yaw
        return row

    def _aux4(self) -> list[float]:
        """The next four standard normals of the receiver's auxiliary stream (velocity noise,
        heading noise), drawn in blocks: the same sequence as four at a time."""
        j, m = self._aux_j, 4   # v (3), heading
        if j + m > len(self._aux):
            self._aux, j = self.aux_rng.standard_normal(4096).tolist(), 0
        self._aux_j = j + m
        return self._aux[j:j + m]

    def update(self, t, p_true, v_true, imu=None):
        raise NotImplementedError("InsFeedback flies through the engine's batch "
                                  "(InsFeedback.batch); it has no per-vehicle path")

    @classmethod
    def batch(cls, feedbacks: list[Any], n_max: int) -> BatchInsFeedback:
        kinds = {type(fb) for fb in feedbacks}
        f0 = feedbacks[0]
        if kinds != {InsFeedback} or any(fb.names != f0.names or fb.D != f0.D
                                         or ins_bank_key(fb.cfg) != ins_bank_key(f0.cfg)
                                         for fb in feedbacks):
            raise ValueError("BatchInsFeedback: the vehicles' INS banks differ (filters, "
                             "latency, filter settings or radar); batch_key keeps such runs "
                             "apart")
        return BatchInsFeedback(feedbacks, n_max)

    # -- scores ----------------------------------------------------------------------------
    def scores(self, p_true: np.ndarray, p_ref: np.ndarray, mission: slice) -> dict[str, Any]:
        """Per filter over the ``mission`` ticks (module docstring); the flown filter's attitude
        figures also go into the summary (:meth:`summary`)."""
        out: dict[str, Any] = {}
        r = self.rec
        n = len(p_true)
        lo, hi, _ = mission.indices(n)
        fk = r["fix_k"]
        sel = (fk >= lo) & (fk < hi)
        #: the mission's per-fix NEES15 per filter, by fix tick (ag-uav experiment ins-nav)
        self.series = {"tick": fk[sel], "dt": self.dt,
                       **{name: r["nees"][sel, j] for j, name in enumerate(self.names)}}
        for j, name in enumerate(self.names):
            he, ve = r["herr"][lo:hi, j], r["verr"][lo:hi, j]
            te, ye = r["tilt"][lo:hi, j], r["yaw"][lo:hi, j]
            fk = r["fix_k"]
            sel = (fk >= lo) & (fk < hi)
            nees = r["nees"][sel, j]
            not_pd = int(np.nansum(r["not_pd"][sel, j]))
            nees = nees[np.isfinite(nees)].astype(np.float64)
            gate = r["gate"][sel, j]
            ff = np.isin(fk, self.false_k) & sel
            ffg = r["gate"][ff, j]
            rsum, rn = r["nis_radar"][j]
            # RMS and max a block at a time (finite_rms_max): no whole-job float64 copies
            h_rms, h_max, h_n = finite_rms_max(he)
            t_rms, t_max, _ = finite_rms_max(te, DEG)

            out[name] = {
                "estimate_rmse_m": h_rms, "estimate_max_m": h_max,
                "velocity_rmse_mps": finite_rms_max(ve)[0],
                "tilt_error_rms_deg": t_rms, "tilt_error_max_deg": t_max,
                "yaw_error_rms_deg": finite_rms_max(ye, DEG)[0],
                "nees15_mean": round(float(nees.mean()), 3) if nees.size else None,
                "nees15_band95": _chi2_band(15, effective_n(nees)),
                "nees15_n_eff": round(effective_n(nees), 1) if nees.size else None,
                "nees15_not_pd": not_pd,
                **{f"nees_{b}_mean": _mean(r[f"nees_{b}"][sel, j]) for b in BLOCKS},
                "nis_mean": _mean(r["nis"][sel, j]),
                "nis_vel_mean": _mean(r["nis_vel"][sel, j]),
                "nis_yaw_mean": _mean(r["nis_yaw"][sel, j]),
                "nis_radar_mean": round(rsum / rn, 3) if rn else None,
                "gate_rejected": int(np.sum(gate >= 1)),
                "gate_resets": int(np.sum(gate == 2)),
                "gate_latched": int(np.sum(gate == 3)),
                "false_fixes_rejected": (round(float(np.mean(ffg >= 1)), 4) if ffg.size
                                         else None),
                "false_fix_peak_m": (finite_rms_max(he[self._false_window(lo, hi)])[1]
                                     if self.false_k else None),
                "update_us": r["update_us"],
                "updates": int(sel.sum()),
                "ticks": h_n,
                "flown": name == self.primary,
            }
            if name == self.primary:
                self.att = {k: out[name][k] for k in ("tilt_error_rms_deg", "tilt_error_max_deg",
                                                      "yaw_error_rms_deg")}
        return out

    def _false_window(self, lo: int, hi: int) -> np.ndarray:
        """Mask over the ticks ``lo:hi``: each false-fix episode (its false fixes, a gap of more
        than 1 s starts another) from its first fix to 10 s after its last."""
        m = np.zeros(hi - lo, dtype=bool)
        ks = np.asarray(self.false_k)
        per_s = int(round(1.0 / self.dt))
        cut = np.flatnonzero(np.diff(ks) > per_s) + 1
        for ep in np.split(ks, cut):
            m[max(ep[0] - lo, 0):max(ep[-1] + 10 * per_s - lo, 0)] = True
        return m

    def summary(self) -> dict[str, Any]:
        counts = self.gps.fix_type_counts
        s: dict[str, Any] = {
            "nav": "ins", "gps_preset": self.cfg.gps.preset, "gps_fixes": self.fixes,
            "gps_fix_types": dict(counts) if counts else None, "gps_rate_hz": self.gps.rate_hz,
            "gps_latency_s": round(self.D * self.dt, 4),
            "ins_counters": self.rec.get("counters"),
            **self.att}
        if self.aid_m > 0:
            s["range_aid_fixes"] = self.range_aid_fixes
        if self.report is not None:
            s["false_fix_episodes"] = self.report.n_false
            s["false_fix_fixes"] = self.report.false_fixes
        return s


class BatchInsFeedback:
    """The INS feedbacks of an engine batch: one :class:`estimators.ins.BatchINS` (rows =
    vehicles × rules), the receivers per vehicle (Python, at the fix rate), the truth ring and
    the score records (numba kernels, one call each per tick)."""

    def __init__(self, fbs: list[InsFeedback], n_max: int) -> None:
        self.fbs = fbs
        f0 = fbs[0]
        self.NV = NV = len(fbs)
        self.names = list(f0.names)
        self.nr = nr = len(self.names)
        self.flown = self.names.index(f0.primary) if f0.primary in self.names else -1
        self.cfg = f0.cfg
        self.icfg = ins_config(f0.cfg)
        self.bank = BatchINS(NV, self.icfg, self.names) if nr else None
        self.D, self.dt = f0.D, f0.dt
        self.ring = np.full((NV, self.D + 1, RING_WIDTH), np.nan)   # rows: RING
        self.R_true: np.ndarray | None = None
        self.w_true: np.ndarray | None = None
        self.init = np.zeros(NV, dtype=np.bool_)
        self.k0 = np.zeros(NV, dtype=np.int64)
        self.next_t = np.zeros(NV)
        self.radar_every = max(1, int(round(f0.cfg.sim.control_hz / f0.cfg.gps.radar_hz)))
        self.imu = np.zeros((NV, IM.SIZE))
        self.due = np.zeros(NV, dtype=np.bool_)
        self.radar_on = f0.radar
        self.gnss = np.full((NV, GN.SIZE), np.nan)
        self.radar = np.full((NV, RN.SIZE), np.nan)
        self.range_last = np.full(NV, np.nan)  # each vehicle's latest radar reading (range aid)
        #: 1.0 while the vehicle's last fix had its height kept out (range aid), else 0.0; each
        #: feedback sees its own element (``aid_on``, a view: the log records it per tick)
        self.aid_on = np.zeros(NV)
        for i, fb in enumerate(fbs):
            fb.aid_on = self.aid_on[i:i + 1]
        self.p_out, self.v_out = np.zeros((NV, 3)), np.zeros((NV, 3))
        self.R_out = np.tile(np.eye(3).ravel(), (NV, 1))
        #: the body rates the rate loop flies on: the gyro less the flown filter's bias estimate
        self.w_out = np.zeros((NV, 3))
        #: each vehicle's considered GNSS variance (the last fix's; InsFeedback.cvar)
        self.cvar = np.zeros((NV, 3))
        self.bias0 = np.stack([fb.bias0 for fb in fbs])
        #: the walked IMU biases of the block of ticks (IMU sample k = tick k from tick 0): the
        #: engine's IMU's own (imu_tap), else refilled from the twins
        self.blk = f0.imu_twin.block
        self.btru = np.zeros((NV, self.blk, 6))
        self.b_next, self.twins = 0, True   # twins: no engine IMU tapped (imu_tap)
        self.prm = np.array([*ANTENNA, *RADAR, *self.icfg.heading_baseline,  # SENSOR_PRM
                             math.cos(self.icfg.radar_max_tilt_deg * DEG),
                             self.icfg.radar_max_range])
        nrec = max(nr, 1)
        # herr, verr, tilt, yaw; tick-major (one tick's rows contiguous: cache-friendly writes).
        # The scoring records are float32 (7 significant digits; the scores sum in float64):
        # half the memory of a long job's records
        self.err = np.full((n_max, NV, ERRORS.size, nrec), np.nan, dtype=np.float32)
        n_fix = int(n_max * max(fb.gps.rate_hz for fb in fbs) * self.dt) + 4
        self.fix_k = np.full((NV, n_fix), -1, dtype=np.int64)
        # the per-fix score record (NEES_REC)
        self.nees = np.full((NV, n_fix, NREC, nrec), np.nan, dtype=np.float32)
        self.n_fix = np.zeros(NV, dtype=np.int64)
        self.noise = np.stack([fb.radar_rng.standard_normal(4096) for fb in fbs])
        self.noise_i = np.zeros(NV, dtype=np.int64)
        self.upd_ns = 0
        self.n_upd = 0
        self.n_calls = 0
        #: the kernels' arguments (ins_kernels: declared by name, passed as plain tuples)
        self.rows = tuple(SensorRows(self.ring, self.prm, self.btru, self.imu, self.gnss,
                                     self.radar, self.next_t, self.init, self.due))
        self.scores = tuple(Scores(self.ring, self.init, self.gnss, self.imu, self.cvar,
                                   self.err, self.fix_k, self.nees, self.n_fix, self.k0))
        self.outs = tuple(Outputs(self.p_out, self.v_out, self.R_out, self.w_out))
        bk = self.bank   # its arrays are made once and written in place: views taken once
        self.bank_view = (tuple(BankView(bk.x_out, bk.x_core, bk.P, bk.nis, bk.gate_state,
                                         bk.core_tick)) if bk is not None else ())
        self.logging = any(fb.log is not None for fb in fbs)
        self._logged: list[tuple[int, Any]] | None = None
        self._pdiag = np.zeros((0, 0))

    def imu_tap(self, walked: np.ndarray) -> None:
        """The engine's IMU's walked biases of its buffered blocks (N, block, 6:
        :attr:`~ag_uav.vehicle.sensors_batched.BatchImu.walked`, refilled in place by the
        sensing stage before this stage's tick): read as the bias states' truth instead of the
        twins' (the same draws: :meth:`~ag_uav.vehicle.imu.ImuSensor.walk_block`), when its
        block is the twins'."""
        if walked.shape[1] != self.blk:
            return
        self.btru, self.twins = walked, False
        self.rows = tuple(SensorRows(self.ring, self.prm, self.btru, self.imu, self.gnss,
                                     self.radar, self.next_t, self.init, self.due))

    def truth_tap(self, R: np.ndarray, omega: np.ndarray) -> None:
        """The engine's true attitude (N, 9) and body rate (N, 3) arrays (written in place each
        tick): read by the sensor models (heading, antenna velocity, slant range) and the
        scores only."""
        self.R_true, self.w_true = R, omega

    def update(self, k: int, t: float, p: np.ndarray, v: np.ndarray, imu: tuple | None,
               act: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One control tick of every active vehicle: sensors → INS → (p, v, R) of the flown
        filter. Per tick: one kernel for the truth ring, the IMU rows and the due fixes, the
        receivers of the vehicles with a fix due (Python, at the fix rate), the radar (at its
        rate), the INS (one kernel), one kernel for the outputs and the score records."""
        if imu is None:
            raise ConfigError("estimator.nav = \"ins\" needs the MEMS IMU (imu.model = "
                              "\"mems\", estimator.imu = true)")
        if self.R_true is None:   # no engine tap: the sensors that need the attitude drop out
            self.truth_tap(np.full((self.NV, 9), np.nan), np.full((self.NV, 3), np.nan))
        if k >= self.b_next:   # the next block of the walked biases (scoring truth)
            if self.twins:
                for i, fb in enumerate(self.fbs):
                    self.btru[i] = fb.imu_twin.walk_block()
            self.b_next += self.blk
        # Truth's fields, as a plain tuple (ins_kernels: a named one types slower)
        f_m, _, om = imu   # the engine's (f̃, R, ω̃)
        truth = (p, v, self.R_true, self.w_true, act, f_m, om)
        flags = tick_in(truth, self.rows, k, t, k % self.blk)
        if flags & FIX_DUE:
            self._fixes(k, t)
        if self.radar_on and k % self.radar_every == 0:
            self._radar(k, act)
        if self.bank is not None:
            t0 = time.perf_counter_ns()
            self.bank.step_raw(self.imu, self.gnss, self.radar)
            if self.n_calls:   # the first call may compile (or load) the kernel: not timed
                self.upd_ns += time.perf_counter_ns() - t0
                self.n_upd += 1
            self.n_calls += 1
            outputs(self.bank_view, (p, v, self.R_true, act), self.scores, self.outs, k,
                    self.nr, self.flown)
        if flags & NOT_INITIALISED:
            self._pre_init(act)
        if self.logging and flags & FIX_DUE:
            self._log(t, p)
        if self.flown < 0:   # estimator.name = "true": the controller flies on the truth
            return p, v
        return self.p_out, self.v_out, self.R_out, self.w_out

    def pos_sigma(self, out: np.ndarray) -> None:
        """Each vehicle's horizontal position 1σ (m) of the flown rule (NaN before its first fix):
        :func:`~ag_uav.navigation.aiding.horizontal_sigma`."""
        P = None if self.bank is None or self.flown < 0 else self.bank.P[self.flown::self.nr]
        horizontal_sigma(P, 0, 1, self.init, out)

    def _log(self, t: float, p: np.ndarray) -> None:
        """``/estimator/<rule>`` of the vehicles that fused a fix this tick: the output state
        (16) and the core's P diagonal (15), as the position-filter bank logs its filters."""
        if self._logged is None:  # (vehicle, its log); the P diagonal as a view, once
            self._logged = [(i, fb.log) for i, fb in enumerate(self.fbs) if fb.log is not None]
            self._pdiag = np.diagonal(self.bank.P, axis1=1, axis2=2)
        gnss, x, pd, nr = self.gnss, self.bank.x_out, self._pdiag, self.nr
        for i, log in self._logged:
            if math.isfinite(gnss[i, 0]):
                r = i * nr
                log.estimator_bank(t, self.names, x[r:r + nr], pd[r:r + nr], p[i])

    def _fixes(self, k: int, t: float) -> None:
        """The receivers of the vehicles with a fix due (Python, one vehicle at a time at the
        fix rate, on the truth ring's delayed row as a list); what they give goes into the
        batch's rows in one assignment each (``gnss``, ``cvar``, ``aid_on``, ``next_t``)."""
        ii = np.flatnonzero(self.due).tolist()
        slot = max(k - self.D, 0) % (self.D + 1)
        rings = self.ring[ii, slot, :RG.YAW_END].tolist()   # antenna p, v, heading
        rl, init = self.range_last[ii].tolist(), self.init[ii].tolist()
        fused: list[int] = []
        rows: list[list[float]] = []
        cvar: list[list[float]] = []
        aid_on: list[float] = []
        for i, r, rng, ok in zip(ii, rings, rl, init, strict=True):
            if not math.isfinite(r[0]):   # before D ticks of history: the oldest there is
                r = self.ring[i, 0, :RG.YAW_END].tolist()
            fb = self.fbs[i]
            row = fb.fix(t, r[RG.ANT_P:RG.ANT_P_END], r[RG.ANT_V:RG.ANT_V_END], r[RG.YAW])
            if row is None or not all(math.isfinite(c) for c in row[GN.P:GN.P_END]):
                continue
            if not ok:
                if abs(float(np.linalg.norm(self.imu[i, :IM.F_END])) - 9.81) < 0.5:  # at rest
                    self._initialise(i, k, np.array(row))
                continue
            aid = rng < fb.aid_m and math.hypot(row[GN.V + X], row[GN.V + Y]) < fb.aid_mps
            if aid:
                row[GN.VAR_P + Z] = NOT_FUSED_VAR  # range aid: the radar is the height source
                fb.range_aid_fixes += 1
            aid_on.append(1.0 if aid else 0.0)
            fused.append(i)
            rows.append(row)
            cvar.append(fb.cvar)
            if fb.last_false:
                fb.false_k.append(k)
        self.next_t[ii] = [self.fbs[i].gps.next_fix_t for i in ii]
        if fused:
            self.gnss[fused] = rows
            self.cvar[fused] = cvar
            self.aid_on[fused] = aid_on

    def _initialise(self, i: int, k: int, row: np.ndarray) -> None:
        """On the ground at the first fix (module docstring)."""
        f = self.imu[i, IM.F:IM.F_END]
        roll = math.atan2(f[Y], f[Z])   # φ = atan2(f̃_y, f̃_z)
        pitch = math.atan2(-f[X], math.hypot(f[Y], f[Z]))   # θ = atan2(−f̃_x, √(f̃_y² + f̃_z²))
        q = np.empty(4)
        euler_to_quat(roll, pitch, float(row[GN.YAW]), q)
        Rm = np.empty(9)
        quat_to_rot_flat(q, Rm)
        p = row[GN.P:GN.P_END] - Rm.reshape(3, 3) @ np.asarray(ANTENNA)   # fix − R r_ant
        im = self.cfg.imu
        sd = np.r_[np.sqrt(row[GN.VAR_P:GN.VAR_P_END]), [0.1] * 3, [DEG, DEG, 2 * DEG],
                   [max(im.accel_bias_mg * 1e-3 * 9.81, 1e-3)] * 3,
                   [max(im.gyro_bias_dps, 1e-3) * DEG] * 3]
        self.bank.reset_vehicle(i, p, np.zeros(3), q, P0=sd)
        self.init[i] = True
        self.k0[i] = k - 1   # the reset state is the tick before: this tick's step moves it on

    def _radar(self, k: int, act: np.ndarray) -> None:
        """The radar's slant range of every active vehicle (:func:`radar_rows`; its noise from
        the vehicle's own stream, drawn in blocks of 4096)."""
        sig = self.cfg.gps.radar_sigma_m
        while radar_rows(self.ring, k % (self.D + 1), act, self.noise, self.noise_i, sig,
                         self.radar, self.range_last):
            for i in np.flatnonzero(act & (self.noise_i >= self.noise.shape[1])).tolist():
                self.noise[i] = self.fbs[i].radar_rng.standard_normal(self.noise.shape[1])
                self.noise_i[i] = 0

    def _pre_init(self, act: np.ndarray) -> None:
        """Vehicles without a fix yet: radar height, zero velocity, levelled attitude."""
        for i in np.flatnonzero(act & ~self.init):
            f = self.imu[i, IM.F:IM.F_END]
            q = np.empty(4)
            euler_to_quat(math.atan2(f[Y], f[Z]), math.atan2(-f[X], math.hypot(f[Y], f[Z])), 0.0,
                          q)
            quat_to_rot_flat(q, self.R_out[i])
            h = self.radar[i, RN.RANGE]
            self.p_out[i, :Z] = 0.0
            if np.isfinite(h):   # body height = slant range + the radar's offset (level)
                self.p_out[i, Z] = h - RADAR[Z]
            self.v_out[i] = 0.0

    def finish(self, flown: np.ndarray) -> None:
        """The records back into the per-run feedbacks (for their ``scores``/``summary``)."""
        us = round(self.upd_ns / max(self.n_upd, 1) / 1e3 / self.NV, 2)
        counters = self.bank.counters if self.bank is not None else {}
        for i, fb in enumerate(self.fbs):
            n, nf = int(flown[i]), int(self.n_fix[i])
            e = np.ascontiguousarray(self.err[:n, i])
            fb.rec = {**{name: e[:, c] for name, c in ERRORS.offset.items()},  # herr .. yaw
                      "fix_k": self.fix_k[i, :nf], "nees": self.nees[i, :nf, NR.NEES15],
                      "nis": self.nees[i, :nf, NR.NISP], "nis_vel": self.nees[i, :nf, NR.NISV],
                      "nis_yaw": self.nees[i, :nf, NR.NISY],
                      **{f"nees_{b}": self.nees[i, :nf, NR.POS + m]
                         for m, b in enumerate(BLOCKS)},
                      "not_pd": self.nees[i, :nf, NR.NOTPD],
                      "gate": self.nees[i, :nf, NR.GATE],
                      "nis_radar": (self.bank.radar_nis[i * self.nr:(i + 1) * self.nr].tolist()
                                    if self.bank is not None else []),
                      "update_us": us,
                      "counters": {key: [int(x) for x in val[i * self.nr:(i + 1) * self.nr]]
                                   for key, val in counters.items()}}

