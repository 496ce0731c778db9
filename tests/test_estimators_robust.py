"""Every filter of the bank survives 1e6 m outliers, NaN fixes and alpha-stable noise.

Three phases: clean Gaussian noise, a disturbance phase (alpha-stable α = 1.1 noise, 1 % of
fixes replaced by ±1e6 m outliers, 5 % NaN fixes), and clean noise again.  Throughout, x and
P stay finite and P symmetric positive definite; at the end the position error is back to the
level it had before the disturbance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import levy_stable

import estimators

DT = 0.05
EXTRA = {"kf-bias": dict(tau=30.0, sigma_b=0.3), "kf-diff": dict(gamma=0.3)}


def _scenario(n_steps: int, seed: int):
    rng = np.random.default_rng(seed)
    rng_noise, rng_stable, rng_out, rng_nan = (
        np.random.default_rng(s) for s in rng.bit_generator.seed_seq.spawn(4)
    )
    t = np.arange(n_steps) * DT
    truth = np.stack([50 * np.sin(0.02 * t) + 2 * t, 40 * np.cos(0.015 * t)], axis=1)
    Z = truth + rng_noise.standard_normal((n_steps, 2))
    a, b = int(0.2 * n_steps), int(0.6 * n_steps)
    Z[a:b] = truth[a:b] + levy_stable.rvs(
        1.1, 0.0, scale=1.0, size=(b - a, 2), random_state=rng_stable
    )
    out = a + np.flatnonzero(rng_out.random(b - a) < 0.01)
    Z[out] = truth[out] + 1e6 * rng_out.choice([-1.0, 1.0], size=(len(out), 2))
    nan = a + np.flatnonzero(rng_nan.random(b - a) < 0.05)
    Z[nan, rng_nan.integers(0, 2, size=len(nan))] = np.nan
    return truth, Z, (a, b)


def _check_spd(P: np.ndarray) -> None:
    assert np.all(np.isfinite(P))
    assert np.allclose(P, P.T, rtol=1e-9, atol=1e-12 * float(np.max(np.abs(P))))
    np.linalg.cholesky(0.5 * (P + P.T))  # raises if not positive definite


def _run(name: str, n_steps: int, seed: int) -> None:
    truth, Z, (a, b) = _scenario(n_steps, seed)
    mdl_x0 = np.array([truth[0, 0], 2.0, truth[0, 1], 0.0])
    f = estimators.make(
        name, model="cv", dim=2, dt=DT, q=0.5, r=1.0, x0=mdl_x0, p0=1.0, **EXTRA.get(name, {})
    )
    err = np.empty(n_steps)
    n_nan_rejected = 0
    for k in range(n_steps):
        f.predict()
        used = f.update(Z[k])
        if not np.all(np.isfinite(Z[k])):
            assert not used
            n_nan_rejected += 1
        assert np.all(np.isfinite(f.x)), (name, k)
        if k % 97 == 0 or a <= k < a + 50:
            _check_spd(f.P)
        err[k] = math.hypot(*(f.x[[0, 2]] - truth[k]))
    _check_spd(f.P)
    assert n_nan_rejected > 0
    tail = max(n_steps // 20, 200)
    before = float(np.sqrt(np.mean(err[a - tail : a] ** 2)))
    after = float(np.sqrt(np.mean(err[-tail:] ** 2)))
    assert before < 2.0, (name, before)
    assert after < 1.5 * before + 0.1, (name, before, after)


@pytest.mark.parametrize("name", estimators.available())
def test_robust_fast(name):
    _run(name, 10_000, seed=1)


@pytest.mark.slow
@pytest.mark.parametrize("name", estimators.available())
def test_robust_long(name):
    _run(name, 100_000, seed=2)
