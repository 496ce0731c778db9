"""GPS-denied mission: bearings to field landmarks + radar altimeter + IMU-aided prediction."""

import math

import numpy as np
import pytest

import ag_uav
from ag_uav.engine.missions import simulate
from ag_uav.navigation.bearing import BearingFeedback, default_landmarks
from ag_uav.world.mission import build_field
from estimators.bearing import angle_residual


def _cfg(max_time: float = 40.0, seed: int = 0):
    # the bearing studies fly the default field at 6 m lanes (their bounds are in lane widths)
    cfg = ag_uav.load_config(None, {"sim.max_time_s": max_time, "seed": seed,
                                    "mission.swath_m": 6.0, "mission.headland_m": 6.0})
    cfg.log.enabled = False
    return cfg


@pytest.fixture(scope="module")
def flown():
    cfg = _cfg()
    fb = BearingFeedback.for_config(cfg, filter="mcc-ekf", shadow=("ekf", "ukf"))
    res = simulate(cfg, feedback=fb)
    return cfg, fb, res


def test_default_landmarks_surround_the_field():
    cfg = _cfg()
    x0, y0, x1, y1 = build_field(cfg).bounds
    lm = default_landmarks(cfg)
    assert lm.shape == (4, 2)
    np.testing.assert_allclose(lm.min(axis=0), [x0 - 10, y0 - 10])
    np.testing.assert_allclose(lm.max(axis=0), [x1 + 10, y1 + 10])


def test_measurement_is_wrapped_bearing_plus_mixture_noise():
    cfg = _cfg()
    lm = [[10.0, 0.0], [0.0, 10.0], [-10.0, 0.0], [0.0, -10.0]]
    fb = BearingFeedback(cfg, np.random.SeedSequence(1), np.random.SeedSequence(2),
                         landmarks=lm, noise_scale=1.0)
    z = np.array([fb.measure((0.0, 0.0, 3.0)) for _ in range(4000)])
    assert z.shape == (4000, 5)
    assert np.all(np.abs(z[:, :4]) <= math.pi)
    err = angle_residual(z[:, :4], np.array([0.0, math.pi / 2, math.pi, -math.pi / 2]))
    # the landmark at −x sits on the ±π cut: wrapped residuals are small, not ~2π
    assert np.max(np.abs(err)) < 2.0
    # mixture (1−ϑ)N(0, .01) + ϑN(0, .1): variance .019, excess kurtosis well above 0
    assert np.var(err) == pytest.approx(0.019, rel=0.12)
    k = np.mean(err**4) / np.var(err) ** 2 - 3.0
    assert k > 1.0
    assert fb.n_outliers == pytest.approx(0.1 * 4 * 4000, rel=0.12)
    assert np.std(z[:, 4] - 3.0) == pytest.approx(cfg.gps.radar_sigma_m, rel=0.1)
    # the filter's R defaults to the noise's total variance, the altimeter's σ² last
    np.testing.assert_allclose(np.diag(fb.R)[:4], 0.019)
    assert fb.R[4, 4] == pytest.approx(max(cfg.gps.radar_sigma_m**2, 1e-4))


def test_jacobian_matches_finite_differences():
    fb = BearingFeedback(_cfg(), np.random.SeedSequence(0))
    x = np.zeros(fb.n)
    x[fb.pos_idx] = [30.0, 40.0, 3.0]
    x[fb.vel_idx] = [1.0, -2.0, 0.1]
    if fb.n == 9:
        x[[2, 5, 8]] = [0.01, -0.02, 0.03]
    H = fb.H_jac(x)
    num = np.zeros_like(H)
    for j in range(fb.n):
        d = np.zeros(fb.n)
        d[j] = 1e-6
        num[:, j] = angle_residual(fb.h(x + d), fb.h(x - d)) / 2e-6
    np.testing.assert_allclose(H, num, atol=1e-7)
    np.testing.assert_allclose(fb.h(np.stack([x, x]))[1], fb.h(x))


def test_short_mission_flies_without_gps(flown):
    cfg, fb, res = flown
    s = res.summary
    assert not s["crashed"]
    assert s["gps_denied"] and s["gps_fixes"] == 0
    assert s["sim_time_s"] == pytest.approx(40.0, abs=0.02)
    assert set(s["estimators"]) == {"mcc-ekf", "ekf", "ukf"}
    assert s["estimate_rmse_m"] == s["estimators"]["mcc-ekf"]["estimate_rmse_m"]
    assert s["bearing_measurements"] == pytest.approx(40.0 * fb.rate_hz, abs=1)
    # the controller flew on the estimate, which is not the truth ...
    d = res.p_fb[1:, :2] - res.p_true[1:, :2]
    err = np.hypot(d[:, 0], d[:, 1])
    assert np.sqrt(np.mean(err**2)) > 0.05
    # ... but stays bounded (default noise ~0.8° RMS, beacons ≤ ~150 m away, P0 = 3 m)
    assert np.max(err) < 3.0
    for sc in s["estimators"].values():
        assert np.isfinite(sc["estimate_rmse_m"]) and sc["estimate_rmse_m"] < 1.5
    # and it followed the plan (the sweep started; tracking error of the order of the estimate)
    assert s["tracking_rmse_m"] < 2.0
    assert s["altitude_rmse_m"] < 0.5


def test_paper_noise_stays_within_a_swath_and_mcc_beats_ekf():
    # the paper's noise (0.1 rad nominal, 10 % outliers of 0.32 rad): metres of error, but bounded
    cfg = _cfg()
    fb = BearingFeedback.for_config(cfg, filter="mcc-ekf", noise_scale=1.0, shadow=("ekf",))
    res = simulate(cfg, feedback=fb)
    s = res.summary
    assert not s["crashed"]
    d = res.p_fb[1:, :2] - res.p_true[1:, :2]
    assert np.max(np.hypot(d[:, 0], d[:, 1])) < res.plan.swath
    sc = s["estimators"]
    assert sc["mcc-ekf"]["estimate_rmse_m"] < 3.0 and sc["ekf"]["estimate_rmse_m"] < 3.0
    # same bearings for both (shadow): the correntropy kernel discounts the outliers
    assert sc["mcc-ekf"]["estimate_rmse_m"] < sc["ekf"]["estimate_rmse_m"]
    assert s["bearing_outliers"] > 0


def test_same_seed_same_flight_other_seed_other_noise():
    runs = []
    for seed in (3, 3, 4):
        cfg = _cfg(15.0, seed)
        res = simulate(cfg, feedback=BearingFeedback.for_config(cfg, filter="ekf"))
        runs.append(res)
    np.testing.assert_array_equal(runs[0].p_fb, runs[1].p_fb)
    np.testing.assert_array_equal(runs[0].p_true, runs[1].p_true)
    assert runs[0].summary["estimate_rmse_m"] == runs[1].summary["estimate_rmse_m"]
    assert not np.array_equal(runs[0].p_fb, runs[2].p_fb)


def test_bad_arguments():
    cfg = _cfg()
    with pytest.raises(ValueError, match="filter"):
        BearingFeedback(cfg, None, filter="pf")
    with pytest.raises(ValueError, match="shadow"):
        BearingFeedback(cfg, None, shadow=("kf",))
    with pytest.raises(ValueError, match="landmarks"):
        BearingFeedback(cfg, None, landmarks=[[0.0, 0.0]])
