"""Putting a recorded IMU on the reference's clock and axes, and the INS's initial state.

**Clock lag** (:func:`clock_lag`): the magnitude of the body rate seen by the gyro, |ω̃| (no
mounting needed: a rotation keeps the norm), against the reference's |ω| from its attitude
(|Log(R_kᵀ R_{k+1})| / Δt), both on a common grid at ``fs`` Hz, the gyro's smoothed over the
reference's sample interval; the lag is the shift of the IMU's clock that maximises their
normalised cross-correlation over ±``max_lag_s``, refined by a parabola through the peak and
its neighbours.  ``t_ref = t_imu + lag``.  (The yaw rate alone — the gyro about the measured
vertical against the heading's rate — was tried first: on the periodic paths of the Phantom 4
RTK set its correlation peaks at 0.14–0.72 and at lags seconds apart from path to path; the
rate magnitude peaks at 0.976–0.997, with one lag on runs of consecutive paths.)

**Mounting** (:func:`mount_rotation`): the rotation M (IMU axes → body axes) with ω_imu = M
ω_body, by the orthogonal Procrustes / Kabsch solution (Kabsch 1976, *Acta Cryst.* A32:922) on
the reference's body rates ω_k = Log(R_kᵀ R_{k+1}) / Δt (between its samples) and the IMU's
rates averaged over the same intervals: H = Σ ω_imu ω_bodyᵀ = U S Vᵀ, M = U diag(1, 1,
det(U Vᵀ)) Vᵀ.

**Initial state** (:func:`initial_state`): position the first fix less the lever arm (or the
reference's); velocity the fix's (or the reference's, or 0); roll and pitch from the
reference's attitude, else levelled from the accelerometer (φ = atan2(g_y, g_z), θ =
atan2(−g_x, √(g_y² + g_z²)), g = f − Rᵀ a with a the GNSS velocity's slope about the start:
:func:`_level`); heading from the reference, else from
the autopilot's estimate, else from the GNSS course over ground (ψ = atan2(v_n, v_e) in ENU)
at the first fix faster than 1 m/s, where the filter then starts.
"""

from __future__ import annotations

import math

import numpy as np

from numkit import X, Y, Z
from numkit.geometry import euler_to_rots, rots_to_euler

from .data import DEG, IMU, FlightLog, ReplayError, Track

__all__ = ["clock_lag", "initial_state", "mount_rotation", "rot_log"]


def rot_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) → rotation vectors (n, 3) (the SO(3) logarithm)."""
    c = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    ang = np.arccos(c)
    v = np.stack([R[:, Z, Y] - R[:, Y, Z], R[:, X, Z] - R[:, Z, X], R[:, Y, X] - R[:, X, Y]], 1)
    s = np.sin(ang)
    k = np.where(s > 1e-9, ang / (2.0 * np.where(s > 1e-9, s, 1.0)), 0.5)
    return v * k[:, None]


def _smooth(y: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return y
    return np.convolve(y, np.ones(n) / n, mode="same")


def ref_rate(ref: Track) -> tuple[np.ndarray, np.ndarray]:
    """(mid-interval times, |ω| rad/s) of the reference's body rate between its samples."""
    if ref.R is None:
        raise ReplayError("the reference has no attitude: no clock alignment possible "
                          "(give --clock-lag S)")
    w = rot_log(np.einsum("nji,njk->nik", ref.R[:-1], ref.R[1:]))
    return 0.5 * (ref.t[1:] + ref.t[:-1]), np.linalg.norm(w, axis=1) / np.diff(ref.t)


def clock_lag(imu_t: np.ndarray, imu: np.ndarray, ref: Track, max_lag_s: float = 10.0,
              fs: float = 50.0) -> tuple[float, float]:
    """(lag s, peak normalised correlation): ``t_ref = t_imu + lag`` (module docstring)."""
    dt_imu = float(np.median(np.diff(imu_t)))
    dt_ref = float(np.median(np.diff(ref.t)))
    w_imu = _smooth(np.linalg.norm(imu[:, IMU.GYRO:IMU.GYRO_END], axis=1),
                    max(1, int(round(dt_ref / dt_imu))))
    tm, w_ref = ref_rate(ref)
    grid = np.arange(tm[0], tm[-1], 1.0 / fs)
    y_ref = np.interp(grid, tm, w_ref)
    n_l = int(round(max_lag_s * fs))
    lags = np.arange(-n_l, n_l + 1) / fs
    corr = np.full(lags.size, -np.inf)
    for i, L in enumerate(lags):
        tq = grid - L
        m = (tq >= imu_t[0]) & (tq <= imu_t[-1])
        if m.sum() < 0.5 * grid.size:
            continue
        a = np.interp(tq[m], imu_t, w_imu)
        b = y_ref[m]
        a, b = a - a.mean(), b - b.mean()
        den = math.sqrt(float(a @ a) * float(b @ b))
        corr[i] = float(a @ b) / den if den > 0 else -np.inf
    if not np.isfinite(corr).any():
        raise ReplayError("the IMU and the reference do not overlap in time: no clock alignment "
                          "(give --clock-lag S)")
    i = int(np.argmax(corr))
    lag = lags[i]
    if 0 < i < lags.size - 1 and np.isfinite(corr[i - 1]) and np.isfinite(corr[i + 1]):
        d = corr[i - 1] - 2 * corr[i] + corr[i + 1]
        if d < 0:
            lag += 0.5 * (corr[i - 1] - corr[i + 1]) / d / fs
    return float(lag), float(corr[i])


def mount_rotation(imu_t: np.ndarray, imu: np.ndarray, ref: Track) -> tuple[np.ndarray, float]:
    """(M, RMS rate residual rad/s): ω_imu = M ω_body (module docstring); ``imu_t`` already on
    the reference's clock."""
    if ref.R is None:
        raise ReplayError("the reference has no attitude: the IMU's mounting cannot be found")
    dt = np.diff(ref.t)
    w_body = rot_log(np.einsum("nji,njk->nik", ref.R[:-1], ref.R[1:])) / dt[:, None]
    # the IMU's rate averaged over each reference interval (trapezoidal cumulative integral)
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(
        0.5 * (imu[1:, IMU.GYRO:IMU.GYRO_END] + imu[:-1, IMU.GYRO:IMU.GYRO_END])
        * np.diff(imu_t)[:, None], axis=0)])
    a, b = ref.t[:-1], ref.t[1:]
    ok = (a >= imu_t[0]) & (b <= imu_t[-1]) & np.all(np.isfinite(w_body), axis=1)
    if ok.sum() < 10:
        raise ReplayError("the IMU and the reference overlap by less than 10 samples: the "
                          "IMU's mounting cannot be found")
    w_imu = np.stack([(np.interp(b[ok], imu_t, cum[:, j]) - np.interp(a[ok], imu_t, cum[:, j]))
                      / dt[ok] for j in range(3)], axis=1)
    H = w_imu.T @ w_body[ok]
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))])
    M = U @ D @ Vt
    res = w_imu - w_body[ok] @ M.T
    return M, float(np.sqrt(np.mean(np.sum(res**2, axis=1))))


def initial_state(log: FlightLog, t_grid: np.ndarray, imu: np.ndarray, lever: np.ndarray,
                  heading: str) -> dict:
    """The INS's start: tick index ``k0``, p, v, q (as a rotation matrix ``R``), the 15
    initial standard deviations' first 9 (position from the fix, velocity, tilt/yaw) and what
    each came from (module docstring).  ``heading``: "auto", "reference", "autopilot" or
    "gnss-course"."""
    ref, ap = log.reference, log.autopilot
    src = heading
    if heading == "auto":
        src = ("reference" if ref is not None and ref.R is not None else
               "autopilot" if ap is not None and ap.R is not None else "gnss-course")
    if src in ("reference", "autopilot") and (ref if src == "reference" else ap) is None:
        raise ReplayError(f"--heading {src}: the log has no {src} attitude")
    k0 = 0
    if src == "gnss-course":
        if log.gnss_v is None or not log.gnss_t.size:
            raise ReplayError("no heading source: no reference, no autopilot attitude and no "
                              "GNSS velocity (give a reference or --heading)")
        sp = np.hypot(log.gnss_v[:, 0], log.gnss_v[:, 1])
        j = np.flatnonzero(sp > 1.0)
        if not j.size:
            raise ReplayError("--heading gnss-course: the GNSS speed never exceeds 1 m/s")
        k0 = int(np.searchsorted(t_grid, log.gnss_t[j[0]]))
    elif log.gnss_t.size and ref is None:   # start at the first fix
        k0 = int(np.searchsorted(t_grid, log.gnss_t[0]))
    if ref is not None:
        k0 = max(k0, int(np.searchsorted(t_grid, ref.t[0])))
    elif src == "autopilot":   # its attitude may start later than the IMU
        k0 = max(k0, int(np.searchsorted(t_grid, ap.t[0])))
    k0 = min(k0, t_grid.size - 2)
    t0 = t_grid[k0]
    R, how_att = _attitude(log, t_grid, imu, k0, src)
    p, v, sd_p, how_p = _position(log, t0, R, lever)
    sd = np.r_[sd_p, [0.3] * 3, [2 * DEG] * 2, [5 * DEG if src != "gnss-course" else 20 * DEG]]
    return {"k0": k0, "p": p, "v": v, "R": R, "sd9": sd, "attitude": how_att,
            "heading": src, "position": how_p}


def _attitude(log: FlightLog, t_grid, imu, k0: int, src: str) -> tuple[np.ndarray, str]:
    t0 = t_grid[k0]
    ref = log.reference
    if src in ("reference", "autopilot"):
        tr = ref if src == "reference" else log.autopilot
        _, Ry = tr.at(np.array([t0]))
        if not np.all(np.isfinite(Ry)):
            raise ReplayError(f"--heading {src}: no {src} attitude at the start (t = {t0:.2f} s)")
        yaw = float(rots_to_euler(Ry)[0, Z])
    else:
        j = min(int(np.searchsorted(log.gnss_t, t0)), log.gnss_t.size - 1)
        yaw = math.atan2(log.gnss_v[j, 1], log.gnss_v[j, 0])
    Rr = ref.at(np.array([t0]))[1] if ref is not None and ref.R is not None else None
    if Rr is not None and np.all(np.isfinite(Rr)):
        rpy, how = rots_to_euler(Rr)[0], "roll/pitch from the reference"
    else:
        rpy, comp = _level(log, t_grid, imu, k0, yaw)
        how = "roll/pitch levelled from the accelerometer" + (
            " less the GNSS acceleration" if comp else "")
    rpy[Z] = yaw
    return euler_to_rots(*[np.array([a]) for a in rpy])[0], f"{how}, heading from {src}"


def _level(log: FlightLog, t_grid, imu, k0: int, yaw: float) -> tuple[np.ndarray, bool]:
    """Roll and pitch from the accelerometer: f = Rᵀ(a − g_w), so Rᵀ e_z g = f − Rᵀ a; the
    world acceleration a is the slope of the GNSS velocity over the fixes within ±0.6 s of the
    start (none: a = 0, the vehicle taken at rest), f the mean over the same window (0.2 s
    without it); three rounds of levelling f − R(φ, θ, ψ)ᵀ a.  Returns (roll, pitch, 0) and
    whether the acceleration was taken off."""
    t0 = t_grid[k0]
    a_w, comp = np.zeros(3), False
    sel = slice(k0, k0 + max(1, int(round(0.2 / float(t_grid[1] - t_grid[0])))))
    if log.gnss_v is not None and log.gnss_t.size >= 2:
        te = log.gnss_t - log.gnss_delay_s
        m = (np.abs(te - t0) <= 0.6) & np.all(np.isfinite(log.gnss_v), axis=1)
        if m.sum() >= 2 and np.ptp(te[m]) > 0:
            a_w, comp = np.polyfit(te[m], log.gnss_v[m], 1)[0], True
            sel = (t_grid >= te[m].min()) & (t_grid <= te[m].max())
    f = imu[sel, IMU.ACC:IMU.ACC_END].mean(axis=0)
    rpy = np.array([0.0, 0.0, yaw])
    g = f
    for _ in range(3):
        rpy[X], rpy[Y] = math.atan2(g[Y], g[Z]), math.atan2(-g[X], math.hypot(g[Y], g[Z]))
        g = f - euler_to_rots(*[np.array([a]) for a in rpy])[0].T @ a_w
    return np.array([rpy[0], rpy[1], 0.0]), comp


def _position(log: FlightLog, t0: float, R: np.ndarray, lever: np.ndarray):
    if log.gnss_t.size:
        # the last fix at or before the start (else the first), carried to it by its velocity
        j = max(int(np.searchsorted(log.gnss_t, t0 + 1e-9)) - 1, 0)
        v = log.gnss_v[j] if log.gnss_v is not None else np.zeros(3)
        v = np.where(np.isfinite(v), v, 0.0)
        p = log.gnss_p[j] + v * (t0 - log.gnss_t[j] + log.gnss_delay_s) - R @ lever
        return p, v, np.sqrt(np.maximum(log.gnss_var[j], 1e-4)), "the first fix"
    ref = log.reference or log.autopilot
    if ref is not None:
        (pm, p0, pp), _ = ref.at(np.array([t0 - 0.05, t0, t0 + 0.05]))
        if np.all(np.isfinite([pm, p0, pp])):
            return p0, (pp - pm) / 0.1, np.full(3, 0.1), f"the {ref.label}"
    return np.zeros(3), np.zeros(3), np.full(3, 1.0), "the origin (no fix, no reference)"
