"""The drone navigates on the INS: ag_uav.navigation.ins_feedback."""

from __future__ import annotations

import numpy as np
import pytest

from ag_uav.config import ConfigError, config_from_dict
from ag_uav.engine import missions as M
from ag_uav.engine.missions import simulate, simulate_many
from ag_uav.navigation.ins_feedback import BatchInsFeedback, InsFeedback
from ag_uav.vehicle.gps import ReceiverReport


def _cfg(**kw) -> object:
    d: dict = {"sim": {"max_time_s": 8.0}, "log": {"enabled": False, "render": False}}
    for k, v in kw.items():
        sec, key = k.split("__")
        d.setdefault(sec, {})[key] = v
    return config_from_dict(d)


def test_default_is_ins_and_flies_on_its_attitude():
    cfg = _cfg()
    assert cfg.estimator.nav == "ins" and cfg.gps.latency_s == pytest.approx(0.11)
    s = simulate(cfg).summary
    assert s["nav"] == "ins" and not s["crashed"]
    est = s["estimators"]
    assert list(est) == ["pca-mckf", "kf", "mckf", "pca-kf"] and est["pca-mckf"]["flown"]
    for e in est.values():
        assert e["estimate_rmse_m"] < 0.1 and e["velocity_rmse_mps"] < 0.2
        assert e["tilt_error_rms_deg"] < 1.0 and e["nees15_mean"] > 0
    for k in ("tilt_error_rms_deg", "tilt_error_max_deg", "yaw_error_rms_deg"):
        assert s[k] == est["pca-mckf"][k]
    assert s["gps_latency_s"] == pytest.approx(0.11)
    assert s["ins_counters"]["late"] == [0, 0, 0, 0]


class _Blind(BatchInsFeedback):
    """The bank with every truth array it is handed (position, velocity, attitude, body rate)
    replaced by NaN from tick ``K`` on: only the sensors read them, so the fixes and the radar
    drop out and the INS must coast on the IMU alone."""

    K = 400

    def update(self, k, t, p, v, imu, act):
        if k >= self.K:
            p, v = np.full_like(p, np.nan), np.full_like(v, np.nan)
            self.R_true = np.full((self.NV, 9), np.nan)
            self.w_true = np.full((self.NV, 3), np.nan)
        return super().update(k, t, p, v, imu, act)


def test_nothing_in_the_control_path_reads_the_truth(monkeypatch):
    """Structural: after take-off (t = 4 s) the truth handed to the feedback is NaN; the
    vehicle still flies (on the IMU alone: no fix, no radar) to the end of the 8 s and its
    fed-back state stays finite."""
    monkeypatch.setattr(InsFeedback, "batch",
                        classmethod(lambda cls, fbs, n_max: _Blind(fbs, n_max)))
    cfg = _cfg(gps__receiver="ideal")
    res = simulate(cfg)
    s = res.summary
    assert not s["crashed"], s.get("crash_reason")
    assert np.all(np.isfinite(res.p_fb))
    # 10 Hz fixes until 4 s, plus those delivered in the next 110 ms (they report the state
    # 110 ms back, still true): none after
    assert 30 <= s["ins_counters"]["gnss_fused"][0] <= 42
    drift = np.linalg.norm(res.p_fb[-1, :2] - res.p_true[-1, :2])
    assert 0.0 < drift < 2.0


def test_alone_or_batched_bit_identical():
    c0, c1 = _cfg(), _cfg()
    c1.seed = 7
    alone = simulate(c0)
    both = simulate_many([c1, c0])
    assert np.array_equal(alone.p_fb, both[1].p_fb)
    assert alone.summary["estimators"] == {
        k: {**v, "update_us": alone.summary["estimators"][k]["update_us"]}
        for k, v in both[1].summary["estimators"].items()}


def test_gnss_rate_above_control_rate_refused():
    with pytest.raises(ConfigError, match="exceeds sim.control_hz"):
        _cfg(sim__control_hz=10.0, gps__preset="rtk")
    with pytest.raises(ConfigError, match="exceeds sim.control_hz"):
        _cfg(sim__control_hz=50.0, gps__rate_hz=100.0)


def test_ins_refuses_rules_it_has_not():
    cfg = _cfg(estimator__shadow=["kf-bias"])
    with pytest.raises(ConfigError, match="not an INS GNSS update rule"):
        M.prepare_run(cfg, None, None, None)


def test_receiver_report_false_fixes_lag_and_calibration():
    """False fixes start only in RTK fixed, at the configured rate, last ~mean_s, carry a
    bias in the configured range; the reported type lags by report_lag_s; each reported-type
    episode draws a new accuracy scale."""
    rate = 10.0
    rr = ReceiverReport(rate, 3, per_hour=360.0, mean_s=5.0, bias_m=(0.1, 0.4),
                        calibration_sigma=0.3, report_lag_s=1.0)
    n = 36000  # one hour of fixes
    types = ["rtk-fixed"] * n
    for a in range(1000, n, 3000):          # 10 s of float every 300 s
        types[a:a + 100] = ["rtk-float"] * 100
    bias = np.zeros((n, 3))
    rep, scale = [], []
    for k, ty in enumerate(types):
        b, r_, s_ = rr.step(ty)
        bias[k] = b
        rep.append(r_)
        scale.append(s_)
    on = np.linalg.norm(bias, axis=1)
    assert np.all(on[on > 0] >= 0.1 - 1e-12) and np.all(on <= 0.4 + 1e-12)
    assert not np.any(on[np.array(types) == "rtk-float"] > 0)
    # a renewal: fixed time 3240 s / (1/λ + mean_s = 10 s + 5 s) ≈ 216 episodes
    assert 180 < rr.n_false < 255
    assert rep[:10] == ["rtk-fixed"] * 10
    assert rep[1000 + 10] == "rtk-float" and rep[1000 + 9] == "rtk-fixed"   # 1 s late
    sc = np.array(scale)
    u = np.unique(sc)
    assert len(u) == 2 * 12 + 1 - 1 or len(u) >= 20    # one draw per reported-type episode
    assert 0.15 < np.std(np.log(u)) < 0.45              # calibration_sigma = 0.3


def test_honest_receiver_off_in_rtk_preset():
    """The consistency check's preset has no fix types: no report, no false fixes."""
    from ag_uav.seeds import seed_sequences

    fb = InsFeedback(_cfg(gps__preset="rtk"), seed_sequences(0))
    assert fb.report is None
    fb2 = InsFeedback(_cfg(), seed_sequences(0))
    assert fb2.report is not None


def test_true_flown_with_ins_shadows_flies_on_the_truth():
    """estimator.name = "true": the INS rules are scored as shadows, the controller flies on
    the true position (and the sensing stage's attitude, not an identity)."""
    res = simulate(_cfg(estimator__name="true", sim__max_time_s=4.0))
    s = res.summary
    assert not s["crashed"] and list(s["estimators"]) == ["kf", "mckf", "pca-kf"]
    # (on the skids and in the lift-off latch the horizontal part is the reference's)
    assert np.array_equal(res.p_fb[:, 2], res.p_true[:, 2])
    assert np.array_equal(res.p_fb[-100:], res.p_true[-100:])
    assert s["estimators"]["kf"]["estimate_rmse_m"] < 0.1


@pytest.mark.parametrize("aid_m, gate", [(5.0, 0.0), (0.0, 0.0), (0.0, 5.0)])
def test_range_aid_keeps_a_wrong_gnss_height_out_at_take_off(monkeypatch, aid_m, gate):
    """Range aid (PX4's conditional range aid): below 5 m of radar range and 1 m/s of
    horizontal speed the fixes' height is not fused. Fixes 1 m too high from t = 1 s to the
    end of the take-off hover (4.5 s; the receiver still reports RTK), the KF flown, no gate:
    with range aid the vehicle holds its 3 m on the radar; without it, it descends towards the
    GNSS height (0.68 m low at 4 s). The innovation gate alone also keeps that jump out (a 1 m
    step against a centimetre-level innovation σ): every such fix's height is rejected."""
    fix = InsFeedback.fix

    def high(self, t, p_ant, v_ant, yaw):
        row = fix(self, t, p_ant, v_ant, yaw)
        if row is not None and 1.0 <= t < 4.5:
            row[3] += 1.0
        return row

    monkeypatch.setattr(InsFeedback, "fix", high)
    res = simulate(_cfg(gps__receiver="ideal", sim__max_time_s=4.5, estimator__name="kf",
                        estimator__ins_range_aid_m=aid_m, estimator__ins_gate_sigma=gate))
    s = res.summary
    k = int(np.searchsorted(res.t, 4.0))
    dz = res.p_true[k, 2] - res.p_ref[k, 2]
    if aid_m:
        assert abs(dz) < 0.15 and s["range_aid_fixes"] >= 35
    elif gate:
        assert abs(dz) < 0.15 and s["ins_counters"]["gate_rejected_pos"][0] >= 30
    else:
        assert dz < -0.5 and "range_aid_fixes" not in s


def test_the_log_shows_when_the_radar_is_the_height_source(tmp_path):
    """``/drone/state``'s ``ctrl.nav.range_aid``: 1 through the take-off hover (fixes' height
    not fused), 0 once the vehicle is on its way (faster than 1 m/s, from ~5 s)."""
    from ag_uav.analysis import viewing
    from ag_uav.record.runlog import RunLog

    cfg = _cfg(sim__max_time_s=8.0)
    with RunLog(tmp_path / "r.mcap", channels="full", rates={"camera": 0.0},
                layout=False) as log:
        s = simulate(cfg, log=log).summary
    st = viewing.read_run(tmp_path / "r.mcap", images=False).series["/drone/state"]
    aid, t = st["ctrl.nav.range_aid"], st.t
    assert set(np.unique(aid)) == {0.0, 1.0}
    assert np.all(aid[(t > 0.5) & (t < 4.0)] == 1.0) and np.all(aid[t > 6.5] == 0.0)
    assert s["range_aid_fixes"] >= 35


def test_quad_inv_matches_numpy_and_refuses_an_indefinite_matrix():
    """The NEES's eᵀ P⁻¹ e (allocation-free Cholesky) against numpy's solve, on the whole matrix
    and on its leading block; NaN where the block is not positive definite."""
    from ag_uav.navigation.ins_kernels import quad_inv

    rng = np.random.default_rng(3)
    L, y = np.empty((15, 15)), np.empty(15)
    for _ in range(20):
        A = rng.standard_normal((15, 15))
        P = A @ A.T + 1e-3 * np.eye(15)
        e = rng.standard_normal(15)
        for n in (15, 3):
            ref = float(e[:n] @ np.linalg.solve(P[:n, :n], e[:n]))
            assert quad_inv(P, e, n, L, y) == pytest.approx(ref, rel=1e-9)
    P = np.eye(15)
    P[4, 4] = -1.0
    assert np.isnan(quad_inv(P, np.ones(15), 15, L, y))
    assert quad_inv(P, np.ones(15), 3, L, y) == pytest.approx(3.0)


class _Indefinite(BatchInsFeedback):
    """The kf shadow's covariance (row 1 of each vehicle) made indefinite for ticks K..K+40."""

    K = 600   # in the mission (after take-off)

    def update(self, k, t, p, v, imu, act):
        if self.K <= k <= self.K + 40:
            self.bank.P[1::self.nr, 11, 11] = -1.0   # accelerometer z bias: no fix resets it
        return super().update(k, t, p, v, imu, act)


def test_a_covariance_that_is_not_positive_definite_is_counted_not_hidden(monkeypatch):
    """Such a fix has no NEES: it leaves the mean, and the count reaches the scores and the
    report's table (it used to drop out silently)."""
    from rich.console import Console

    from ag_uav.analysis.report import estimator_table

    monkeypatch.setattr(InsFeedback, "batch",
                        classmethod(lambda cls, fbs, n_max: _Indefinite(fbs, n_max)))
    est = simulate(_cfg()).summary["estimators"]
    assert est["kf"]["nees15_not_pd"] >= 2          # 10 Hz fixes over 0.4 s, some in the mission
    assert all(est[n]["nees15_not_pd"] == 0 for n in ("pca-mckf", "mckf", "pca-kf"))
    assert est["kf"]["nees15_mean"] is not None       # the other fixes still score
    console = Console(width=200, record=True)
    console.print(estimator_table(est))
    assert "not positive definite: kf " in " ".join(console.export_text().split())


def test_consider_never_fuses_a_fix_as_exact():
    """A receiver whose error is all Gauss–Markov leaves "consider" no white part: the fused
    R keeps R_WHITE_FLOOR (R = 0 made the position block singular and the gate divide by zero),
    the rest is considered; the default receiver's R is its floored whole less the Gauss–Markov
    part, above that floor."""
    from ag_uav.navigation.receiver import R_FLOOR, R_WHITE_FLOOR
    from ag_uav.seeds import seed_sequences

    gm = _cfg(gps__preset="perfect", gps__overrides={"components": [
        {"type": "gauss-markov", "name": "bias", "sigma": 3.0, "tau_s": 1e7}]})
    R, cv = InsFeedback(gm, seed_sequences(0)).var_nominal
    assert np.all(R == R_WHITE_FLOOR) and np.allclose(cv[:2], 9.0)
    R, cv = InsFeedback(_cfg(gps__preset="rtk"), seed_sequences(0)).var_nominal
    assert np.all(R > R_WHITE_FLOOR)
    assert np.allclose(R + cv, np.maximum(R + cv, R_FLOOR))
