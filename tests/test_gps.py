"""Tests for ag_uav.vehicle.gps: noise components, outages, presets and the GpsSensor."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
import tomli_w
from scipy import stats

from ag_uav.vehicle.gps import (
    AR1,
    AlphaStable,
    Gaussian,
    GaussianMixture,
    GaussMarkov,
    GpsSensor,
    Laplace,
    MultipathSpikes,
    OutageProcess,
    StudentT,
    SymmetricWeibull,
    available_presets,
    gps_preset,
    make_component,
    validate_overrides,
)

N = 300_000


def _lag_corr(x: np.ndarray, lag: int) -> float:
    x = x - x.mean()
    return float(np.dot(x[:-lag], x[lag:]) / np.dot(x, x))


# ------------------------------------------------------------------ i.i.d. components


@pytest.mark.parametrize(
    "comp, dist",
    [
        (Gaussian(1.7, 1), stats.norm(scale=1.7)),
        (StudentT(1.3, 5.0, 2), stats.t(5.0, scale=1.3 * math.sqrt(3.0 / 5.0))),
        (StudentT(2.0, 3.0, 3), stats.t(3.0, scale=2.0 * math.sqrt(1.0 / 3.0))),
        (Laplace(0.8, 4), stats.laplace(scale=0.8 / math.sqrt(2.0))),
    ],
)
def test_iid_shape_matches_reference_distribution(comp, dist):
    x = comp.sample(50_000)
    assert stats.kstest(x, dist.cdf).pvalue > 1e-3


@pytest.mark.parametrize(
    "comp",
    [
        Gaussian(1.7, 1),
        StudentT(1.3, 5.0, 2),
        Laplace(0.8, 4),
        SymmetricWeibull(1.1, 0.8, 5),
        SymmetricWeibull(1.1, 2.0, 6),
        GaussianMixture(0.1, 0.3, 2.0, 7),
        MultipathSpikes(0.05, 3.0, 8),
        MultipathSpikes(0.05, 3.0, 9, amplitude_max=6.0),
    ],
)
def test_variance_matched(comp):
    x = comp.sample(N)
    assert x.var() == pytest.approx(comp.variance, rel=0.04)
    assert abs(x.mean()) < 0.01 * math.sqrt(comp.variance)


def test_weibull_magnitude_and_random_sign():
    k, sigma = 0.8, 1.5
    c = SymmetricWeibull(sigma, k, 3)
    x = c.sample(100_000)
    lam = sigma / math.sqrt(math.gamma(1 + 2 / k))
    assert c.lam == pytest.approx(lam)
    assert stats.kstest(np.abs(x), stats.weibull_min(k, scale=lam).cdf).pvalue > 1e-3
    assert (x > 0).mean() == pytest.approx(0.5, abs=0.01)


def test_mixture_outlier_rate_and_kurtosis():
    eps = 0.07
    x = GaussianMixture(eps, 0.0, 2.0, 11).sample(N)
    assert (x != 0).mean() == pytest.approx(eps, abs=0.003)
    m = GaussianMixture(eps, 0.5, 3.0, 12)
    y = m.sample(N)
    m4 = 3 * ((1 - eps) * 0.5**4 + eps * 3.0**4)
    assert np.mean(y**4) == pytest.approx(m4, rel=0.06)


def test_spike_rate_amplitude_and_sign():
    x = MultipathSpikes(0.03, 4.0, 13).sample(N)
    hit = x != 0
    assert hit.mean() == pytest.approx(0.03, abs=0.002)
    np.testing.assert_array_equal(np.abs(x[hit]), 4.0)
    assert (x[hit] > 0).mean() == pytest.approx(0.5, abs=0.03)


@pytest.mark.parametrize("alpha, beta", [(1.5, 0.0), (1.2, 0.5), (1.0, 0.3), (0.8, 0.0)])
def test_alpha_stable_matches_scipy_levy_stable(alpha, beta):
    scale = 0.7
    x = AlphaStable(alpha, scale, 17, beta=beta).sample(100_000)
    q = np.array([-3.0, -1.0, -0.3, 0.0, 0.3, 1.0, 3.0])
    ref = stats.levy_stable.cdf(q, alpha, beta, scale=scale)
    emp = np.array([(x <= v).mean() for v in q])
    np.testing.assert_allclose(emp, ref, atol=0.006)


def test_alpha_stable_alpha2_is_gaussian():
    x = AlphaStable(2.0, 0.5, 19).sample(N)
    assert x.var() == pytest.approx(2 * 0.5**2, rel=0.03)


# ------------------------------------------------------------------ coloured components


def test_gauss_markov_variance_and_correlation():
    sigma, tau, dt = 2.0, 0.5, 0.05
    x = GaussMarkov(sigma, tau, 23).sample(N, dt)
    assert x.std() == pytest.approx(sigma, rel=0.05)
    for lag in (1, 10):
        assert _lag_corr(x, lag) == pytest.approx(math.exp(-lag * dt / tau), abs=0.02)


def test_gauss_markov_dt_enters_discretisation():
    # same tau, different fix interval: per-sample correlation must follow e^{-dt/tau}
    x = GaussMarkov(1.0, 2.0, 29).sample(N, 1.0)
    assert _lag_corr(x, 1) == pytest.approx(math.exp(-0.5), abs=0.01)


def test_ar1_keeps_driver_variance_and_rho():
    drv = StudentT(1.5, 4.0, 31)
    ar = AR1(drv, rho=0.8)
    x = ar.sample(N)
    assert x.var() == pytest.approx(1.5**2, rel=0.08)
    assert _lag_corr(x, 1) == pytest.approx(0.8, abs=0.01)
    ar_tau = AR1(Laplace(1.0, 37), tau_s=1.0)
    y = ar_tau.sample(N, 0.05)
    assert _lag_corr(y, 1) == pytest.approx(math.exp(-0.05), abs=0.01)
    assert y.var() == pytest.approx(1.0, rel=0.1)


def test_ar1_with_stable_driver_keeps_scale():
    x = AR1(AlphaStable(1.5, 1.0, 41), rho=0.7).sample(200_000)
    ref = AlphaStable(1.5, 1.0, 43).sample(200_000)
    assert stats.ks_2samp(x, ref).pvalue > 1e-3


@pytest.mark.parametrize(
    "cfg",
    [
        {"type": "gaussian", "sigma": 1.0},
        {"type": "student-t", "sigma": 1.0, "nu": 3.0},
        {"type": "laplace", "sigma": 1.0},
        {"type": "weibull", "sigma": 1.0, "k": 0.8},
        {"type": "mixture", "eps": 0.1, "sigma1": 1.0, "sigma2": 4.0},
        {"type": "alpha-stable", "alpha": 1.5, "scale": 1.0, "beta": 0.2},
        {"type": "spikes", "prob": 0.1, "amplitude": 2.0, "amplitude_max": 3.0},
        {"type": "gauss-markov", "sigma": 1.0, "tau_s": 3.0},
        {"type": "ar1", "rho": 0.9, "driver": {"type": "weibull", "sigma": 1.0, "k": 1.5}},
    ],
)
def test_components_deterministic_and_chunk_invariant(cfg):
    a = make_component(cfg, np.random.SeedSequence(5))
    b = make_component(cfg, np.random.SeedSequence(5))
    c = make_component(cfg, np.random.SeedSequence(6))
    xa = a.sample(1000, 0.05)
    xb = np.concatenate([b.sample(1, 0.05), b.sample(336, 0.05), b.sample(663, 0.05)])
    np.testing.assert_allclose(xa, xb, rtol=1e-13, atol=1e-15)
    assert not np.array_equal(xa, c.sample(1000, 0.05))


# ------------------------------------------------------------------ outages


def test_outage_mean_durations():
    dt = 0.05
    out = OutageProcess(2.0, 0.5, 47).sample(400_000, dt)
    edges = np.flatnonzero(np.diff(out.astype(np.int8))) + 1
    runs = np.diff(np.concatenate(([0], edges, [out.size])))
    states = out[np.concatenate(([0], edges))]
    runs, states = runs[1:-1], states[1:-1]  # drop the censored first and last runs
    assert runs[~states].mean() * dt == pytest.approx(2.0, rel=0.05)
    assert runs[states].mean() * dt == pytest.approx(0.5, rel=0.05)
    assert 1 - out.mean() == pytest.approx(2.0 / 2.5, abs=0.01)


def test_outage_starts_up_unless_asked():
    assert not OutageProcess(1.0, 1.0, 1).sample(1, 0.05)[0]
    assert OutageProcess(1.0, 1.0, 1, start_in_outage=True).sample(1, 0.05)[0]


# ------------------------------------------------------------------ sensor


def _fixes(sensor: GpsSensor, seconds: float, ctrl_hz: float = 100.0, pos=None):
    out = []
    for i in range(int(round(seconds * ctrl_hz))):
        t = i / ctrl_hz
        p = (0.0, 0.0, 0.0) if pos is None else pos(t)
        out.append((t, sensor.measure(t, p)))
    return out


def test_rate_20hz_when_called_at_100hz():
    s = GpsSensor.from_preset("standalone", 1, rate_hz=20.0)
    res = _fixes(s, 10.0)
    times = [t for t, f in res if f is not None]
    assert len(times) == 200
    np.testing.assert_allclose(np.diff(times), 0.05, atol=1e-12)
    s5 = GpsSensor.from_preset("rtk", 1, rate_hz=5.0)
    assert sum(f is not None for _, f in _fixes(s5, 10.0)) == 50


def test_latency_returns_delayed_truth():
    s = GpsSensor.from_preset("perfect", 0, latency_s=0.1)

    def pos(t):
        return (t, 2.0 * t, 3.0)

    res = [(t, f) for t, f in _fixes(s, 2.0, pos=pos) if f is not None]
    for t, f in res:
        if t >= 0.1:
            np.testing.assert_allclose(f, pos(t - 0.1), atol=1e-9)
    # a latency between control ticks is interpolated
    s = GpsSensor.from_preset("perfect", 0, latency_s=0.025)
    res = [(t, f) for t, f in _fixes(s, 1.0, pos=pos) if f is not None and t > 0.1]
    np.testing.assert_allclose(res[0][1], pos(res[0][0] - 0.025), atol=1e-9)


def i_fix(t: float) -> bool:
    return abs(t * 20.0 - round(t * 20.0)) < 1e-6


def test_measure_equals_generate_errors_with_outages():
    over = {
        "outage": {"mean_up_s": 3.0, "mean_down_s": 0.4},
        "components": {"bias": {"type": "gauss-markov", "sigma": 0.5, "tau_s": 10.0}},
    }
    a = GpsSensor.from_preset("coloured-impulsive", 99, **over)
    b = GpsSensor.from_preset("coloured-impulsive", 99, **over)
    res = _fixes(a, 150.0)  # 3000 fixes, crosses several 1024-fix blocks
    got = np.array([f if f is not None else [np.nan] * 3 for t, f in res if i_fix(t)])
    ref = b.generate_errors(3000)
    assert np.isnan(ref[:, 0]).any() and (~np.isnan(ref[:, 0])).any()
    np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-13)


def test_determinism_and_stream_independence():
    base = GpsSensor.from_preset("standalone", 2024).generate_errors(5000)
    again = GpsSensor.from_preset("standalone", 2024).generate_errors(5000)
    other = GpsSensor.from_preset("standalone", 2025).generate_errors(5000)
    np.testing.assert_array_equal(base, again)
    assert not np.allclose(base, other)
    # add a component in FRONT of the list: the existing components' draws are unchanged
    cfg = gps_preset("standalone")
    spikes = {"type": "spikes", "name": "mp", "prob": 0.05, "amplitude": 7.0}
    cfg["components"].insert(0, spikes)
    more = GpsSensor.from_config(cfg, 2024).generate_errors(5000)
    diff = more - base
    hit = np.abs(diff) > 1e-9
    assert 0.03 < hit.mean() < 0.07
    np.testing.assert_allclose(np.abs(diff[hit]), 7.0 * np.broadcast_to(
        np.array(cfg["axis_scale"]), diff.shape)[hit], rtol=1e-9)
    # reordering components changes nothing
    cfg2 = gps_preset("standalone")
    cfg2["components"].reverse()
    np.testing.assert_allclose(GpsSensor.from_config(cfg2, 2024).generate_errors(5000), base,
                               rtol=1e-12, atol=1e-12)


def test_axes_independent_and_scaled():
    s = GpsSensor.from_preset("paper-numerical", 3)
    e = s.generate_errors(N)
    np.testing.assert_allclose(e.var(axis=0), [10.0, 100.0, 10.0], rtol=0.03)
    assert abs(np.corrcoef(e.T)[0, 1]) < 0.01
    assert s.variance == pytest.approx((10.0, 100.0, 10.0))


def test_presets_build_and_magnitudes():
    assert set(available_presets()) >= {
        "perfect", "rtk", "sbas", "standalone", "paper-numerical", "student-t", "laplace",
        "weibull", "mixture", "alpha-stable", "coloured", "coloured-impulsive",
    }
    for name in available_presets():
        e = GpsSensor.from_preset(name, 1).generate_errors(100)
        assert e.shape == (100, 3)
    h = {n: math.sqrt(GpsSensor.from_preset(n, 1).variance[0]) for n in available_presets()}
    assert h["perfect"] == 0.0
    assert 0.005 <= h["rtk"] <= 0.02
    assert 0.5 <= h["sbas"] <= 1.0
    assert 1.0 <= h["standalone"] <= 2.0
    for n in ("student-t", "laplace", "weibull", "mixture", "coloured", "coloured-impulsive"):
        assert GpsSensor.from_preset(n, 1).variance[:2] == pytest.approx((10.0, 100.0))
    sa = GpsSensor.from_preset("standalone", 1)
    assert 1.5 <= sa.axis_scale[2] / sa.axis_scale[0] <= 2.0


def test_standalone_dominated_by_slow_bias():
    e = GpsSensor.from_preset("standalone", 8).generate_errors(20_000)[:, 0]  # 2000 s at 10 Hz
    assert _lag_corr(e, 10) > 0.8  # 1 s apart: still strongly correlated


def test_overrides_and_toml_roundtrip():
    s = GpsSensor.from_preset("standalone", 4, components={"bias": {"tau_s": 30.0}},
                              latency_s=0.2)
    (name, procs, _), *_ = s.components
    assert name == "bias" and procs[0].tau_s == 30.0 and s.latency_s == 0.2
    s = GpsSensor.from_preset("standalone", 4, components={"white": {}})
    assert [c[0] for c in s.components] == ["bias"]
    cfg = tomllib.loads(tomli_w.dumps({"gps": gps_preset("coloured-impulsive")}))["gps"]
    np.testing.assert_array_equal(
        GpsSensor.from_config(cfg, 5).generate_errors(500),
        GpsSensor.from_preset("coloured-impulsive", 5).generate_errors(500),
    )


def test_errors_name_key_value_and_allowed():
    with pytest.raises(ValueError, match="'nonsense'.*allowed: perfect"):
        gps_preset("nonsense")
    with pytest.raises(ValueError, match=r"sigma = -1.0.*>= 0"):
        GpsSensor.from_preset("standalone", 1, components={"white": {"sigma": -1.0}})
    with pytest.raises(ValueError, match=r"nu = 2.0.*> 2"):
        make_component({"type": "student-t", "sigma": 1.0, "nu": 2.0}, 1)
    with pytest.raises(ValueError, match="sigmaa"):
        make_component({"type": "gaussian", "sigmaa": 1.0}, 1)
    with pytest.raises(ValueError, match="type = 'cauchy'.*allowed"):
        make_component({"type": "cauchy", "sigma": 1.0}, 1)
    with pytest.raises(ValueError, match="rate_hz = 0"):
        GpsSensor.from_preset("rtk", 1, rate_hz=0)
    with pytest.raises(ValueError, match="ratehz"):
        GpsSensor.from_preset("rtk", 1, ratehz=5)
    with pytest.raises(ValueError, match="rho"):
        make_component({"type": "ar1", "rho": 1.0, "driver": {"type": "gaussian", "sigma": 1}}, 1)
    with pytest.raises(ValueError, match="unique"):
        GpsSensor(components=[{"type": "gaussian", "sigma": 1}, {"type": "gaussian", "sigma": 2}],
                  seed=1)
    with pytest.raises(ValueError, match="mean_down_s"):
        GpsSensor(seed=1, outage={"mean_up_s": 1.0})


# ------------------------------------------------------------------ rtk-m350: fix-quality episodes

M350_DWELL = {"rtk-fixed": 300.0, "rtk-float": 20.0, "dgps": 30.0}
# occupancy pi_i ~ nu_i T_i, nu the jump chain's stationary law: nu ~ (0.8, 1, 0.32) by hand
# from next = fixed: {float .85, dgps .15}, float: {fixed .8, dgps .2}, dgps: {float 1}
_OCC = np.array([0.8 * 300.0, 1.0 * 20.0, 0.32 * 30.0])
M350_OCC = dict(zip(("rtk-fixed", "rtk-float", "dgps"), _OCC / _OCC.sum(), strict=True))


def _runs(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lengths, states) of the runs of ``idx``, without the censored first and last runs."""
    edges = np.flatnonzero(np.diff(idx)) + 1
    starts = np.concatenate(([0], edges))
    lengths = np.diff(np.concatenate((starts, [idx.size])))
    return lengths[1:-1], idx[starts][1:-1]


def test_m350_preset_nominal_figures_and_rate():
    s = GpsSensor.from_preset("rtk-m350", 1)
    assert s.rate_hz == 10.0
    assert s.fix_types == ("rtk-fixed", "rtk-float", "dgps")
    vx, vy, vz = s.variance  # nominal = RTK fixed, 1 cm + 1 ppm H, 1.5 cm + 1 ppm V at 1 km
    assert math.sqrt(vx + vy) == pytest.approx(0.011, rel=1e-9)
    assert math.sqrt(vz) == pytest.approx(0.016, rel=1e-9)
    # the episodes' extra error is not in the nominal variance (R is the RTK-fixed figure)
    assert s.mode_variance("dgps")[0] > 5000 * vx
    assert s.fix_quality.occupancy() == pytest.approx(M350_OCC, rel=1e-9)
    assert M350_OCC["rtk-fixed"] == pytest.approx(0.890, abs=1e-3)


def test_m350_dwell_means_occupancy_and_jumps():
    chain = GpsSensor.from_preset("rtk-m350", 7).fix_quality
    dt = 0.1
    idx = np.concatenate([chain.sample(500_000, dt)[0] for _ in range(8)])  # 400,000 s
    lengths, states = _runs(idx)
    tol = {"rtk-fixed": 0.10, "rtk-float": 0.08, "dgps": 0.15}  # ~4 standard errors
    for i, name in enumerate(chain.names):
        mean_s = lengths[states == i].mean() * dt
        assert mean_s == pytest.approx(M350_DWELL[name], rel=tol[name]), name
        assert (idx == i).mean() == pytest.approx(M350_OCC[name], rel=0.12), name
    # jump table: from fixed 85 % to float; from float 80 % re-fix; dgps always to float
    nxt = states[1:]
    cur = states[:-1]
    assert (nxt[cur == 0] == 1).mean() == pytest.approx(0.85, abs=0.04)
    assert (nxt[cur == 1] == 0).mean() == pytest.approx(0.80, abs=0.04)
    assert np.all(nxt[cur == 2] == 1)
    assert not np.any(nxt == cur)


def test_chain_weights_ramp_in_and_snap_back():
    chain = GpsSensor.from_preset("rtk-m350", 3).fix_quality
    dt = 0.1
    idx, w = chain.sample(300_000, dt)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(w >= -1e-15)
    # every fixed fix is a pure fixed fix (the snap)
    np.testing.assert_array_equal(w[idx == 0], np.broadcast_to([1.0, 0.0, 0.0], w[idx == 0].shape))
    # a float episode entered from fixed ramps in as 1 - a^j, a = exp(-dt / 2 s)
    a = math.exp(-dt / 2.0)
    starts = np.flatnonzero((idx[1:] == 1) & (idx[:-1] == 0)) + 1
    assert starts.size > 5
    for k0 in starts[:5]:
        j = np.arange(1, 6)
        np.testing.assert_allclose(w[k0 : k0 + 5, 1], 1.0 - a**j, rtol=1e-12)


def test_m350_errors_per_mode_exact_composition():
    """In the fixed mode the error is the base (RTK-fixed) error plus rare glitches only."""
    full, types = GpsSensor.from_preset("rtk-m350", 11).generate_errors(200_000,
                                                                        with_fix_type=True)
    base = GpsSensor.from_preset("rtk-m350", 11, fix_quality={}).generate_errors(200_000)
    fixed = types == 0
    d = np.abs(full[fixed] - base[fixed])
    hit = d[:, 0] > 1e-12
    assert 0.0005 < hit.mean() < 0.002  # glitch probability 0.001 per fix
    assert np.all((d[hit, 0] >= 0.05 - 1e-12) & (d[hit, 0] <= 0.20 + 1e-12))
    assert (types == 1).any() and (types == 2).any()
    assert np.abs(full[types == 2] - base[types == 2])[:, 0].mean() > 0.3


@pytest.mark.parametrize("mode, h_rms_lo, h_rms_hi", [
    ("rtk-fixed", 0.010, 0.014),   # 1 cm + 1 ppm at 1 km = 1.1 cm; glitches make it 1.25
    ("rtk-float", 0.25, 0.35),     # 0.3 m H RMS (0.1-0.5 m)
    ("dgps", 1.10, 1.30),          # SBAS 1.0 m CEP -> 0.85 m per axis -> 1.20 m H RMS
])
def test_m350_error_level_per_mode(mode, h_rms_lo, h_rms_hi):
    # hold the chain in `mode` (dwell 1e9 s) and sample 100,000 s at 1 s (>> every tau)
    ov = {"fix_quality": {"start": mode, "modes": {mode: {"mean_dwell_s": 1e9}}}}
    s = GpsSensor.from_preset("rtk-m350", 5, **ov)
    e, types = s.generate_errors(100_000, dt=1.0, with_fix_type=True)
    assert np.all(types == s.fix_types.index(mode))
    e = e[100:]  # past any ramp
    var = s.mode_variance(mode)
    np.testing.assert_allclose(e.var(axis=0), var, rtol=0.08)
    h_rms = math.sqrt(float(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))
    assert h_rms_lo <= h_rms <= h_rms_hi
    # heavy tails: the white part is Student-t, the spikes add outliers
    z = e[:, 0] / e[:, 0].std()
    assert np.mean(np.abs(z) > 4.0) > 2 * 2 * stats.norm.sf(4.0)


def test_m350_chunk_invariant_and_measure_matches():
    a = GpsSensor.from_preset("rtk-m350", 21)
    b = GpsSensor.from_preset("rtk-m350", 21)
    ea, ta = a.generate_errors(30_000, with_fix_type=True)
    parts = [b.generate_errors(n, with_fix_type=True) for n in (1, 1023, 9000, 19_976)]
    np.testing.assert_allclose(ea, np.concatenate([p[0] for p in parts]), rtol=1e-12,
                               atol=1e-14)
    np.testing.assert_array_equal(ta, np.concatenate([p[1] for p in parts]))
    assert (ta > 0).any()  # the stretch crosses episodes
    # measure() at 100 Hz delivers the same errors and reports the fix type of each fix
    c = GpsSensor.from_preset("rtk-m350", 21)
    kinds = []
    errs = []
    for i in range(300_000):  # 3000 s
        t = i / 100.0
        f = c.measure(t, (0.0, 0.0, 0.0))
        if f is not None:
            errs.append(f)
            kinds.append(c.last_fix_type)
    assert len(errs) == 30_000
    np.testing.assert_allclose(np.array(errs), ea, rtol=1e-12, atol=1e-14)
    assert kinds == [c.fix_types[i] for i in ta]
    assert c.fix_type_counts == {n: int((ta == i).sum()) for i, n in enumerate(c.fix_types)}


def test_m350_deterministic_per_seed_and_streams_keyed_by_name():
    e1, t1 = GpsSensor.from_preset("rtk-m350", 2024).generate_errors(50_000, with_fix_type=True)
    e2, t2 = GpsSensor.from_preset("rtk-m350", 2024).generate_errors(50_000, with_fix_type=True)
    e3, t3 = GpsSensor.from_preset("rtk-m350", 2025).generate_errors(50_000, with_fix_type=True)
    np.testing.assert_array_equal(e1, e2)
    np.testing.assert_array_equal(t1, t2)
    assert not np.allclose(e1, e3)
    assert not np.array_equal(t1, t3)
    # a new component in one mode changes neither the chain nor the other components' draws
    ov = {"fix_quality": {"modes": {"dgps": {"components": {"extra": {
        "type": "gaussian", "sigma": 5.0}}}}}}
    e4, t4 = GpsSensor.from_preset("rtk-m350", 2024, **ov).generate_errors(50_000,
                                                                           with_fix_type=True)
    np.testing.assert_array_equal(t4, t1)
    same = t1 != 2
    # outside dgps only the fading dgps weight can differ: equal except within the ramp-out
    assert np.mean(np.isclose(e4[same], e1[same], rtol=0, atol=1e-12)) > 0.97
    assert not np.allclose(e4[t1 == 2], e1[t1 == 2])


def test_presets_without_fix_quality_report_no_fix_type():
    s = GpsSensor.from_preset("rtk", 1)
    e, t = s.generate_errors(100, with_fix_type=True)
    assert s.fix_types == () and np.all(t == -1)
    s.measure(0.0, (0.0, 0.0, 0.0))
    assert s.last_fix_type is None and s.fix_type_counts == {}


# ------------------------------------------------------------------ strict override validation

_BAD_OVERRIDES = [
    # (preset, overrides, regex the one-line message must match)
    ("rtk", {"axis_scale": "x"}, r"axis_scale = 'x'.*3 finite numbers >= 0"),
    ("rtk", {"axis_scale": "123"}, r"axis_scale = '123'.*3 finite numbers"),
    ("rtk", {"axis_scale": [1.0, 1.0]}, r"axis_scale = \[1.0, 1.0\].*3 finite"),
    ("rtk", {"axis_scale": [1.0, float("nan"), 1.0]}, r"axis_scale = \[1.0, nan, 1.0\]"),
    ("rtk", {"axis_scale": [1.0, True, 1.0]}, r"axis_scale = \[1.0, True, 1.0\]"),
    ("rtk", {"axis_scale": [1.0, -1.0, 1.0]}, r"axis_scale.*>= 0"),
    ("rtk", {"rate_hz": "20"}, r"rate_hz = '20'.*number > 0 and <= 100"),
    ("rtk", {"rate_hz": True}, r"rate_hz = True.*number"),
    ("rtk", {"rate_hz": float("nan")}, r"rate_hz = nan.*finite"),
    ("rtk", {"rate_hz": float("inf")}, r"rate_hz = inf.*finite"),
    ("rtk", {"rate_hz": 0}, r"rate_hz = 0.*> 0"),
    ("rtk", {"rate_hz": 500.0}, r"rate_hz = 500.0.*<= 100"),
    ("rtk", {"latency_s": -0.1}, r"latency_s = -0.1.*>= 0"),
    ("rtk", {"latency_s": 5.0}, r"latency_s = 5.0.*<= 1"),
    ("rtk", {"ratehz": 5}, r"ratehz = 5.*unknown key; allowed: axis_scale"),
    ("rtk", {"components": "white"}, r"components = 'white'.*list of component tables"),
    ("rtk", {"components": {"white": 0.5}}, r"components.white = 0.5.*must be a table"),
    ("rtk", {"components": [1.0]}, r"components\[0\] = 1.0.*component table"),
    ("rtk", {"components": {"white": {"sigma": "0.5"}}}, r"sigma = '0.5'.*number >= 0"),
    ("rtk", {"components": {"white": {"sigma": float("nan")}}}, r"sigma = nan.*finite"),
    ("rtk", {"components": {"white": {"sigmaa": 1.0}}}, r"sigmaa = 1.0.*unknown key"),
    ("rtk", {"components": {"white": {"axis_scale": "xyz"}}}, r"axis_scale = 'xyz'"),
    ("rtk", {"components": {"mp": {"type": "spikes", "prob": 1.5, "amplitude": 1.0}}},
     r"prob = 1.5.*\[0, 1\]"),
    ("rtk", {"components": {"ar": {"type": "ar1", "rho": 0.5, "driver": {
        "type": "ar1", "rho": 0.5, "driver": {"type": "gaussian", "sigma": 1.0}}}}},
     r"type = 'ar1'.*driver must be one of"),
    ("rtk", {"components": {"t": {"type": "student-t", "sigma": 1.0, "nu": "3"}}},
     r"nu = '3'"),
    ("rtk", {"outage": "none"}, r"outage = 'none'.*must be a table"),
    ("rtk", {"outage": []}, r"outage = \[\].*must be a table"),
    ("rtk", {"outage": {"mean_up_s": "10", "mean_down_s": 1.0}}, r"mean_up_s = '10'"),
    ("rtk", {"outage": {"mean_up_s": 10.0, "mean_down_s": 1.0, "start_in_outage": "yes"}},
     r"start_in_outage = 'yes'.*true or false"),
    ("rtk", {"outage": {"mean_up_s": 10.0, "mean_down": 1.0}}, r"mean_down = 1.0.*unknown key"),
    ("rtk", [("rate_hz", 5.0)], r"overrides = .*must be a table"),
    ("rtk", {3: 5.0}, r"overrides key = 3.*non-empty strings"),
    ("nonsense", {}, r"name = 'nonsense'.*allowed: perfect"),
    ("rtk-m350", {"fix_quality": 5}, r"fix_quality = 5.*must be a table"),
    ("rtk-m350", {"fix_quality": {"mode": {}}}, r"mode = \{\}.*unknown key; allowed: modes"),
    ("rtk-m350", {"fix_quality": {"start": "rtk"}}, r"start = 'rtk'.*one of the modes"),
    ("rtk-m350", {"fix_quality": {"modes": "x"}}, r"modes = 'x'.*table of mode tables"),
    ("rtk-m350", {"fix_quality": {"modes": {"dgps": 30.0}}}, r"modes.dgps = 30.0.*table"),
    ("rtk-m350", {"fix_quality": {"modes": {"dgps": {"mean_dwell_s": -30.0}}}},
     r"'dgps'.*mean_dwell_s = -30.0.*> 0"),
    ("rtk-m350", {"fix_quality": {"modes": {"dgps": {"mean_dwell_s": "30"}}}},
     r"mean_dwell_s = '30'"),
    ("rtk-m350", {"fix_quality": {"modes": {"dgps": {"ramp_s": float("inf")}}}},
     r"ramp_s = inf.*finite"),
    ("rtk-m350", {"fix_quality": {"modes": {"dgps": {"next": {"rtk-float": 0.5}}}}},
     r"next = \{'rtk-float': 0.5\}.*summing to 1"),
    ("rtk-m350", {"fix_quality": {"modes": {"dgps": {"next": {"dgps": 1.0}}}}},
     r"next.dgps = 1.0.*other modes"),
    ("rtk-m350", {"fix_quality": {"modes": {"dgps": {"next": {"rtk-float": 1.0,
                                                              "rtk-fixed": -0.0001}}}}},
     r"next.rtk-fixed = -0.0001.*>= 0"),
    ("rtk-m350", {"fix_quality": {"modes": {"dgps": {"dwell": 3.0}}}}, r"dwell = 3.0.*unknown"),
    ("rtk-m350", {"fix_quality": {"modes": {"dgps": {"components": {"white": {"nu": 2.0}}}}}},
     r"nu = 2.0.*> 2"),
    ("rtk-m350", {"fix_quality": {"modes": {"sbas": {"mean_dwell_s": 10.0}}}},
     r"'sbas'.*next = None.*required"),
]


@pytest.mark.parametrize("preset, overrides, pattern", _BAD_OVERRIDES)
def test_bad_overrides_raise_one_line_naming_key_value_allowed(preset, overrides, pattern):
    with pytest.raises(ValueError, match=pattern) as ei:
        validate_overrides(preset, overrides)
    assert "\n" not in str(ei.value)
    if isinstance(overrides, dict) and all(isinstance(k, str) for k in overrides):
        with pytest.raises(ValueError, match=pattern):
            GpsSensor.from_preset(preset, 0, **overrides)


@pytest.mark.parametrize("preset, overrides", [
    ("rtk", {}),
    ("rtk", {"axis_scale": [1, 1, 2], "rate_hz": 5, "latency_s": 0.05}),
    ("standalone", {"components": {"bias": {"tau_s": 30.0}, "white": {}}}),
    ("standalone", {"outage": {"mean_up_s": 10.0, "mean_down_s": 1.0,
                               "start_in_outage": True}}),
    ("rtk-m350", {"fix_quality": {}}),
    ("rtk-m350", {"rate_hz": 20.0, "fix_quality": {"modes": {
        "dgps": {"mean_dwell_s": 60.0, "components": {"multipath": {}}}}}}),
])
def test_good_overrides_pass(preset, overrides):
    assert validate_overrides(preset, overrides) is None
    GpsSensor.from_preset(preset, 0, **overrides)


def test_mode_override_removes_a_mode():
    ov = {"fix_quality": {"modes": {"dgps": {},
                                    "rtk-fixed": {"next": {"rtk-float": 1.0}},
                                    "rtk-float": {"next": {"rtk-fixed": 1.0}}}}}
    s = GpsSensor.from_preset("rtk-m350", 0, **ov)
    assert s.fix_types == ("rtk-fixed", "rtk-float")
    with pytest.raises(ValueError, match=r"next.dgps = 0.15"):
        validate_overrides("rtk-m350", {"fix_quality": {"modes": {"dgps": {}}}})


def test_m350_filters_get_the_nominal_rtk_r_not_the_fix_type():
    """The loop's R comes from the nominal (RTK-fixed) variance, floored at (1 cm)^2; the episode
    levels (float: 0.2 m, DGPS: 0.85 m per axis) never reach it."""
    import ag_uav
    from ag_uav.navigation.estimation import R_FLOOR, EstimatorFeedback
    from ag_uav.seeds import seed_sequences

    cfg = ag_uav.load_config(None, {"gps.preset": "rtk-m350", "estimator.name": "kf"})
    ss = seed_sequences(cfg.seed)
    fb = EstimatorFeedback(cfg, ss["gps"], ss["altimeter"], ss["imu"])
    nominal = fb.gps.variance
    assert nominal[0] < R_FLOOR
    np.testing.assert_allclose(fb.r_diag[:2], [R_FLOOR, R_FLOOR])
    assert fb.r_diag[0] < 1e-3 * fb.gps.mode_variance("dgps")[0]
