"""Error-state INS/GNSS filter (estimators.ins) on a synthetic figure-8 with known IMU errors.

The truth is a smooth figure-8 (30 m × 15 m lobes, 40 s period, ~5 m/s, altitude 5 ± 1 m,
yaw along the track) flown by a multirotor whose thrust is along body z: the attitude is the
thrust direction a − g_w plus the yaw; the specific force is f = Rᵀ(a − g_w), the body rate
ω = Log(R_kᵀ R_k+1)/Δt.  Position and velocity are integrated with the filter's own discrete
kinematics (acceleration and rate held over each 10 ms step: the filter runs with
``coning=False``, whose step is exactly that), so the only errors are the sensors'
(white noise, constant biases drawn per seed, GNSS/heading/radar noise, latency): this tests
the filter, not its discretisation.  ``python tests/test_ins.py`` prints the figures quoted in
docs/ins.md.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest
from scipy.stats import chi2

from estimators.ins import RULES, BatchINS, INSConfig, quat_log_err

DT = 0.01
G = 9.81
DEG = math.pi / 180.0
SIG_P = np.array([0.008, 0.008, 0.016])   # RTK fixed per axis (rtk-m350 preset level)
SIG_V = 0.03                              # GNSS velocity per axis (judgement)
SIG_YAW = 0.5 * DEG                       # dual-antenna heading (INSConfig default)
SIG_RADAR = 0.05
BA0, BG0 = 5e-3 * G, 0.05 * DEG           # turn-on bias 1σ (the simulator's [imu] defaults)
P0_STD = np.r_[[0.05] * 3, [0.05] * 3, [1.0 * DEG] * 3, [BA0] * 3, [BG0] * 3]


def _rot(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _quat(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


def _qexp(phi: np.ndarray) -> np.ndarray:
    th = np.linalg.norm(phi)
    if th < 1e-12:
        return np.r_[1.0, 0.5 * phi]
    return np.r_[math.cos(th / 2), math.sin(th / 2) * phi / th]


def _qmul(a, b):
    return np.array([
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]])


def _log(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(R).as_rotvec()


def figure8(T: float = 60.0, dt: float = DT) -> dict[str, np.ndarray]:
    """Truth p, v, q (K+1 ticks) and the noiseless IMU samples u[t] (f, ω) that take tick t−1
    to t (u[0] unused)."""
    K = int(round(T / dt))
    t = np.arange(K + 1) * dt
    Om = 2 * math.pi / 40.0
    A, B = 30.0, 15.0
    vel = np.stack([A * Om * np.cos(Om * t), 2 * B * Om * np.cos(2 * Om * t),
                    0.5 * Om * np.cos(0.5 * Om * t)], 1)
    acc = np.stack([-A * Om**2 * np.sin(Om * t), -4 * B * Om**2 * np.sin(2 * Om * t),
                    -0.25 * Om**2 * np.sin(0.5 * Om * t)], 1)
    yaw = np.unwrap(np.arctan2(vel[:, 1], vel[:, 0]))
    Rs = np.empty((K + 1, 3, 3))
    for k in range(K + 1):
        zb = acc[k] + [0, 0, G]
        zb /= np.linalg.norm(zb)
        xc = np.array([math.cos(yaw[k]), math.sin(yaw[k]), 0.0])
        yb = np.cross(zb, xc)
        yb /= np.linalg.norm(yb)
        Rs[k] = np.stack([np.cross(yb, zb), yb, zb], 1)
    p = np.empty((K + 1, 3))
    v = np.empty((K + 1, 3))
    q = np.empty((K + 1, 4))
    u = np.zeros((K + 1, 6))
    p[0], v[0], q[0] = [0.0, 0.0, 5.0], vel[0], _quat(Rs[0])
    for k in range(1, K + 1):
        Rp = _rot(q[k - 1])
        om = _log(Rp.T @ Rs[k]) / dt
        u[k, :3] = Rp.T @ (acc[k - 1] + [0, 0, G])
        u[k, 3:] = om
        a = Rp @ u[k, :3] - [0, 0, G]
        p[k] = p[k - 1] + v[k - 1] * dt + 0.5 * a * dt * dt
        v[k] = v[k - 1] + a * dt
        qn = _qmul(q[k - 1], _qexp(om * dt))
        q[k] = qn / np.linalg.norm(qn)
    return {"t": t, "p": p, "v": v, "q": q, "u": u, "R": np.array([_rot(x) for x in q])}


def run(truth, n_seeds: int = 1, rules=("kf",), cfg: INSConfig | None = None, latency=0.11,
        gnss_hz=10.0, radar_hz=20.0, lever=None, outage=None, false_fix=None,
        seed: int = 0, with_vel=True, with_yaw=True, t_end=None):
    """Fly the INS bank on ``n_seeds`` independent sensor draws of the truth (one vehicle per
    seed in one BatchINS).  Returns output errors (now) and core errors / NEES (fusion
    horizon) per tick, per row."""
    # the truth holds f and ω over each step: the filter's held-rate step is its exact model
    cfg = dataclasses.replace(cfg or INSConfig(), coning=False)
    K = len(truth["t"]) - 1 if t_end is None else int(round(t_end / DT))
    NV, nr = n_seeds, len(rules)
    rng = np.random.default_rng(seed)
    ba = rng.normal(0, BA0, (NV, 3))
    bg = rng.normal(0, BG0, (NV, 3))
    ins = BatchINS(NV, cfg, rules)
    e0 = rng.normal(0, 1, (NV, 15)) * P0_STD
    q0 = np.array([_qmul(truth["q"][0], _qexp(-e0[i, 6:9])) for i in range(NV)])
    ins.reset(truth["p"][0] - e0[:, 0:3], truth["v"][0] - e0[:, 3:6], q0, -e0[:, 9:12] + ba,
              -e0[:, 12:15] + bg, P0_STD)
    # x_est = x_true − e0 (biases: b_est = b_true − e), so the error x_true − x_est = e0
    lever = np.asarray(cfg.lever_arm if lever is None else lever, float)
    Lt = int(round(latency / DT))
    g_every, r_every = int(round(100 / gnss_hz)), int(round(100 / radar_hz))
    err_out = np.zeros((K + 1, NV * nr, 3))
    err_core = np.zeros((K + 1, NV * nr, 15))
    nees = np.full((K + 1, NV * nr), np.nan)
    tilt = np.zeros((K + 1, NV * nr))
    sig_imu = np.r_[[cfg.accel_sigma] * 3, [cfg.gyro_sigma] * 3]
    rb = np.asarray(cfg.heading_baseline, float)
    dq = np.empty(3)
    for k in range(1, K + 1):
        imu = truth["u"][k] + np.c_[ba, bg] + rng.normal(0, 1, (NV, 6)) * sig_imu
        gin = None
        if k % g_every == 0 and k - Lt >= 0 and not (outage and outage[0] <= k * DT < outage[1]):
            j = k - Lt
            Rj = truth["R"][j]
            pa = truth["p"][j] + Rj @ lever + rng.normal(0, 1, (NV, 3)) * SIG_P
            for f0, f1, fb in ([false_fix] if isinstance(false_fix, tuple) else false_fix or []):
                if f0 <= j * DT < f1:
                    pa = pa + np.asarray(fb)
            om = truth["u"][min(j + 1, K), 3:]
            va = truth["v"][j] + Rj @ np.cross(om, lever) + rng.normal(0, SIG_V, (NV, 3))
            b = Rj @ rb
            yw = math.atan2(b[1], b[0]) - math.atan2(rb[1], rb[0]) + rng.normal(0, SIG_YAW, NV)
            gin = np.full((NV, 15), np.nan)
            gin[:, 0] = Lt * DT
            gin[:, 1:4] = pa
            if with_vel:
                gin[:, 4:7] = va
            if with_yaw:
                gin[:, 7] = yw
            gin[:, 8:11] = SIG_P**2
            gin[:, 11:14] = SIG_V**2
            gin[:, 14] = SIG_YAW**2
        rin = None
        if k % r_every == 0:
            Rk = truth["R"][k]
            h = truth["p"][k][2] + (Rk @ np.array(cfg.radar_offset))[2] - cfg.ground_z
            rho = h / Rk[2, 2] + rng.normal(0, SIG_RADAR, NV)
            rho[rng.random(NV) < 0.05] = np.nan  # dropouts
            rin = np.c_[rho, np.full(NV, SIG_RADAR**2), np.zeros(NV)]
        ins.step(imu, gin, rin)
        rows = np.arange(NV * nr)
        v_of = rows // nr
        err_out[k] = truth["p"][k] - ins.x_out[:, 0:3]
        c = int(ins.core_tick[0])
        xc = ins.x_core
        e = np.empty((NV * nr, 15))
        e[:, 0:3] = truth["p"][c] - xc[:, 0:3]
        e[:, 3:6] = truth["v"][c] - xc[:, 3:6]
        for i in rows:
            quat_log_err(xc[i, 6:10], truth["q"][c], dq)
            e[i, 6:9] = dq
        e[:, 9:12] = ba[v_of] - xc[:, 10:13]
        e[:, 12:15] = bg[v_of] - xc[:, 13:16]
        err_core[k] = e
        nees[k] = np.einsum("ni,nij,nj->n", e, np.linalg.inv(ins.P), e)
        tilt[k] = np.hypot(e[:, 6], e[:, 7])
    return {"ins": ins, "err_out": err_out, "err_core": err_core, "nees": nees, "tilt": tilt,
            "ba": ba, "bg": bg}


@pytest.fixture(scope="module")
def truth():
    return figure8(60.0)


def _rms(a, axis=None):
    return float(np.sqrt(np.mean(np.square(a), axis=axis)))


# ------------------------------------------------------------------------ unit checks
def test_jacobians_match_finite_differences():
    """H of every measurement model against central differences of h(x ⊕ δx)."""
    from estimators.ins import h_gnss_pos, h_gnss_vel, h_heading, h_radar, inject_reset
    cfg = INSConfig(lever_arm=(0.2, -0.1, 0.3), radar_offset=(0.05, 0.02, -0.1),
                    heading_baseline=(0.3, 1.0, 0.05))
    prm = cfg.prm()
    rng = np.random.default_rng(1)
    x = np.r_[1.0, 2.0, 6.0, 0.5, -0.3, 0.1, _qexp(np.array([0.2, -0.15, 0.7])),
              rng.normal(0, 0.05, 3), rng.normal(0, 0.01, 3)]
    w = np.array([0.3, -0.2, 0.5])
    models = [(lambda x_, z, nu, H: h_gnss_pos(x_, prm, z, nu, H), 3),
              (lambda x_, z, nu, H: h_gnss_vel(x_, w, prm, z, nu, H), 3),
              (lambda x_, z, nu, H: h_heading(x_, prm, z, nu, H), 1),
              (lambda x_, z, nu, H: h_radar(x_, prm, z, nu, H), 1)]
    for h, m in models:
        z = np.zeros(m)
        H = np.zeros((m, 15))
        nu0 = np.zeros(m)
        h(x, z, nu0, H)
        Hn = np.zeros((m, 15))
        for j in range(15):
            col = []
            for s in (1e-6, -1e-6):
                xp = x.copy()
                dx = np.zeros(15)
                dx[j] = s
                inject_reset(xp, np.eye(15), dx)
                nu = np.zeros(m)
                h(xp, z, nu, np.zeros((m, 15)))
                col.append(-nu)  # ν = z − h
            Hn[:, j] = (col[0] - col[1]) / 2e-6
        np.testing.assert_allclose(H, Hn, atol=2e-6)


def test_mckf_with_infinite_sigma_is_the_kf(truth):
    """σ = ∞: every correntropy weight is 1, the MCKF update is the KF's."""
    a = run(truth, 1, ("kf", "mckf"), INSConfig(sigma=np.inf), t_end=20.0)
    np.testing.assert_allclose(a["err_out"][:, 0], a["err_out"][:, 1], atol=1e-9)


def test_batch_rows_are_bit_identical_to_single(truth):
    """A vehicle's rows in a batch of three equal the same vehicle run alone (the seeds give
    vehicle 0 the same draws only if alone: so compare row 0 of a 1-vehicle bank of four
    rules with the 4-rule bank's rows of vehicle 0 run twice)."""
    a = run(truth, 3, RULES, t_end=10.0, seed=5)
    b = run(truth, 3, RULES, t_end=10.0, seed=5)
    assert np.array_equal(a["err_out"], b["err_out"])
    ins = BatchINS(1, INSConfig(), RULES)
    single = BatchINS(1, INSConfig(), ("pca-mckf",))
    rng = np.random.default_rng(3)
    for f in (ins, single):
        f.reset(truth["p"][0], truth["v"][0], truth["q"][0], P0=P0_STD)
    for k in range(1, 400):
        imu = (truth["u"][k] + rng.normal(0, 0.05, 6))[None]
        g = None
        if k % 10 == 0:
            g = BatchINS.gnss_row(truth["p"][k - 11] + rng.normal(0, 0.01, 3),
                                  truth["v"][k - 11], age_s=0.11)[None]
        ins.step(imu, g)
        single.step(imu, g)
    assert np.array_equal(ins.x_out[3], single.x_out[0])
    assert np.array_equal(ins.P[3], single.P[0])


# ------------------------------------------------------------------------ behaviour
def test_converges_attitude_and_biases(truth):
    """RTK-class fixes with the true 110 ms latency, delayed fusion: after 30 s the position
    error is centimetric, tilt < 0.5°, biases estimated."""
    r = run(truth, 4, ("kf",), seed=11)
    sl = slice(3000, None)
    pos = _rms(r["err_out"][sl])
    tilt = float(np.max(r["tilt"][sl])) / DEG
    ba_err = np.abs(r["err_core"][-1, :, 9:12])
    bg_err = np.abs(r["err_core"][-1, :, 12:15])
    print(f"pos rms {pos:.4f} m, tilt max {tilt:.3f} deg, |ba err| max {ba_err.max():.4f}, "
          f"|bg err| max {bg_err.max() / DEG:.4f} deg/s; true |ba| {np.abs(r['ba']).max():.3f}")
    assert pos < 0.03
    assert tilt < 0.5
    assert ba_err.max() < 0.3 * BA0 + 0.01
    assert bg_err.max() < 0.2 * BG0


def test_nees_20_seeds(truth):
    """Mean 15-state NEES over 20 seeds vs the two-sided 95 % band of χ²(15·20)/20, time
    averaged after 10 s."""
    r = run(truth, 20, ("kf",), seed=21, t_end=60.0)
    m = np.mean(r["nees"][1000:], axis=1)
    lo, hi = chi2.ppf([0.025, 0.975], 15 * 20) / 20
    inside = float(np.mean((m >= lo) & (m <= hi)))
    print(f"mean NEES {m.mean():.2f} (band {lo:.2f}-{hi:.2f}), in band {inside:.0%} of ticks")
    assert lo * 0.8 < m.mean() < hi * 1.25


def test_delayed_fusion_beats_fusion_at_receipt(truth):
    """110 ms latency at ~5 m/s: fusing at receipt pulls the estimate ~0.5 m behind."""
    d = run(truth, 2, ("kf",), INSConfig(delayed=True), seed=31)
    a = run(truth, 2, ("kf",), INSConfig(delayed=False), seed=31)
    ed, ea = _rms(d["err_out"][1000:]), _rms(a["err_out"][1000:])
    print(f"pos rms delayed {ed:.4f} m, at receipt {ea:.4f} m")
    assert ed < 0.25 * ea


def test_gnss_outage_drift(truth):
    """10 s without GNSS (and heading) from t = 30 s; the radar stays."""
    r = run(truth, 4, ("kf",), outage=(30.0, 40.0), seed=41)
    e = r["err_out"]
    before = np.linalg.norm(e[2990, :, :2], axis=1)
    end = np.linalg.norm(e[3999, :, :2], axis=1)  # the last tick before the first new fix
    vz = np.abs(e[3999, :, 2])
    print(f"horizontal error at outage start {before.mean():.3f} m, after 10 s "
          f"{end.mean():.3f} m (max {end.max():.3f}); vertical {vz.mean():.3f} m")
    assert 3 * before.mean() < end.mean() and end.max() < 1.5
    assert vz.max() < 0.2


def test_lever_arm_matters(truth):
    """A 0.36 m lever arm ignored by the filter biases the position as the vehicle turns."""
    arm = (0.2, 0.0, 0.3)
    ok = run(truth, 2, ("kf",), INSConfig(lever_arm=arm), lever=arm, seed=51)
    no = run(truth, 2, ("kf",), INSConfig(lever_arm=(0.0, 0.0, 0.0)), lever=arm, seed=51)
    eo, en = _rms(ok["err_out"][1000:]), _rms(no["err_out"][1000:])
    print(f"pos rms with lever arm {eo:.4f} m, ignored {en:.4f} m")
    assert en > 3 * eo


def test_false_fix_kf_vs_mckf(truth):
    """RTK false fix: +0.3 m east, +0.2 m north for 20 s at 20-40 s, reported as fixed; no
    innovation gate (the update rules alone; the gate: tests/test_ins_consistency.py)."""
    r = run(truth, 4, RULES, INSConfig(gate_sigma=math.inf),
            false_fix=(20.0, 40.0, (0.3, 0.2, 0.0)), seed=61)
    e = r["err_out"]
    ep = np.linalg.norm(e[2000:4000, :, :2], axis=2)  # during the episode
    out = {}
    for j, rule in enumerate(RULES):
        out[rule] = (_rms(ep[:, j::4]), float(np.max(ep[:, j::4])))
    print("false fix, horizontal rms / max during the episode: " + ", ".join(
        f"{k} {a:.3f}/{b:.3f} m" for k, (a, b) in out.items()))
    assert out["kf"][0] > 0.15  # the KF follows the false fix
    assert all(math.isfinite(a) for a, _ in out.values())


def false_fix_sigma_sweep(truth, sigmas=(1.0, 2.0, 4.0, np.inf), recoveries=("kf", None)):
    """Horizontal RMS during the false-fix episode for the MCKF rule per (σ, recovery)."""
    res = {}
    for rec in recoveries:
        for s in sigmas:
            r = run(truth, 4, ("mckf",), INSConfig(sigma=s, recovery=rec, gate_sigma=math.inf),
                    false_fix=(20.0, 40.0, (0.3, 0.2, 0.0)), seed=61)
            ep = np.linalg.norm(r["err_out"][2000:4000, :, :2], axis=2)
            after = np.linalg.norm(r["err_out"][4000:5000, :, :2], axis=2)
            res[(s, rec)] = (_rms(ep), _rms(after))
    return res


def bench(n: int = 2000) -> dict[str, float]:
    """µs per tick: one row (single), a bank of four (one vehicle), and per vehicle at N=64
    (bank of four each); predict-only ticks and GNSS ticks separately."""
    truth = figure8(25.0)
    out = {}
    for name, NV, rules in (("single kf", 1, ("kf",)), ("single pca-mckf", 1, ("pca-mckf",)),
                            ("bank of 4, 1 vehicle", 1, RULES),
                            ("bank of 4, 64 vehicles", 64, RULES)):
        ins = BatchINS(NV, INSConfig(), rules)
        ins.reset(truth["p"][0], truth["v"][0], truth["q"][0], P0=P0_STD)
        rng = np.random.default_rng(0)
        imu = np.repeat(truth["u"][1:n + 1, None, :], NV, 1) + rng.normal(0, 0.01, (n, NV, 6))
        g = np.stack([np.repeat(BatchINS.gnss_row(truth["p"][k] + 0.01, truth["v"][k],
                                                  0.0, age_s=0.11)[None], NV, 0)
                      for k in range(n)])
        ins.step(imu[0], g[0])
        tp = tg = 0.0
        npred = ng = 0
        for k in range(1, n):
            t0 = time.perf_counter()
            if k % 10 == 0:
                ins.step(imu[k], g[k])
                tg += time.perf_counter() - t0
                ng += 1
            else:
                ins.step(imu[k])
                tp += time.perf_counter() - t0
                npred += 1
        per = NV
        out[name] = (1e6 * tp / npred / per, 1e6 * tg / ng / per,
                     1e6 * (tp + tg) / (npred + ng) / per)
    return out


if __name__ == "__main__":  # pragma: no cover
    tr = figure8(60.0)
    for fn in (test_converges_attitude_and_biases, test_nees_20_seeds,
               test_delayed_fusion_beats_fusion_at_receipt, test_gnss_outage_drift,
               test_lever_arm_matters, test_false_fix_kf_vs_mckf):
        print(fn.__name__)
        try:
            fn(tr)
        except AssertionError as exc:
            print("  ASSERTION FAILED", exc)
    for (s, rec), (a, b) in false_fix_sigma_sweep(tr).items():
        print(f"mckf sigma {s:>4} recovery {rec!s:5}: false-fix rms {a:.3f} m, next 10 s "
              f"{b:.3f} m")
    for k, (p, g, a) in bench().items():
        print(f"{k:26s} predict tick {p:6.2f} µs, GNSS tick {g:6.2f} µs, mean {a:6.2f} µs "
              "(per vehicle)")


def test_the_bank_scratch_holds_the_mckf_work():
    """The INS bank's flat scratch reserves exactly the MCKF update's work (15 states, 3 rows)
    after the KF offset: the KF and the MCKF updates share that region."""
    from estimators.ins import layout
    from estimators.mckf import mckf_work_size

    assert layout.SCRATCH.size - layout.W.KF == mckf_work_size(15, 3)
