"""The world's packed rows are what their Layouts say: a wind row built by :class:`Wind` has the
layout's size and its named fields hold the configuration and the last tick's state."""

from __future__ import annotations

import math

import numpy as np

from ag_uav.world.wind import (
    DRAWS,
    FILTER2,
    WIND_INTS,
    WIND_ROW,
    Wind,
    dryden_parameters,
)

W, WI = WIND_ROW.at, WIND_INTS.at


def test_a_wind_row_holds_its_configuration_by_name():
    rng = np.random.default_rng(7)
    wind = Wind(mean_speed=4.0, direction_deg=30.0, turbulence=2.5, rng=rng, rel_tol=0.02)
    fs, ist, buf = wind.row_state
    assert fs.shape == (1, WIND_ROW.size) and ist.shape == (1, WIND_INTS.size)
    assert WIND_ROW.width["vc"] == WIND_ROW.width["wc"] == FILTER2.size == 7
    assert (fs[0, W.W20], fs[0, W.RELTOL]) == (2.5, 0.02)
    d = math.radians(30.0)
    assert (fs[0, W.EX], fs[0, W.EY]) == (-math.sin(d), -math.cos(d))  # downwind
    assert (fs[0, W.MX], fs[0, W.MY]) == wind.mean[:2]
    assert fs[0, W.V] == fs[0, W.H] == fs[0, W.DT] == -1.0  # nothing cached yet
    assert ist[0, WI.TURB] == 1 and ist[0, WI.BLOCK] == wind.turbulence.block == buf.shape[1]


def test_a_wind_row_holds_the_last_tick_by_name():
    rng = np.random.default_rng(11)
    wind = Wind(mean_speed=3.0, direction_deg=200.0, turbulence="mean", rng=rng)
    fs, ist, _ = wind.row_state
    wx, wy, wz = wind.step(0.01, 12.0, 5.0)
    assert (fs[0, W.V], fs[0, W.H], fs[0, W.DT]) == (5.0, 12.0, 0.01)
    su, sw, l_u, l_w, _ = dryden_parameters(3.0, 12.0)
    assert (fs[0, W.SU], fs[0, W.SW], fs[0, W.LU], fs[0, W.LW]) == (su, sw, l_u, l_w)
    assert fs[0, W.A] == math.exp(-5.0 * 0.01 / l_u)  # a = e^−θu
    assert ist[0, WI.I] == DRAWS.size  # one tick read its five normals
    # w = σ_w (½ zw1 + √3/2 zw2): the vertical gust from the named filter states
    assert wz == sw * (0.5 * fs[0, W.ZW1] + math.sqrt(3.0) / 2.0 * fs[0, W.ZW2])
    u = su * fs[0, W.ZU]
    v = su * (0.5 * fs[0, W.ZV1] + math.sqrt(3.0) / 2.0 * fs[0, W.ZV2])
    ex, ey = fs[0, W.EX], fs[0, W.EY]
    assert (wx, wy) == (fs[0, W.MX] + u * ex - v * ey, fs[0, W.MY] + u * ey + v * ex)
