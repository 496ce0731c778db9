"""The product's INS on a recorded flight: one :class:`estimators.ins.BatchINS` of one vehicle
with the four GNSS rules (the flown one first), its gate and step latch, run on the log's IMU
samples and fixes — the very kernel a simulated flight navigates on, with the settings
:func:`ag_uav.navigation.ins_feedback.ins_config` gives the default config (σ, kernel, recovery,
PCA window, gate, reset and latch), and these from the log:

* **Rate and Δt.** The IMU is put on a uniform grid at its nominal rate (median interval) by
  linear interpolation (real logs jitter; the INS integrates at a fixed Δt).
* **Process noise.** The per-sample white noise of each sensor is read from the log itself:
  σ = std(f̃_k+1 − f̃_k)/√2 per axis (the difference removes the slow motion and keeps the
  white part, vibration included), the median over the three axes, times the simulated
  flight's margins on the variance (``estimator.ins_q_accel``, ``estimator.ins_q_gyro`` of the
  default config: × 1, × 1), or ``q_margins`` where asked.  The samples are taken as the
  sensor's means over Δt (delta-angles and delta-velocities over the interval) with the coning
  and sculling corrections, as the simulated flight's ``imu.sampling = "increments"`` (``coning
  = False``: rates held over Δt, no correction).  The bias random walks
  are the ``[imu]`` defaults; the initial bias σ are ``bias_sd`` (0.2 m/s², 0.3 °/s: a MEMS
  unit's turn-on bias without a calibration).
* **Fixes.** A fix stamped ``t`` (the arrival stamp of an autopilot log, whose position is
  ``gnss_delay_s`` older; the fix's own epoch for a CSV or a fix built from a reference) is
  handed to the bank at the first tick at or after ``t`` with its age (tick − epoch); the bank's
  fusion horizon is set to cover it (delayed fusion, :mod:`estimators.ins`).  GNSS velocity is
  fused where the log has it; there is no heading fix (a single antenna).
* **GNSS from a reference** (``gnss_from_reference = PRESET``): fixes at ``gnss_rate_hz`` from
  the reference's position plus the error series of the product's receiver preset
  (:meth:`ag_uav.vehicle.gps.GpsSensor.generate_errors`, seeded), R = the preset's reported
  variance for the fix's type (floored at (1 cm)² as the INS chain floors it); the velocity is
  the reference's (central difference over ±0.05 s) plus white noise of ``gps.velocity_sigma_mps``
  of the default config (0.05 m/s), from a stream of the same seed; its variance is that σ²
  plus the differencing's own error where the record logs a speed to measure it by
  (:func:`difference_sigma`: 0.11–0.25 m/s on the Phantom paths, where 0.05 m/s alone
  left the velocity NIS at ~10 for 3 and the gate shut the INS out on some paths).
* **GNSS gap** (``gnss_gap`` = (start, duration) s from the replay's start; start < 0: the
  middle): no fix inside; the drift is the horizontal error at the gap's last tick.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from estimators.ins import RULES, BatchINS
from numkit.geometry import rots_to_euler, rots_to_quats

from ...vehicle.gps import GpsSensor, derive_seed
from .align import clock_lag, initial_state, mount_rotation
from .data import DEG, IMU, FlightLog, ReplayError

__all__ = ["ReplayOptions", "ReplayResult", "run_replay"]

R_FLOOR = 1e-4


@dataclass
class ReplayOptions:
    """What ``ag-uav replay`` is asked (module docstring); ``flown``: the rule reported as
    flown (the default config's ``estimator.name``)."""

    flown: str | None = None
    gnss_from_reference: str | None = None
    gnss_rate_hz: float = 5.0
    seed: int = 0
    gnss_gap: tuple[float, float] | None = None
    lever_arm: tuple[float, float, float] | None = None
    gnss_delay_s: float | None = None
    clock_lag_s: float | None = None
    heading: str = "auto"
    bias_sd: tuple[float, float] = (0.2, 0.3)
    gnss_velocity: bool = True
    q_margins: tuple[float, float] | None = None
    coning: bool | None = None


@dataclass
class ReplayResult:
    """A replay's records: the grid ``t`` (from the start tick), every rule's output state
    ``x`` (K, rules, 16) and the flown rule's core P diagonal ``pdiag`` (K, 15), the fixes as
    handed to the INS (``fix_t``, ``fix_p``, ``fix_var``), per rule the processed fixes
    (``fix_events[rule]``: rows of time, gate verdict 0 fused / 1 rejected / 2 reset / 3 held
    by the latch, position NIS, velocity NIS) and ``info`` (lag, mounting, noise, start)."""

    log: FlightLog
    rules: tuple[str, ...]
    t: np.ndarray
    x: np.ndarray
    pdiag: np.ndarray
    fix_t: np.ndarray
    fix_p: np.ndarray
    fix_var: np.ndarray
    fix_events: dict[str, np.ndarray]
    info: dict = field(default_factory=dict)
    gap: tuple[float, float] | None = None


def _prepare_imu(log: FlightLog, opts: ReplayOptions, info: dict) -> None:
    """Clock lag and mounting onto the reference (a Phantom path: both unknown; otherwise as
    given, default none)."""
    ref = log.reference
    lag = opts.clock_lag_s
    if lag is None and log.source == "phantom" and ref is not None:
        lag, corr = clock_lag(log.imu_t, log.imu, ref)
        info["clock_lag_s"], info["clock_lag_corr"] = round(lag, 4), round(corr, 4)
    elif lag is not None:
        info["clock_lag_s"] = lag
    if lag:
        log.imu_t = log.imu_t + lag
    if log.source == "phantom" and ref is not None:
        M, res = mount_rotation(log.imu_t, log.imu, ref)
        acc, gyr = log.imu[:, IMU.ACC:IMU.ACC_END], log.imu[:, IMU.GYRO:IMU.GYRO_END]
        log.imu = np.concatenate([acc @ M, gyr @ M], axis=1)
        info["mount_rpy_deg"] = np.round(rots_to_euler(M[None])[0] / DEG, 2).tolist()
        info["mount_rate_residual_dps"] = round(res / DEG, 3)


def gnss_from_reference(log: FlightLog, preset: str, rate_hz: float, seed: int) -> None:
    """Fixes built from the reference (module docstring), in place of the log's."""
    from ...config import load_config

    ref = log.reference
    if ref is None:
        raise ReplayError(f"{log.path}: --gnss-from-reference needs a reference track")
    root = np.random.SeedSequence(seed)
    try:
        gps = GpsSensor.from_preset(preset, derive_seed(root, "replay_gnss"), rate_hz=rate_hz)
    except ValueError as e:
        raise ReplayError(f"--gnss-from-reference {preset}: {e}") from None
    t = np.arange(math.ceil(ref.t[0] * rate_hz), math.floor(ref.t[-1] * rate_hz) + 1) / rate_hz
    err, types = gps.generate_errors(t.size, with_fix_type=True)
    p, _ = ref.at(t)
    pm, _ = ref.at(np.clip(t - 0.05, ref.t[0], ref.t[-1]))
    pp, _ = ref.at(np.clip(t + 0.05, ref.t[0], ref.t[-1]))
    span = np.clip(t + 0.05, ref.t[0], ref.t[-1]) - np.clip(t - 0.05, ref.t[0], ref.t[-1])
    v = (pp - pm) / span[:, None]
    sv = load_config(None).gps.velocity_sigma_mps
    s_fd = difference_sigma(ref, t, v)
    rng = np.random.default_rng(derive_seed(root, "replay_gnss_velocity"))
    v = v + sv * rng.standard_normal(v.shape)
    names = gps.fix_types
    var = np.array([gps.reported_variance(names[k] if k >= 0 else None) for k in types])
    ok = np.all(np.isfinite(err), axis=1) & np.all(np.isfinite(p), axis=1)
    log.gnss_t, log.gnss_p = t[ok], (p + err)[ok]
    log.gnss_var = np.maximum(var[ok], R_FLOOR)
    log.gnss_v, log.gnss_var_v = v[ok], np.full((int(ok.sum()), 3), sv**2 + s_fd**2)
    if s_fd > 0:
        log.notes.append(f"GNSS velocity σ {math.hypot(sv, s_fd):.3f} m/s: {sv:g} m/s of "
                         f"receiver noise and {s_fd:.3f} m/s, the RMS of the reference's "
                         "differenced horizontal speed less the speed it logs")
    log.gnss_delay_s = 0.0
    log.notes.append(f"GNSS built from the reference: preset {preset}, {rate_hz:g} Hz, seed {seed}"
                     f" ({int(ok.sum())} fixes)")


def difference_sigma(ref, t: np.ndarray, v: np.ndarray) -> float:
    """The error of a velocity differenced from the reference's positions, where the record
    logs its own speed beside them: RMS(|v_h| − speed) over the fix epochs (the positions'
    noise over the ±0.05 s span, the lever arm's ω × r, the speed's own error: all taken as the
    built fix's); 0 without a logged speed (a reference known exactly, as a test's)."""
    if ref.speed is None:
        return 0.0
    sp = np.interp(t, ref.t, ref.speed, left=np.nan, right=np.nan)
    d = np.hypot(v[:, 0], v[:, 1]) - sp
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d * d))) if d.size else 0.0


def white_sigma(a: np.ndarray) -> float:
    """Per-sample white noise σ of a sampled signal (n, 3): median over the axes of
    std(diff)/√2 (module docstring)."""
    return float(np.median(np.std(np.diff(a, axis=0), axis=0)) / math.sqrt(2.0))


def _ins_cfg(log: FlightLog, opts: ReplayOptions, dt: float, delay: float, lever: np.ndarray,
             info: dict):
    """The default config's INS settings with the log's noise, rate, delay and lever arm
    (module docstring); the margins and the coning switch as the simulated flight's unless
    ``opts`` says otherwise."""
    from ...config import load_config
    from ..ins_feedback import ins_config

    cfg = load_config(None)
    e = cfg.estimator
    sa = white_sigma(log.imu[:, IMU.ACC:IMU.ACC_END])
    sg = white_sigma(log.imu[:, IMU.GYRO:IMU.GYRO_END])
    info["imu_white_sigma"] = {"accel_mps2": round(sa, 4), "gyro_dps": round(sg / DEG, 4)}
    qa, qg = opts.q_margins if opts.q_margins is not None else (e.ins_q_accel, e.ins_q_gyro)
    base = ins_config(cfg)
    coning = base.coning if opts.coning is None else bool(opts.coning)
    info["q_margins"], info["coning"] = [qa, qg], coning
    return dataclasses.replace(
        base, dt=dt, accel_sigma=sa * math.sqrt(qa), gyro_sigma=sg * math.sqrt(qg),
        lever_arm=tuple(lever), delay_s=delay + 2.0 * dt, delayed=True, coning=coning), e.name


def _gap(opts: ReplayOptions, t0: float, t1: float) -> tuple[float, float] | None:
    if opts.gnss_gap is None:
        return None
    s, d = opts.gnss_gap
    start = 0.5 * (t0 + t1) - 0.5 * d if s < 0 else t0 + s
    if not (t0 <= start and start + d <= t1 and d > 0):
        raise ReplayError(f"--gnss-gap {s:g},{d:g}: outside the replay ({t1 - t0:.1f} s long)")
    return (start, start + d)


def run_replay(log: FlightLog, opts: ReplayOptions) -> ReplayResult:
    """Align, build the bank, run it over the log (module docstring)."""
    info: dict = {"source": log.source, "path": log.path}
    _prepare_imu(log, opts, info)
    if opts.gnss_from_reference:
        gnss_from_reference(log, opts.gnss_from_reference, opts.gnss_rate_hz, opts.seed)
    elif log.source == "phantom":
        raise ReplayError(f"{log.path}: a Phantom 4 RTK path has no GNSS of its own: give "
                          "--gnss-from-reference PRESET (e.g. rtk)")
    if not opts.gnss_velocity:
        log.gnss_v = None
    rate = log.imu_rate_hz
    dt = 1.0 / rate
    t_grid = np.arange(log.imu_t[0], log.imu_t[-1], dt)
    imu = np.stack([np.interp(t_grid, log.imu_t, log.imu[:, j]) for j in range(6)], axis=1)
    lever = np.asarray(opts.lever_arm if opts.lever_arm is not None else
                       (log.lever_arm if log.lever_arm is not None else (0.0, 0.0, 0.0)), float)
    delay = opts.gnss_delay_s if opts.gnss_delay_s is not None else log.gnss_delay_s
    icfg, flown = _ins_cfg(log, opts, dt, delay, lever, info)
    flown = opts.flown or flown
    rules = (flown,) + tuple(r for r in RULES if r != flown)
    init = initial_state(log, t_grid, imu, lever, opts.heading)
    k0 = init["k0"]
    gap = _gap(opts, t_grid[k0], t_grid[-1])
    keep = np.ones(log.gnss_t.size, dtype=bool)
    if gap is not None:
        keep = ~((log.gnss_t >= gap[0]) & (log.gnss_t < gap[1]))
    bank = BatchINS(1, icfg, rules)
    bs_a, bs_g = opts.bias_sd
    sd = np.r_[init["sd9"], [bs_a] * 3, [bs_g * DEG] * 3]
    bank.reset(init["p"], init["v"], rots_to_quats(init["R"][None])[0], P0=sd)
    info.update({"imu_rate_hz": round(rate, 3), "gnss_delay_s": delay,
                 "lever_arm_m": lever.tolist(), "rules": list(rules), "flown": flown,
                 "start_t_s": round(float(t_grid[k0]), 3),
                 "init": {k: init[k] for k in ("position", "attitude", "heading")}})
    res = _loop(bank, log, t_grid[k0:], imu[k0:], keep, delay, rules)
    res.info.update(info)
    res.gap = gap
    return res


def _loop(bank: BatchINS, log: FlightLog, t: np.ndarray, imu: np.ndarray, keep: np.ndarray,
          delay: float, rules: tuple[str, ...]) -> ReplayResult:
    """One bank step per IMU tick; a due fix goes in with its age; the processed fixes are
    read off the bank's counters (a fix is fused or rejected when the core reaches it)."""
    K, nr = t.size, len(rules)
    x = np.full((K, nr, 16), np.nan)
    pdiag = np.full((K, 15), np.nan)
    x[0] = bank.x_out
    pdiag[0] = np.diagonal(bank.P[0])
    gt = log.gnss_t
    idx = np.flatnonzero(keep & (gt >= t[0]))
    has_v = log.gnss_v is not None
    cnt = bank.counters
    seen = cnt["gnss_fused"] + cnt["gate_rejected_pos"]
    ev: list[list[list[float]]] = [[] for _ in rules]
    u = np.zeros((1, 6))
    g = np.full((1, 15), np.nan)
    j, used = 0, []
    for k in range(1, K):
        u[0] = imu[k]
        gin = None
        if j < idx.size and gt[idx[j]] <= t[k] + 1e-9:
            i = idx[j]
            j += 1
            g[0] = BatchINS.gnss_row(
                log.gnss_p[i], log.gnss_v[i] if has_v else None, None, log.gnss_var[i],
                log.gnss_var_v[i] if has_v else (1.0,) * 3, 1.0, age_s=t[k] - gt[i] + delay)
            gin = g
            used.append(i)
        bank.step(u, gin)
        x[k] = bank.x_out
        pdiag[k] = np.diagonal(bank.P[0])
        now = cnt["gnss_fused"] + cnt["gate_rejected_pos"]
        for r in np.flatnonzero(now != seen):
            tc = t[0] + float(bank.core_tick[r]) * (t[1] - t[0])
            ev[r].append([tc, float(bank.gate_state[r]), float(bank.nis[r, 0]),
                          float(bank.nis[r, 1])])
        seen = now.copy()
    used_a = np.asarray(used, dtype=int)
    events = {r: np.asarray(ev[i], dtype=float).reshape(-1, 4) for i, r in enumerate(rules)}
    return ReplayResult(log, rules, t, x, pdiag, gt[used_a] - delay, log.gnss_p[used_a],
                        log.gnss_var[used_a], events)
