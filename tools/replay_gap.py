"""What a replayed GNSS gap's drift is made of, per recorded flight with a reference track.

A development tool of the repository (not part of the installed package); the figures of
``docs/replay.md`` ("The 10 s gap: what the 20× is made of"):

    python tools/replay_gap.py .../Horizontal/path_{1..13} --gnss-from-reference m8p-rtk-static

Per flight, the replay with a ``--gap`` s GNSS gap in the middle (seed 0, the default INS
settings) and:

* ``drift``: the flown rule's horizontal error at the gap's last tick; ``sigma``: its own
  horizontal 1σ there, √(P_ee + P_nn) (and, over the flights, the mean of (drift / sigma)²:
  1 for a filter whose covariance covers its drift);
* ``acc``, ``gyro``, ``rss``: the horizontal error free inertial navigation gets from the log's
  white noise alone after T s (σ_a, σ_g per sample at Δt, as the replay reads them):
  √2 σ_a √Δt T^{3/2}/√3 and √2 g σ_g √Δt T^{5/2}/√20 (a white acceleration error integrated
  twice; a white rate error integrated once into tilt, then twice through g), and their RSS;
* ``open_ref``, ``open_ref_b``, ``open_gyro``: the median horizontal error after T s of
  integrating the log's specific force from the reference's state (position, velocity as its
  central difference) over windows every 2 s, with the reference's attitude; the same with the
  flight's mean body-frame accelerometer residual against the reference removed; and with the
  attitude from the log's gyro instead;
* ``ref_tilt``: the reference attitude's own interpolation error: every other sample
  interpolated from its neighbours, the tilt RMS against the samples left out (°).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from ag_uav.navigation.replay import ReplayOptions, read_log, run_replay, score_replay
from ag_uav.navigation.replay.data import Track
from ag_uav.navigation.replay.runner import white_sigma
from estimators.ins.config import G_STD

UP = np.array([0.0, 0.0, 1.0])


def _exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: exp([w]×)."""
    th = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + math.sin(th) / th * K + (1.0 - math.cos(th)) / th**2 * K @ K


def _vel(ref: Track, t: np.ndarray) -> np.ndarray:
    pm, _ = ref.at(t - 0.05)
    pp, _ = ref.at(t + 0.05)
    return (pp - pm) / 0.1


def open_loop(t, f, ref: Track, t0: float, T: float, gyro: bool = False,
              ba: np.ndarray | None = None) -> float:
    """Horizontal error after T s of integrating the specific force ``f`` (n, 6: f, ω body)
    from the reference's state at ``t0``; attitude the reference's, or the gyro's from the
    reference's at ``t0`` (``gyro``); ``ba`` a body-frame bias taken out."""
    k = np.flatnonzero((t >= t0) & (t < t0 + T))
    dt = float(t[1] - t[0])
    p0, R0 = ref.at(t[k[:1]])
    p, R, v = p0[0].copy(), R0[0].copy(), _vel(ref, t[k[:1]])[0].copy()
    _, Rr = ref.at(t[k])
    b = np.zeros(3) if ba is None else ba
    for i, kk in enumerate(k):
        a = (R if gyro else Rr[i]) @ (f[kk, :3] - b) - G_STD * UP
        p += v * dt + 0.5 * a * dt * dt
        v += a * dt
        if gyro:
            R = R @ _exp(f[kk, 3:] * dt)
    pe, _ = ref.at(t[k[-1:]] + dt)
    return float(np.hypot(*(p - pe[0])[:2]))


def white_drift(sa: float, sg: float, dt: float, T: float) -> tuple[float, float]:
    """Horizontal drift after T s from white accelerometer / gyro noise (module docstring)."""
    acc = math.sqrt(2.0) * sa * math.sqrt(dt) * T**1.5 / math.sqrt(3.0)
    gyr = math.sqrt(2.0) * G_STD * sg * math.sqrt(dt) * T**2.5 / math.sqrt(20.0)
    return acc, gyr


def ref_tilt_interp(ref: Track) -> float:
    """Tilt RMS (°) of every other reference sample interpolated from its neighbours."""
    half = Track(ref.t[::2], ref.p[::2], ref.R[::2])
    tm = ref.t[1::2][:-1]
    _, Rh = half.at(tm)
    cz = np.clip(np.einsum("ni,ni->n", Rh[:, :, 2], ref.R[1::2][:-1, :, 2]), -1.0, 1.0)
    return math.degrees(math.sqrt(float(np.nanmean(np.arccos(cz) ** 2))))


def body_residual(t, f, ref: Track) -> np.ndarray:
    """The flight's mean body-frame accelerometer residual against the reference's specific
    force Rᵀ(a + g e_z), a from the central difference of its velocity over ±0.1 s."""
    inside = (t >= ref.t[0] + 0.2) & (t <= ref.t[-1] - 0.2)
    ti = t[inside]
    _, Rr = ref.at(ti)
    a = (_vel(ref, ti + 0.1) - _vel(ref, ti - 0.1)) / 0.2
    fr = np.einsum("nji,nj->ni", Rr, a + G_STD * UP)
    r = f[inside, :3] - fr
    return np.nanmean(r[np.all(np.isfinite(r), axis=1)], axis=0)


def analyse(path: str, preset: str, T: float) -> dict[str, float]:
    """One flight's row (module docstring)."""
    res = run_replay(read_log(path), ReplayOptions(gnss_from_reference=preset, seed=0,
                                                   gnss_gap=(-1.0, T)))
    flown = res.rules[0]
    e = score_replay(res)["estimators"][flown]
    k1 = int(np.searchsorted(res.t, res.gap[1])) - 1
    log, ref = res.log, res.log.reference
    t, f = log.imu_t, log.imu
    dt = float(res.t[1] - res.t[0])
    acc, gyr = white_drift(white_sigma(f[:, :3]), white_sigma(f[:, 3:]), dt, T)
    starts = np.arange(ref.t[0] + 0.5, ref.t[-1] - T - 0.2, 2.0)
    ba = body_residual(t, f, ref)
    return {"drift": e["gap_drift_m"], "sigma": math.sqrt(res.pdiag[k1, 0] + res.pdiag[k1, 1]),
            "acc": acc, "gyro": gyr, "rss": math.hypot(acc, gyr),
            "open_ref": float(np.median([open_loop(t, f, ref, s, T) for s in starts])),
            "open_ref_b": float(np.median([open_loop(t, f, ref, s, T, ba=ba) for s in starts])),
            "open_gyro": float(np.median([open_loop(t, f, ref, s, T, gyro=True)
                                          for s in starts])),
            "ref_tilt": ref_tilt_interp(ref)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("paths", nargs="+", help="recorded flights with a reference track")
    p.add_argument("--gnss-from-reference", default="m8p-rtk-static", metavar="PRESET")
    p.add_argument("--gap", type=float, default=10.0, help="gap length T (s, default 10)")
    a = p.parse_args()
    rows = []
    cols = ("drift", "sigma", "acc", "gyro", "rss", "open_ref", "open_ref_b", "open_gyro",
            "ref_tilt")
    print("flight  " + "  ".join(f"{c:>10}" for c in cols))
    for path in a.paths:
        r = analyse(path, a.gnss_from_reference, a.gap)
        rows.append([r[c] for c in cols])
        print(f"{path.rstrip('/').split('/')[-1]:<7} " + "  ".join(f"{r[c]:10.3f}" for c in cols))
    arr = np.array(rows)
    print("median  " + "  ".join(f"{x:10.3f}" for x in np.median(arr, axis=0)))
    # E[d²] = P_ee + P_nn for a consistent filter: the mean of (drift / sigma)² reads 1
    print(f"mean (drift / sigma)²: {np.mean((arr[:, 0] / arr[:, 1]) ** 2):.3f} (1 = consistent)")


if __name__ == "__main__":
    main()
