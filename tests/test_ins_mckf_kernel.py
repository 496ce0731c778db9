"""The INS's GNSS position update with the MCKF kernel options (``INSConfig.mckf_kernel``):
σ → ∞ is the KF, and the fixed / adaptive / multi-kernel updates equal the hand-written
reference MCKF of ``tests/oracles/mckf.py`` (vectorised numpy, independent of the row
functions) run on the 15-state error with the same injection and reset."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators import MCKF
from estimators.ins import INS, INSConfig, h_gnss_pos, inject_reset
from tests.oracles.mckf import OracleMCKF

DEG = math.pi / 180.0
VAR = np.array([1e-4, 1e-4, 4e-4])
P0 = np.r_[[0.05] * 3, [0.05] * 3, [1.0 * DEG] * 3, [0.05] * 3, [1e-3] * 3]
Q0 = np.array([math.cos(0.2), 0.0, 0.0, math.sin(0.2)])  # yawed 23°: a lever-arm term in H


def _fixes(n: int = 60) -> np.ndarray:
    """Antenna fixes around (1, 2, 5.3): noise 3× the reported σ (a persistent mismatch that
    widens the adaptive kernel), decimetre outliers every 7th fix (rejections, recoveries)."""
    rng = np.random.default_rng(11)
    z = np.array([1.0, 2.0, 5.3]) + 3.0 * np.sqrt(VAR) * rng.standard_normal((n, 3))
    z[::7] += np.array([0.3, -0.2, 0.1])
    return z


def _ins(kernel: str, sigma=2.0, rule: str = "mckf") -> INS:
    # the update laws alone: no innovation gate in front of them
    ins = INS(INSConfig(delayed=False, sigma=sigma, mckf_kernel=kernel, gate_sigma=math.inf),
              rule)
    ins.reset(np.array([1.0, 2.0, 5.0]), np.zeros(3), Q0, P0=P0)
    return ins


def test_infinite_sigma_is_the_kf_update():
    """σ = ∞: every weight is exactly 1 and the MCKF update is the KF's (to 1e-12)."""
    a, b = _ins("fixed", np.inf), _ins("fixed", rule="kf")
    for z in _fixes(30):
        a.update_gnss(z, var_pos=VAR)
        b.update_gnss(z, var_pos=VAR)
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.P, b.P, rtol=0, atol=1e-12)
    # the adaptive kernel scales ∞ to ∞: still the KF
    c = _ins("adaptive", np.inf)
    for z in _fixes(30):
        c.update_gnss(z, var_pos=VAR)
    np.testing.assert_allclose(c.x, b.x, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kernel", ["fixed", "adaptive", "multi"])
def test_kernel_matches_the_reference(kernel):
    """Fix by fix: the INS's x and P equal the reference MCKF's error-state update (F = I,
    Q = 0, x⁰ = 0, z = ν; ŝ and the rejection count carried over) followed by the library's
    injection and reset."""
    cfg = INSConfig(delayed=False, sigma=2.0, mckf_kernel=kernel)
    sig = cfg.kernel_widths()
    ins = _ins(kernel)
    prm = cfg.prm()
    x = ins.x_core.copy()
    P = np.diag(P0**2)
    ref = OracleMCKF(np.eye(15), np.zeros((3, 15)), np.zeros((15, 15)), np.diag(VAR),
                     np.zeros(15), P, sigma=sig, adaptive_sigma=kernel == "adaptive")
    widened = rejected = 0
    for z in _fixes():
        nu, H = np.empty(3), np.empty((3, 15))
        h_gnss_pos(x, prm, z, nu, H)
        ref.H, ref.x, ref.P = H, np.zeros(15), P
        ref.update(nu)
        P = np.array(ref.P)
        inject_reset(x, P, np.array(ref.x))
        ins.update_gnss(z, var_pos=VAR)
        np.testing.assert_allclose(ins.x_core, x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(ins.P, P, rtol=1e-7, atol=1e-15)
        widened += bool(ref.sigma_k[-1] > 2.0 * 1.05)
        rejected += ref.rejected
    assert rejected >= 5
    assert (widened > 10) == (kernel == "adaptive")
    if kernel == "multi":
        assert np.all(np.isinf(sig[:15])) and np.all(sig[15:] == 2.0)


def test_kernels_differ():
    """The three kernels are different updates on the same fixes (the option is wired)."""
    ends = []
    for kernel in ("fixed", "adaptive", "multi"):
        ins = _ins(kernel)
        for z in _fixes():
            ins.update_gnss(z, var_pos=VAR)
        ends.append(ins.x.copy())
    assert np.abs(ends[0] - ends[1]).max() > 1e-4
    assert np.abs(ends[0] - ends[2]).max() > 1e-6


def test_scalar_mckf_and_ins_share_the_adaptive_row():
    """MCKF(adaptive_sigma=True) runs the same row function: its ŝ follows the oracle's."""
    rng = np.random.default_rng(2)
    F, H = np.eye(2), np.eye(2)
    R = 0.01 * np.eye(2)
    f = MCKF(F, H, np.zeros((2, 2)), R, np.zeros(2), np.eye(2), adaptive_sigma=True)
    o = OracleMCKF(F, H, np.zeros((2, 2)), R, np.zeros(2), np.eye(2), adaptive_sigma=True)
    for _ in range(40):
        z = 0.5 * rng.standard_normal(2)
        f.update(z)
        o.update(z)
        assert f.scale2 == pytest.approx(o.scale2, rel=1e-12)
    np.testing.assert_allclose(f.sigma_k, o.sigma_k, rtol=1e-12)
    assert f.scale2 > 1.5


@pytest.mark.parametrize("kw,msg", [
    ({"mckf_kernel": "gaussian"}, "mckf_kernel must be one of fixed, adaptive, multi"),
    ({"mckf_kernel": "multi", "sigma": [2.0] * 18}, "takes a scalar sigma"),
    ({"mckf_kernel": "adaptive", "adapt_lambda": 1.0}, "adapt_lambda"),
    ({"sigma": 0.0}, "positive scalar"),
])
def test_bad_kernel_settings_are_refused(kw, msg):
    with pytest.raises(ValueError, match=msg):
        INS(INSConfig(**kw), "mckf")


def test_config_key_is_validated():
    from ag_uav.config import ConfigError, load_config
    from ag_uav.navigation.estimation import make_filter
    from ag_uav.navigation.ins_feedback import ins_config

    with pytest.raises(ConfigError, match="estimator.mckf_kernel"):
        load_config(None, {"estimator.mckf_kernel": "huber"})
    cfg = load_config(None, {"estimator.mckf_kernel": "adaptive"})
    assert ins_config(cfg).mckf_kernel == "adaptive"
    assert load_config(None, {}).estimator.mckf_kernel == "fixed"
    cfg = load_config(None, {"estimator.mckf_kernel": "multi",
                             "estimator.nav": "ideal-attitude"})
    with pytest.raises(ConfigError, match='only with estimator.nav = "ins"'):
        make_filter("mckf", cfg, np.ones(3))
