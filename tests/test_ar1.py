"""The sensors' first-order recursion (``ag_uav.vehicle.ar1``) against scipy's lfilter, bit
for bit, over random draws, gains, poles (negative ones too), block lengths and starts."""

import numpy as np
import pytest
from scipy.signal import lfilter

from ag_uav.vehicle.ar1 import ar1_filter
from ag_uav.vehicle.gps.noise import AR1, GaussMarkov, StudentT
from ag_uav.vehicle.imu import gauss_markov_block


@pytest.mark.parametrize("seed", range(6))
def test_equals_lfilter_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    for _ in range(20):
        n, m = int(rng.integers(1, 400)), int(rng.integers(1, 7))
        g, phi = float(rng.uniform(0.0, 3.0)), float(rng.uniform(-0.999, 0.9999))
        x = rng.standard_t(3.0, (n, m))
        y0 = rng.normal(size=m)
        want, _ = lfilter([g], [1.0, -phi], x, axis=0, zi=(phi * y0)[None, :])
        assert np.array_equal(ar1_filter(x, g, phi, phi * y0), want)
        want1, _ = lfilter([g], [1.0, -phi], x[:, 0], zi=[phi * y0[0]])
        got1 = ar1_filter(x[:, 0], g, phi, phi * y0[0])
        assert got1.shape == (n,) and np.array_equal(got1, want1)


def test_recursion_by_hand():
    x = np.array([1.0, -2.0, 0.5])
    y = ar1_filter(x, 2.0, 0.5, 0.25)   # y_-1 = 0.5
    assert y.tolist() == [0.25 + 2.0, 0.5 * 2.25 - 4.0, 0.5 * (0.5 * 2.25 - 4.0) + 1.0]


def _lfilter_gm_block(rng, x0, n, phi, sigma):
    drive = rng.standard_normal((n, len(x0))) * (sigma * np.sqrt(max(1.0 - phi * phi, 0.0)))
    return lfilter([1.0], [1.0, -phi], drive, axis=0, zi=(phi * x0)[None, :])[0]


def test_sensor_processes_unchanged():
    """The IMU's attitude-error block and the GNSS Gauss–Markov and AR(1) components give
    what they gave on lfilter."""
    x0 = np.array([0.01, -0.02, 0.003])
    sig = np.array([0.02, 0.02, 0.05])
    got = gauss_markov_block(np.random.default_rng(4), x0, 1000, 0.995, sig)
    assert np.array_equal(got, _lfilter_gm_block(np.random.default_rng(4), x0, 1000, 0.995, sig))

    gm = GaussMarkov(0.3, 30.0, seed=11)
    a, b = gm.sample(50, 0.1), gm.sample(70, 0.1)
    ref = GaussMarkov(0.3, 30.0, seed=11)
    r = ref._rng.standard_normal(50)
    rho, g = np.exp(-0.1 / 30.0), 0.3 * np.sqrt(-np.expm1(-0.2 / 30.0))
    first = 0.3 * r[0]
    want = np.concatenate(([first], lfilter([g], [1.0, -rho], r[1:], zi=[rho * first])[0]))
    assert np.array_equal(a, want)
    r2 = ref._rng.standard_normal(70)
    assert np.array_equal(b, lfilter([g], [1.0, -rho], r2, zi=[rho * want[-1]])[0])

    ar = AR1(StudentT(1.0, 3.0, seed=5), rho=-0.6)
    out = ar.sample(200, 0.1)
    drv = StudentT(1.0, 3.0, seed=5).sample(200, 0.1)
    gain = np.sqrt(1.0 - 0.36)
    want = np.concatenate(([drv[0]], lfilter([gain], [1.0, 0.6], drv[1:], zi=[-0.6 * drv[0]])[0]))
    assert np.array_equal(out, want)
