"""Where the INS's GNSS position R comes from (``estimator.ins_r_source``): the receiver's
reported accuracy by default, the error generator's own variances with ``"truth"``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ag_uav.config import ConfigError, config_from_dict
from ag_uav.navigation.ins_feedback import InsFeedback
from ag_uav.navigation.receiver import R_FLOOR, R_WHITE_FLOOR, fix_variance
from ag_uav.seeds import seed_sequences

_ZERO = np.zeros(3)


def _cfg(**kw) -> object:
    d: dict = {"sim": {"max_time_s": 8.0}, "log": {"enabled": False, "render": False}}
    for k, v in kw.items():
        sec, key = k.split("__")
        d.setdefault(sec, {})[key] = v
    return config_from_dict(d)


def _rows(fb: InsFeedback, reports: list[tuple[str, float]]) -> list[list[float]]:
    """One fix per report (reported type, accuracy scale), the receiver's report replaced by
    these: the rows the filters get."""
    it = iter(reports)
    fb.report.step = lambda _t: (_ZERO, *next(it))
    fb.report.in_false = False
    dt = 1.0 / fb.gps.rate_hz
    return [fb.fix(k * dt, (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 0.0) for k in range(len(reports))]


def test_default_r_is_the_reported_accuracy_and_grows_with_it():
    """A fix reported with twice the accuracy figure gets 4× the R (above the 1 cm floor); a
    reported DGPS fix a larger R than an RTK-fixed one; R = (1 − share) × the reported
    variance (hAcc² / vAcc²)."""
    cfg = _cfg()
    assert cfg.estimator.ins_r_source == "reported"
    fb = InsFeedback(cfg, seed_sequences(0))
    r1, r2, r3 = _rows(fb, [("rtk-fixed", 2.0), ("rtk-fixed", 4.0), ("dgps", 1.0)])
    R1, R2, R3 = (np.array(r[8:11]) for r in (r1, r2, r3))
    np.testing.assert_allclose(R2, 4.0 * R1, rtol=1e-12)
    assert np.all(R3 > 100.0 * R1)
    v = fb.gps.reported_variance("dgps")
    share = cfg.estimator.ins_gnss_gm_share
    h = 0.5 * (v[0] + v[1])
    np.testing.assert_allclose(R3, [(1 - share) * h, (1 - share) * h, (1 - share) * v[2]])
    np.testing.assert_allclose(fb.cvar, [share * h, share * h, share * v[2]])


def test_truth_switch_reads_the_generators_split():
    """``ins_r_source = "truth"``: R is the generator's white part (floored whole less the
    Gauss–Markov part) times the reported scale², as the INS had it before the switch."""
    fb = InsFeedback(_cfg(estimator__ins_r_source="truth"), seed_sequences(0))
    (r,) = _rows(fb, [("rtk-float", 1.5)])
    w, gm = fix_variance(fb.gps, "rtk-float", 1)
    expect = np.maximum(np.maximum(w + gm, R_FLOOR) - gm, R_WHITE_FLOOR) * 1.5 * 1.5
    np.testing.assert_allclose(r[8:11], expect, rtol=1e-12)
    np.testing.assert_allclose(fb.cvar, gm * 1.5**2, rtol=1e-12)


def test_an_all_gauss_markov_receiver_is_not_fused_as_exact_by_default():
    """m8p-standalone's error is all Gauss–Markov: from the generator ("truth") R is the 5 mm
    floor; from the report it is metres (the configured white share of its ~3.4 m hAcc)."""
    truth = InsFeedback(_cfg(gps__preset="m8p-standalone", estimator__ins_r_source="truth"),
                        seed_sequences(0))
    rep = InsFeedback(_cfg(gps__preset="m8p-standalone"), seed_sequences(0))
    assert truth.report is None and rep.report is None
    rt = truth.fix(0.0, (0.0, 0.0, 1.0), _ZERO, 0.0)
    rr = rep.fix(0.0, (0.0, 0.0, 1.0), _ZERO, 0.0)
    assert rt[8] == pytest.approx(R_WHITE_FLOOR)
    assert rr[8] > 1.0   # m²
    # the run's calibration error: the reported figure is not the generator's σ
    s2 = rr[8] / ((1 - 0.5) * rep.gps.spread_variance(None)[0])
    assert s2 != pytest.approx(1.0) and abs(math.log(s2)) < 2.0


def test_r_source_is_checked():
    with pytest.raises(ConfigError, match="ins_r_source"):
        _cfg(estimator__ins_r_source="generator")
