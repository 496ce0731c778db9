"""The world's packed rows are what their Layouts say: a wind row built by :class:`Wind` and the
deposition's parameter vector and input rows built by their packers have the layouts' sizes,
and their named fields hold the configuration and the last tick's state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ag_uav.world.deposition import (
    DepositionBatch,
    DepositionConfig,
    GridSpec,
    footprints,
    pack_input,
    pack_params,
)
from ag_uav.world.deposition_layout import (
    DEP_PARAMS,
    DEP_STATE,
    FOOTPRINT,
    INPUT,
    MOMENTS,
    NACC,
    NFOOT,
    NSLOW,
    P_HEADER,
    S_ACC,
    WIDE,
)
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


P, I = DEP_PARAMS.at, INPUT.at


def test_the_deposition_parameters_hold_the_config_by_name():
    cfg = DepositionConfig(rate_l_per_ha=12.5, swath_m=5.5, speed_min_mps=0.7,
                           pressure_tau_s=0.2, rotor_z_m=0.09, n_classes=7, flush_ticks=40,
                           wake_escape=0.35, airborne_after_s=300.0)
    g = GridSpec(-3.0, -4.0, 0.5, 16, 8, 2, (0, 128, 160))
    par = pack_params(cfg, g)
    assert P_HEADER == DEP_PARAMS.size == P.SIZE and S_ACC == DEP_STATE.size
    assert (NACC, NSLOW, NFOOT) == (MOMENTS.size, WIDE.size, FOOTPRINT.size)
    assert (par[P.RATE], par[P.SWATH], par[P.VMIN], par[P.TAU], par[P.ROTZ]) == (
        12.5, 5.5, 0.7, 0.2, 0.09)
    assert (par[P.X0], par[P.Y0], par[P.CELL], par[P.NX], par[P.NY], par[P.NLEV]) == (
        -3.0, -4.0, 0.5, 16, 8, 2)
    assert (par[P.FLUSHT], par[P.ESC], par[P.TMAX]) == (40, 0.35, 300.0)
    noz = np.asarray(cfg.nozzle_xyz_m, float).reshape(-1, 3)
    assert (par[P.M], par[P.K]) == (len(noz), 7)
    # the arrays follow the header at the offsets its o_* slots hold
    assert par[P.O_NOZ] == P_HEADER
    o = int(par[P.O_NOZ])
    assert np.array_equal(par[o:o + noz.size], noz.ravel())
    o = int(par[P.O_SHARE])
    assert np.array_equal(par[o:o + len(noz)], cfg.nozzle_share)
    o = int(par[P.O_LEV])
    assert np.array_equal(par[o:o + g.levels], g.offsets[:-1])


def test_an_input_row_holds_its_fields_by_name():
    R = np.arange(1.0, 10.0) / 10.0
    inp = pack_input((1.0, 2.0, 3.0), (4.0, 5.0, 6.0), R, 21.5, (0.5, -0.25, 0.0), True)
    assert inp.shape == (1, INPUT.size)
    assert tuple(inp[0, I.POS:I.POS_END]) == (1.0, 2.0, 3.0)
    assert tuple(inp[0, I.VEL:I.VEL_END]) == (4.0, 5.0, 6.0)
    assert np.array_equal(inp[0, I.R:I.R_END], R)
    assert (inp[0, I.THRUST], inp[0, I.CMD]) == (21.5, 1.0)
    assert tuple(inp[0, I.WIND:I.WIND_END]) == (0.5, -0.25, 0.0)
    f = footprints(DepositionConfig(n_classes=3), inp)
    assert list(f)[:NFOOT] == list(FOOTPRINT.offset)


def test_a_deposition_state_row_books_by_name():
    cfg = DepositionConfig(n_classes=3)
    dep = DepositionBatch(cfg, None, 1, bounds=(-5.0, -5.0, 5.0, 5.0))
    R = np.eye(3).ravel()
    inp = pack_input((0.0, 0.0, 3.0), (2.0, 0.0, 0.0), R, 60.0, (0.0, 0.0, 0.0), True)
    S = DEP_STATE.at
    sprayed = last = 0.0
    for _ in range(30):
        last = float(dep.step_packed(0.01, inp)[0])
        sprayed += last
    st = dep.st[0]
    m = int(dep.par[P.M])
    assert dep.st.shape[1] >= S_ACC + 1 + INPUT.size + m * NACC
    assert st[S.ON] == 1.0 and st[S.INSIDE] == 1.0 and st[S.INC] == -1.0  # on, settled
    assert st[S.SPRAYED] == pytest.approx(sprayed, rel=1e-12) and sprayed > 0.0
    assert st[S.LITRES_TICK] == last and st[S.Q] == dep.flow_lps[0] > 0.0
