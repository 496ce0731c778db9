"""What a replay measured: every rule against the reference (or, without one, against the
autopilot's own estimate, labelled so), per tick of the replay grid inside the track's span.

Per rule: horizontal position error RMS / max and vertical RMS (m); the horizontal RMS over
the ticks within 1 s of a fix (``pos_h_rms_with_fixes_m``: a long GNSS loss left out);
velocity RMS (m/s; the track's velocity, else the central difference of its positions over
±0.05 s); roll, pitch, tilt (the angle between the two body z axes) and yaw RMS (°); the
mean NIS of the fused position and velocity fixes (3 each for a consistent filter); the fixes
the gate rejected (verdict 1 or 2) or the latch held (3) with their times; with a GNSS gap
the horizontal error at its start and at its last tick (the drift).
"""

from __future__ import annotations

import math

import numpy as np

from numkit import X, Y, Z
from numkit.geometry import quats_to_rots, rots_to_euler

from .data import DEG, EVENT, XOUT, Track
from .runner import ReplayResult

__all__ = ["score_replay"]


def _rms(a: np.ndarray) -> float | None:
    a = a[np.isfinite(a)]
    return round(float(np.sqrt(np.mean(a * a))), 4) if a.size else None


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _track_v(track: Track, t: np.ndarray) -> np.ndarray:
    if track.v is not None:
        return np.stack([np.interp(t, track.t, track.v[:, j], left=np.nan, right=np.nan)
                         for j in range(3)], axis=1)
    pm, _ = track.at(t - 0.05)
    pp, _ = track.at(t + 0.05)
    return (pp - pm) / 0.1


def _events(ev: np.ndarray) -> dict:
    verdict = ev[:, EVENT.VERDICT]
    fused, rej = verdict == 0, verdict >= 1
    nisp = ev[fused, EVENT.NIS_POS]
    nisv = ev[:, EVENT.NIS_VEL]
    return {"fixes": int(ev.shape[0]),
            "nis_pos_mean": round(float(np.nanmean(nisp)), 3) if np.isfinite(nisp).any() else None,
            "nis_vel_mean": round(float(np.nanmean(nisv)), 3) if np.isfinite(nisv).any() else None,
            "gate_rejected": int(np.sum((verdict == 1) | (verdict == 2))),
            "gate_resets": int(np.sum(verdict == 2)),
            "gate_latched": int(np.sum(verdict == 3)),
            "rejected_t_s": [round(float(x), 2) for x in ev[rej, EVENT.T]]}


def score_replay(res: ReplayResult) -> dict:
    """The summary's ``estimators`` block and what it was scored against (module docstring)."""
    log = res.log
    track = log.reference or log.autopilot
    against = None if track is None else ("reference" if log.reference is not None
                                          else "autopilot")
    out: dict = {"against": against, "against_label": None if track is None else track.label,
                 "estimators": {}}
    if track is not None:
        p_ref, R_ref = track.at(res.t)
        v_ref = _track_v(track, res.t)
        e_ref = rots_to_euler(R_ref) if R_ref is not None else None
    for i, rule in enumerate(res.rules):
        x = res.x[:, i]
        s = _events(res.fix_events[rule])
        if track is not None:
            s.update(_errors(res, x, p_ref, v_ref, R_ref, e_ref))
        out["estimators"][rule] = s
    return out


def _errors(res: ReplayResult, x, p_ref, v_ref, R_ref, e_ref) -> dict:
    dp = x[:, XOUT.POS:XOUT.POS_END] - p_ref
    he = np.hypot(dp[:, X], dp[:, Y])
    s: dict = {"pos_h_rms_m": _rms(he),
               "pos_h_max_m": round(float(np.nanmax(he)), 4) if np.isfinite(he).any() else None,
               "pos_v_rms_m": _rms(dp[:, Z]),
               "vel_rms_mps": _rms(np.linalg.norm(x[:, XOUT.VEL:XOUT.VEL_END] - v_ref, axis=1)),
               "ticks_scored": int(np.isfinite(he).sum())}
    if res.fix_t.size:   # the ticks within 1 s of a fix handed to the INS (GNSS available)
        j = np.clip(np.searchsorted(res.fix_t, res.t), 1, res.fix_t.size - 1)
        near = np.minimum(np.abs(res.t - res.fix_t[j - 1]), np.abs(res.t - res.fix_t[j])) <= 1.0
        s["pos_h_rms_with_fixes_m"] = _rms(he[near])
    if R_ref is not None and np.isfinite(R_ref).any():
        R = quats_to_rots(x[:, XOUT.QUAT:XOUT.QUAT_END])
        e = rots_to_euler(R)
        d = _wrap(e - e_ref) / DEG
        cz = np.clip(np.einsum("ni,ni->n", R[:, :, Z], R_ref[:, :, Z]), -1.0, 1.0)
        s.update({"roll_rms_deg": _rms(d[:, X]), "pitch_rms_deg": _rms(d[:, Y]),
                  "tilt_rms_deg": _rms(np.arccos(cz) / DEG), "yaw_rms_deg": _rms(d[:, Z])})
    if res.gap is not None:
        g0, g1 = res.gap
        k0 = int(np.searchsorted(res.t, g0))
        k1 = max(int(np.searchsorted(res.t, g1)) - 1, k0)
        s["gap_start_err_m"] = round(float(he[k0]), 4) if np.isfinite(he[k0]) else None
        s["gap_drift_m"] = round(float(he[k1]), 4) if np.isfinite(he[k1]) else None
    return s
