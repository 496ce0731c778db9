"""The INS's consistency machinery: the scores' truth, the NEES arithmetic, the innovation gate
and the covariance step's sparse form.

* The bias states' truth is the IMU's *walked* bias: a twin :class:`ImuSensor` built from the
  same seed, block after block (:meth:`ImuSensor.walk_block`), reproduces the sensor's bias
  sample by sample.
* NEES of a linear-Gaussian case: errors drawn from N(0, P) give a mean NEES inside the 95 %
  band of χ²(n·N)/N, the whole 15 and each 3-state block on its marginal covariance; for
  correlated errors the band of the effective number covers the mean at its nominal rate.
* The gate (``INSConfig.gate_sigma``, common to the four rules): a planted 0.3 m RTK-fixed bias
  is rejected, clean fixes are accepted at the rate a consistent filter's innovations give.
* The step latch behind it (``INSConfig.gate_latch_s``): a 0.15 m step the gate alone
  re-admits is held for its whole 35 s, a lone outlier does not release it, its hold limit
  resets the position to the receiver; a PCA rule does not fuse its window's held fixes
  after the step ends, nor a rejected outlier through its window.
* ``cov_step`` (F's 45 non-zeros written out) equals the dense F P Fᵀ + Q to rounding.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2, norm

from ag_uav.config import ImuConfig
from ag_uav.navigation.ins_kernels import quad_inv, quad_inv_at
from ag_uav.vehicle.imu import ImuSensor
from estimators.ins import RULES, INSConfig, cov_step
from tests.test_ins import figure8, run


@pytest.fixture(scope="module")
def truth():
    return figure8(60.0)


def test_walk_block_is_the_sensors_bias_sample_by_sample():
    cfg = ImuConfig(accel_bias_rw=0.01, gyro_bias_rw=0.05)   # a walk that shows
    ss = np.random.SeedSequence(7)
    imu = ImuSensor(cfg, 100.0, ss, block=64)
    twin = ImuSensor(cfg, 100.0, ss, block=64)
    truth = np.concatenate([twin.walk_block().copy() for _ in range(3)])
    got = []
    for _ in range(3 * 64):
        imu.measure([0.0, 0.0, 9.81], [0.0, 0.0, 0.0])
        got.append(imu.bias)
    got = np.array(got)
    assert np.array_equal(got, truth)
    assert np.abs(got[-1] - got[0]).max() > 1e-4   # it did walk


def test_nees_of_a_linear_gaussian_case_is_chi2():
    """e ~ N(0, P), P a random correlated 15×15: mean NEES within the 95 % band of the mean
    of N χ²(15) draws; each block's NEES on its marginal covariance within that of χ²(3)."""
    rng = np.random.default_rng(3)
    A = rng.normal(size=(15, 15)) * np.r_[[0.1] * 3, [0.05] * 3, [0.01] * 3, [0.02] * 3,
                                          [1e-3] * 3]
    P = A @ A.T + np.diag(np.full(15, 1e-8))
    Lc = np.linalg.cholesky(P)
    N = 4000
    L, y, Pb, eb = np.empty((15, 15)), np.empty(15), np.empty((3, 3)), np.empty(3)
    whole, blocks = np.empty(N), np.empty((N, 5))
    for i in range(N):
        e = Lc @ rng.standard_normal(15)
        whole[i] = quad_inv(P, e, 15, L, y)
        for b in range(5):
            blocks[i, b] = quad_inv_at(P, e, 3 * b, 3, L, y, Pb, eb)
    lo, hi = chi2.ppf([0.025, 0.975], 15 * N) / N
    assert lo <= whole.mean() <= hi
    lo3, hi3 = chi2.ppf([0.025, 0.975], 3 * N) / N
    assert np.all((blocks.mean(axis=0) >= lo3) & (blocks.mean(axis=0) <= hi3))
    # the conditional (whole-matrix) block would not be the marginal: it over-counts
    e = Lc @ rng.standard_normal(15)
    assert quad_inv_at(P, e, 6, 3, L, y, Pb, eb) != pytest.approx(
        float(e[6:9] @ np.linalg.inv(P)[6:9, 6:9] @ e[6:9]))


def test_nees_band_of_correlated_fixes_covers_its_mean():
    """Successive fixes' NEES are correlated: the 95 % band of the mean of N χ²(15) values
    covers the mean of an AR(1)-correlated series (ρ = 0.9 per error component) about half the
    time, the band for the effective number (:func:`effective_n`) about 95 % of the time."""
    from scipy.signal import lfilter

    from ag_uav.navigation.ins_feedback import _chi2_band, effective_n

    rng = np.random.default_rng(1)
    rho, N, R = 0.9, 2000, 300
    cov = naive = 0
    for _ in range(R):
        e = lfilter([math.sqrt(1 - rho**2)], [1, -rho], rng.normal(size=(15, N)), axis=1)
        nees = (e**2).sum(axis=0)
        lo, hi = _chi2_band(15, effective_n(nees))
        cov += lo <= nees.mean() <= hi
        lo, hi = _chi2_band(15, N)
        naive += lo <= nees.mean() <= hi
    assert 0.90 <= cov / R <= 0.99 and naive / R < 0.6


def test_gate_rejects_a_planted_false_fix(truth):
    """+0.3 m east for 20 s reported as RTK fixed (σ 8 mm): the gate rejects it (≥ 95 % of
    the episode's fixes, every rule), and the KF's error through it stays a fraction of it;
    without the gate the KF follows it."""
    ff = (20.0, 40.0, (0.3, 0.0, 0.0))
    r = run(truth, 4, RULES, INSConfig(), false_fix=ff, seed=61, t_end=45.0)
    rej = r["ins"].counters["gate_rejected_pos"]
    assert np.all(rej >= 0.95 * 200), rej
    off = run(truth, 4, ("kf",), INSConfig(gate_sigma=math.inf), false_fix=ff, seed=61,
              t_end=45.0)
    e_on = np.linalg.norm(r["err_out"][2000:4000, 0::4, :2], axis=2).max()
    e_off = np.linalg.norm(off["err_out"][2000:4000, :, :2], axis=2).max()
    print(f"peak horizontal error through the false fix: gate {e_on:.3f} m, none {e_off:.3f}")
    assert e_off > 0.25 and e_on < e_off / 3


def test_gate_accepts_clean_fixes_at_the_nominal_rate(truth):
    """Clean fixes: at γ = 5 (the step latch on, the default) no position fix of 4 × 600 is
    rejected (a consistent filter rejects 3·2·Φ(−5) ≈ 1.7e-6 of them); at γ = 2 the gate alone
    (no latch: a 2 σ rejection of the coloured noise would open it) rejects the nominal
    1 − (1 − 2Φ(−2))³ ≈ 0.13 within sampling and the filter's slight conservatism."""
    r5 = run(truth, 4, ("kf",), INSConfig(gate_sigma=5.0), seed=71)
    n = r5["ins"].counters["gnss_fused"] + r5["ins"].counters["gate_rejected_pos"]
    assert np.all(r5["ins"].counters["gate_rejected_pos"] == 0) and np.all(n >= 590)
    r2 = run(truth, 4, ("kf",), INSConfig(gate_sigma=2.0, gate_latch_s=0.0), seed=71)
    c = r2["ins"].counters
    frac = c["gate_rejected_pos"].sum() / (c["gate_rejected_pos"] + c["gnss_fused"]).sum()
    nominal = 1 - (1 - 2 * norm.sf(2.0)) ** 3
    print(f"γ = 2: rejected {frac:.3f} of the fixes, nominal {nominal:.3f}")
    assert 0.6 * nominal < frac < 1.3 * nominal


STEP = (0.15, 0.0, 0.0)   # a false fix 10 σ_S east, reported fixed (σ 8 mm), 15-50 s


def _peak(r, a, b):
    """Per row, the largest horizontal output error over ticks a:b."""
    return np.linalg.norm(r["err_out"][a:b, :, :2], axis=2).max(axis=0)


def test_step_latch_holds_a_false_fix_the_gate_alone_readmits(truth):
    """35 s of a 0.15 m step: the gate alone re-admits it once the position variance, fed by
    the velocities only, has grown to it, and the filter follows it (error ≈ the step); the
    latch holds every fix of the episode (one more after it: the CUSUM's two fixes of
    evidence), fuses them relative to the step so the error stays at the fixes' own level,
    and releases once, after the step ends."""
    ff = (15.0, 50.0, STEP)
    on = run(truth, 4, ("kf",), INSConfig(), false_fix=ff, seed=81)
    off = run(truth, 4, ("kf",), INSConfig(gate_latch_s=0.0), false_fix=ff, seed=81)
    c, c0 = on["ins"].counters, off["ins"].counters
    print(f"held {c['gate_rejected_pos']}, relative {c['gnss_fused_relative']}; gate alone "
          f"rejected {c0['gate_rejected_pos']}; peak {_peak(on, 1500, 5000).round(3)} m, "
          f"gate alone {_peak(off, 1500, 5000).round(3)} m")
    assert np.all((c["gate_rejected_pos"] >= 350) & (c["gate_rejected_pos"] <= 353))
    assert np.all(c["gnss_fused_relative"] >= 340) and np.all(c["gate_latch_releases"] == 1)
    assert np.all(c0["gate_rejected_pos"] < 0.7 * 350)
    assert np.all(_peak(on, 1500, 5000) < 0.04) and np.all(_peak(off, 1500, 5000) > 0.12)
    assert np.all(_peak(on, 5200, 6000) < 0.03)   # released: on the true fixes again


def test_step_latch_is_not_released_by_a_lone_outlier(truth):
    """Two single fixes inside the step that land where the receiver would be without it: each
    fix's evidence is clipped to γ²/2, so neither releases the latch (one release, at the
    end); the error stays as without them."""
    ffs = [(15.0, 50.0, STEP), (30.0, 30.1, (-0.15, 0.0, 0.0)), (35.0, 35.1, (-0.15, 0.0, 0.0))]
    r = run(truth, 4, ("kf",), INSConfig(), false_fix=ffs, seed=81)
    assert np.all(r["ins"].counters["gate_latch_releases"] == 1)
    assert np.all(_peak(r, 1500, 5000) < 0.04)


def test_pca_rules_do_not_fuse_the_held_fixes_after_the_latch_releases(truth):
    """A 0.31 m step (seed 3's first episode, 15-50 s): after it ends the PCA block's window
    (10 fixes) still holds the step's fixes, and its rank-2 reconstruction overshoots the
    step's end by centimetres on the far side; a PCA rule whose latch has released fuses the
    raw fix until its window no longer spans a held fix, so its error after the step stays
    at the KF's level (fusing the PCA'd fixes: 0.034-0.048 m for PCA-KF, 0.009-0.022 the
    KF's)."""
    r = run(truth, 4, ("kf", "pca-kf", "pca-mckf"), INSConfig(),
            false_fix=(15.0, 50.0, (-0.29, 0.11, 0.0)), seed=81)
    pk = _peak(r, 5000, 5400).reshape(4, 3)
    print(f"peak 50-54 s, kf / pca-kf / pca-mckf: {pk.round(3)}")
    assert np.all(r["ins"].counters["gate_latch_releases"] == 1)
    assert np.all(pk[:, 1:] < 0.03) and np.all(pk[:, 1:] < pk[:, :1] + 0.01)


def test_pca_rules_do_not_fuse_a_rejected_outlier_through_their_window(truth):
    """One fix 0.3 m off at 30 s: the gate rejects it for every row, and a PCA rule fuses the
    raw fix while its window holds it, so its error stays at the KF's level (fusing the PCA'd
    fixes, whose reconstruction rings by centimetres for the window's 1 s after the outlier:
    0.02-0.05 m, and up to 9 fixes rejected as the filter left the truth)."""
    r = run(truth, 4, ("kf", "pca-kf", "pca-mckf"), INSConfig(),
            false_fix=(30.0, 30.1, (0.3, 0.0, 0.0)), seed=81, t_end=40.0)
    pk = _peak(r, 3000, 3300).reshape(4, 3)
    print(f"peak 30-33 s, kf / pca-kf / pca-mckf: {pk.round(3)}")
    assert np.all(r["ins"].counters["gate_rejected_pos"] == 1)
    assert np.all(pk[:, 1:] < 0.02) and np.all(pk[:, 1:] < pk[:, :1] + 0.005)


def test_step_latch_believes_the_receiver_after_its_hold_limit(truth):
    """gate_latch_s = 10: held for 10 s, the position resets to the receiver, which the filter
    then follows."""
    r = run(truth, 4, ("kf",), INSConfig(gate_latch_s=10.0), false_fix=(15.0, 50.0, STEP),
            seed=81)
    assert np.all(r["ins"].counters["gate_resets"] >= 1)
    assert np.all(_peak(r, 1500, 2450) < 0.04)
    assert np.all(np.linalg.norm(r["err_out"][2700:5000, :, :2], axis=2).min(axis=0) > 0.1)


def test_sparse_covariance_step_equals_the_dense_one():
    rng = np.random.default_rng(5)
    cfg = INSConfig()
    prm = cfg.prm()
    for _ in range(20):
        A = rng.normal(size=(15, 15))
        P = A @ A.T
        x = np.zeros(16)
        x[0:6] = rng.normal(size=6)
        q = rng.normal(size=4)
        x[6:10] = q / np.linalg.norm(q)
        x[10:16] = rng.normal(size=6) * 0.01
        u = np.r_[rng.normal(size=3) + (0, 0, 9.81), rng.normal(size=3) * 0.5]
        R = np.empty((3, 3))
        from estimators.ins import quat_to_rot
        quat_to_rot(x[6:10], R)
        F, Q = _dense_F_Q(x, u, R, cfg)
        want = F @ P @ F.T + Q
        got = P.copy()
        cov_step(got, x, u, prm, R.copy(), np.empty((9, 15)), np.empty((5, 3, 3)),
                 np.empty(16))
        assert np.allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())


def _dense_F_Q(x, u, R, cfg):
    """F and Q of the module docstring as dense 15×15 matrices (Solà eqs 269-270)."""
    from scipy.spatial.transform import Rotation

    dt = cfg.dt
    a = u[:3] - x[10:13]
    w = u[3:] - x[13:16]
    sk = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    F = np.eye(15)
    F[0:3, 3:6] = np.eye(3) * dt
    F[3:6, 6:9] = -R @ sk * dt
    F[3:6, 9:12] = -R * dt
    F[6:9, 6:9] = Rotation.from_rotvec(w * dt).as_matrix().T
    F[6:9, 12:15] = -np.eye(3) * dt
    Q = np.zeros((15, 15))
    qd = [(cfg.accel_sigma * dt) ** 2, (cfg.gyro_sigma * dt) ** 2, cfg.accel_bias_rw**2 * dt,
          cfg.gyro_bias_rw**2 * dt]
    for b in range(4):
        Q[3 + 3 * b:6 + 3 * b, 3 + 3 * b:6 + 3 * b] = np.eye(3) * qd[b]
    return F, Q


def test_colour_factor_is_the_variance_of_the_mean():
    """n f(n, ρ) = n Var(mean of n AR(1) samples) / σ², from the Toeplitz covariance ρ^|i−j|;
    1 at n = 1, (1+ρ)/(1−ρ) as n → ∞."""
    from ag_uav.navigation.receiver import colour_factor

    for rho in (0.0, 0.5, math.exp(-0.1 / 30.0)):
        for n in (1, 7, 40):
            i = np.arange(n)
            C = rho ** np.abs(i[:, None] - i[None, :])
            assert colour_factor(rho, n) == pytest.approx(C.sum() / n, rel=1e-12)
    rho = 0.9
    assert colour_factor(rho, 20000) == pytest.approx((1 + rho) / (1 - rho), rel=1e-3)


def test_fix_variance_splits_the_receivers_variance():
    """White + Gauss–Markov parts at n = 1 add up to the receiver's own variance per fix type;
    the consider split puts the rtk-m350 fixed mode's 60 % coloured share in the GM part."""
    from ag_uav.config import load_config
    from ag_uav.navigation.receiver import fix_variance, make_gps

    gps = make_gps(load_config(None, {}), np.random.SeedSequence(0))
    for m in gps.fix_types:
        w, g = fix_variance(gps, m, 1)
        assert np.allclose(w + g, gps.mode_variance(m), rtol=1e-12)
    w, g = fix_variance(gps, None, 1)
    assert np.allclose(g / (w + g), 0.6)
