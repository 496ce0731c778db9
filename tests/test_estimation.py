"""The estimator bank in the loop: the drone flies on its estimate; shadows see the same fixes."""

import numpy as np
import pytest

import ag_uav
from ag_uav.navigation.estimation import EstimatorFeedback
from ag_uav.seeds import seed_sequences


def _cfg(**over):
    # the position-filter bank of the ideal-attitude stand-in (the INS: tests/test_ins_feedback)
    base = {"sim.max_time_s": 40.0, "gps.preset": "standalone", "gps.multipath_prob": 0.05,
            "estimator.nav": "ideal-attitude"}
    base.update(over)
    cfg = ag_uav.load_config(None, base)
    cfg.log.enabled = False
    return cfg


@pytest.fixture(scope="module")
def flown():
    cfg = _cfg(**{"estimator.name": "pca-mckf", "estimator.shadow": ["kf", "mckf", "pca-kf"]})
    ss = seed_sequences(cfg.seed)
    fb = EstimatorFeedback(cfg, ss["gps"], ss["altimeter"], ss["imu"])
    res = ag_uav.simulate(cfg, feedback=fb)
    return cfg, fb, res


def test_flies_on_the_estimate_not_the_truth(flown):
    cfg, fb, res = flown
    s = res.summary
    assert not s["crashed"]
    assert set(s["estimators"]) == {"pca-mckf", "kf", "mckf", "pca-kf"}
    # the fed-back position is the primary filter's estimate: it differs from the truth by the
    # estimate error, which is what the summary reports
    d = res.p_fb[:, :2] - res.p_true[:, :2]
    assert np.sqrt(np.mean(np.sum(d[1:] ** 2, axis=1))) > 0.05
    assert s["estimate_rmse_m"] == s["estimators"]["pca-mckf"]["estimate_rmse_m"]
    for sc in s["estimators"].values():
        assert np.isfinite(sc["estimate_rmse_m"]) and sc["estimate_rmse_m"] < 5.0
        assert sc["update_us"] > 0
        assert sc["updates"] == fb.n_upd["kf"]


def test_fix_rate_and_radar_height(flown):
    cfg, fb, res = flown
    rate = fb.gps.rate_hz
    assert len(fb.fixes) == pytest.approx(cfg.sim.max_time_s * rate, abs=2)
    z_err = np.array([f[3] for f in fb.fixes]) - np.interp([f[0] for f in fb.fixes], res.t,
                                                            res.p_true[:, 2])
    # radar altimeter: cm-level height even though the standalone GPS vertical is metres off
    assert np.std(z_err) < 0.2


def test_same_seed_same_fixes_and_estimates():
    a = ag_uav.simulate(_cfg(**{"estimator.name": "kf", "sim.max_time_s": 10.0}))
    b = ag_uav.simulate(_cfg(**{"estimator.name": "kf", "sim.max_time_s": 10.0}))
    assert np.array_equal(a.p_fb, b.p_fb)
    c = ag_uav.simulate(_cfg(**{"estimator.name": "kf", "sim.max_time_s": 10.0, "seed": 1}))
    assert not np.array_equal(a.p_fb, c.p_fb)


def test_shadow_does_not_change_the_flight():
    a = ag_uav.simulate(_cfg(**{"estimator.name": "kf", "sim.max_time_s": 10.0}))
    b = ag_uav.simulate(_cfg(**{"estimator.name": "kf", "estimator.shadow": ["mckf"],
                                "sim.max_time_s": 10.0}))
    assert np.array_equal(a.p_true, b.p_true)


def test_gps_denied_switch_flies_on_landmark_bearings():
    cfg = _cfg(**{"estimator.source": "bearings", "sim.max_time_s": 20.0})
    s = ag_uav.simulate(cfg).summary
    assert s["gps_denied"] and s["gps_fixes"] == 0 and not s["crashed"]
    assert s["feedback"] == "mcc-ekf" and s["estimate_rmse_m"] < 2.0


@pytest.mark.parametrize("name", ["kf-bias", "kf-diff"])
def test_coloured_noise_filters_model_the_receivers_gauss_markov_part(name):
    """kf-bias and kf-diff in the loop take the receiver's Gauss–Markov τ (and σ per axis as
    kf-bias's bias σ_b), start from the first fix, and fly (they used to stop at the first fix
    with a traceback)."""
    from ag_uav.navigation.estimation import make_filter

    cfg = _cfg(**{"estimator.name": name, "gps.preset": "rtk-m350", "sim.max_time_s": 6.0,
                  "estimator.imu": name == "kf-bias"})
    comps = ({"type": "gauss-markov", "sigma": 0.5, "tau_s": 20.0, "axis_scale": [1, 1, 2]},
             {"type": "gaussian", "sigma": 0.3})
    f = make_filter(name, cfg, np.array([0.34, 0.34, 1.09]), comps)
    if name == "kf-bias":
        # the height is the radar's (white): no bias state there
        assert cfg.gps.altitude_source == "radar"
        assert np.allclose(f.sigma_b, [0.5, 0.5, 0.0]) and np.allclose(f.tau[:2], 20.0)
        assert np.allclose(np.diag(f.R), [0.09, 0.09, 1.09])
        f.x, f.P = np.arange(f.n, dtype=float), 2.0 * np.eye(f.n)   # (re)start, bias to prior
        assert np.array_equal(f.x, np.arange(f.n)) and not f.bias.any()
        assert np.allclose(np.diag(f.P_aug)[f.n:], f.sigma_b**2)
    res = ag_uav.simulate(cfg)
    assert np.isfinite(res.p_fb).all() and res.summary["estimate_rmse_m"] < 0.5


def test_coloured_noise_filter_needs_a_gauss_markov_part():
    from ag_uav.config import ConfigError
    from ag_uav.navigation.estimation import make_filter

    with pytest.raises(ConfigError, match="no gauss-markov component"):
        make_filter("kf-bias", _cfg(), np.ones(3), ({"type": "gaussian", "sigma": 1.0},))
    gm = ({"type": "gauss-markov", "sigma": 0.5, "tau_s": 20.0},)
    with pytest.raises(ConfigError, match="no control input"):   # it crashed the drone at 3 s
        make_filter("kf-diff", _cfg(**{"estimator.imu": True}), np.ones(3), gm)
