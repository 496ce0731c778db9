"""Spray deposition (ag_uav.world.deposition): mass balance, symmetry, wind, nozzle delays,
dose metrics, batch = scalar, and the pattern test's CV / effective swath."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ag_uav.jobs.experiments.swath import cv_vs_spacing, effective_swath, pass_states
from ag_uav.world.deposition import (
    Deposition,
    DepositionBatch,
    DepositionConfig,
    DoseMap,
    GridSpec,
    droplet_classes,
    terminal_velocity,
)
from ag_uav.world.field import Field

HOVER_T = 6.47 * 9.81
I9 = np.eye(3).ravel()
SQUARE = Field.from_coords([(0, 0), (40, 0), (40, 30), (0, 30)])


def _pass(dep, x0, x1, y, v, h=3.0, wind=(0.0, 0.0, 0.0), on=None, dt=0.01, R=I9, extra=1.0):
    """Fly along x from x0 to x1 (v may be negative) at y, height h; spray where on(x)."""
    n = int(round(abs(x1 - x0) / abs(v) / dt + extra / dt))
    x = x0
    for _ in range(n):
        x += v * dt
        dep.step(dt, (x, y, h), (v, 0.0, 0.0), R, HOVER_T, wind, bool(on(x)) if on else True)


def test_droplet_classes_match_the_spectrum():
    from scipy.stats import norm

    assert droplet_classes(120, 250, 420, 1)[0][0] == pytest.approx(250e-6)
    d, f = droplet_classes(120, 250, 420, 10)
    assert f.sum() == pytest.approx(1.0) and np.all(np.diff(d) > 0)
    # the volume median of the classes is Dv50 and the volume below 100 µm is represented:
    # the split log-normal puts Φ(ln(100/250)/s_lo) = 5.5 % there; the classes below 105 µm
    # hold it within their bins' resolution
    s_lo = math.log(250 / 120) / norm.ppf(0.9)
    below = norm.cdf(math.log(100 / 250) / s_lo)
    assert below == pytest.approx(0.055, abs=0.001)
    assert f[d < 100e-6].sum() == pytest.approx(below, rel=0.5)
    assert d[0] < 50e-6                       # the finest class sits in the drift tail
    assert np.cumsum(f)[np.searchsorted(d, 250e-6) - 1] < 0.5 < np.cumsum(f)[np.searchsorted(
        d, 250e-6)]


def test_terminal_velocity_stokes_limit_and_monotone():
    d = 20e-6
    stokes = (1000.0 - 1.225) * 9.81 * d * d / (18 * 1.81e-5)
    assert terminal_velocity(d) == pytest.approx(stokes, rel=0.01)
    vs = [terminal_velocity(x * 1e-6) for x in (50, 100, 200, 400, 800)]
    assert all(a < b for a, b in zip(vs, vs[1:], strict=False))
    # above Stokes: the Schiller–Naumann drag slows a 400 µm drop well below Stokes' figure
    assert vs[3] < 0.5 * (1000.0 - 1.225) * 9.81 * (400e-6) ** 2 / (18 * 1.81e-5)


def test_mass_conserved_to_1e9_in_every_destination():
    cfg = DepositionConfig(buffer_m=3.0, cell_m=0.5)
    dep = Deposition(cfg, SQUARE)
    tilt = np.array([[0.985, 0, 0.174], [0, 1, 0], [-0.174, 0, 0.985]]).ravel()
    _pass(dep, -20, 60, 15, 5.0, wind=(0.0, 4.0, 0.3), R=tilt, on=lambda x: x > -15)
    _pass(dep, 60, -20, 2, -6.0, h=5.0, wind=(1.0, -5.0, 0.0), on=lambda x: x < 45)
    dm = dep.dose_map()
    assert dm.sprayed_l > 0 and dm.drift_l > 0 and dm.outside_grid_l > 0
    assert dm.evaporated_l > 0
    total = dm.litres.sum() + dm.outside_grid_l + dm.drift_l + dm.airborne_l  # the tank mix
    assert abs(total - dm.sprayed_l) <= 1e-9 * dm.sprayed_l
    assert dm.evaporated_l < (1.0 - cfg.nonvolatile_fraction) * dm.sprayed_l  # water only
    m = dep.metrics()
    assert abs(m["mass_balance_error"]) <= 1e-9


def test_hover_footprint_symmetric_about_the_nozzles():
    cfg = DepositionConfig(speed_min_mps=0.0, flow_min_l_per_s=0.01, buffer_m=6.0)
    dep = Deposition(cfg, bounds=(-5.0, -5.0, 5.0, 5.0))
    for _ in range(300):
        dep.step(0.01, (0.0, 0.0, 3.0), (0.0, 0.0, 0.0), I9, HOVER_T, (0.0, 0.0, 0.0), True)
    lit = dep.dose_map().litres
    assert lit.sum() > 0
    scale = lit.max()
    assert np.max(np.abs(lit - lit[::-1, :])) <= 1e-9 * scale
    assert np.max(np.abs(lit - lit[:, ::-1])) <= 1e-9 * scale
    assert np.max(np.abs(lit - lit.T)) <= 1e-9 * scale


def _centroid_and_far(wind):
    dep = Deposition(DepositionConfig(buffer_m=25.0), bounds=(-20, -1, 20, 1))
    _pass(dep, -25, 25, 0.0, 5.0, wind=(0.0, wind, 0.0), on=lambda x: abs(x) < 20)
    dm = dep.dose_map()
    _, yc = dm.centres()
    prof = dm.litres.sum(axis=1)
    cen = float((prof * yc).sum() / prof.sum())
    far = float(prof[yc > 5.0].sum() / dm.sprayed_l)
    return cen, far


def test_doubling_the_wind_moves_the_deposit_downwind_monotonically():
    res = [_centroid_and_far(w) for w in (0.0, 1.0, 2.0, 4.0, 8.0)]
    cens = [c for c, _ in res]
    fars = [f for _, f in res]
    assert abs(cens[0]) < 1e-9
    assert all(a < b for a, b in zip(cens, cens[1:], strict=False))
    assert all(a < b for a, b in zip(fars[1:], fars[2:], strict=False))
    assert cens[-1] > 2.0


def _edge(delay_on, delay_off, v=5.0):
    cfg = DepositionConfig(nozzle_on_delay_s=delay_on, nozzle_off_delay_s=delay_off,
                           cmd_off_immediate=False, pressure_tau_s=0.0, cell_m=0.25)
    dep = Deposition(cfg, bounds=(-30, -1, 30, 1))
    _pass(dep, -30, 30, 0.0, v, on=lambda x: -10.0 <= x <= 10.0)
    dm = dep.dose_map()
    xc, _ = dm.centres()
    along = dm.litres.sum(axis=0)
    half = 0.5 * along[np.abs(xc) < 2].mean()
    above = np.nonzero(along > half)[0]
    # interpolated half-height crossings of the rising and the falling edge
    i, j = above[0], above[-1]
    x_on = xc[i - 1] + (half - along[i - 1]) / (along[i] - along[i - 1]) * (xc[i] - xc[i - 1])
    x_off = xc[j] + (along[j] - half) / (along[j] - along[j + 1]) * (xc[j + 1] - xc[j])
    return x_on, x_off, dm.grid.cell


@pytest.mark.parametrize("d", [0.1, 0.4, 1.0])
def test_nozzle_delay_shifts_the_sprayed_edge_by_v_times_d(d):
    v = 5.0
    on0, off0, cell = _edge(0.0, 0.0, v)
    on1, off1, _ = _edge(d, d, v)
    assert abs((on1 - on0) - v * d) <= cell
    assert abs((off1 - off0) - v * d) <= cell


def test_command_off_is_immediate_by_default():
    cfg = DepositionConfig(pressure_tau_s=0.0)
    dep = Deposition(cfg, bounds=(-5, -5, 5, 5))
    lit = [dep.step(0.01, (0, 0, 3), (5, 0, 0), I9, HOVER_T, (0, 0, 0), k < 100)
           for k in range(120)]
    assert lit[9] == 0.0 and lit[10] > 0.0          # opens 0.1 s after the command
    assert lit[99] > 0.0 and lit[100] == 0.0        # closes with the command (AC_Sprayer::run)
    # below the minimum speed the 1 s shut-off delay holds
    dep2 = Deposition(cfg, bounds=(-5, -5, 5, 5))
    lit2 = [dep2.step(0.01, (0, 0, 3), (5.0 if k < 100 else 0.5, 0, 0), I9, HOVER_T,
                      (0, 0, 0), True) for k in range(250)]
    assert lit2[199] > 0.0 and lit2[200] == 0.0


def test_pressure_lag_volume_is_exact():
    tau, dt = 0.15, 0.01
    cfg = DepositionConfig(pressure_tau_s=tau, nozzle_on_delay_s=0.0)
    dep = Deposition(cfg, bounds=(-5, -5, 5, 5))
    n = 80
    total = sum(dep.step(dt, (0, 0, 3), (5, 0, 0), I9, HOVER_T, (0, 0, 0), True)
                for _ in range(n))
    qs = 1.0 * 6.0 * 5.0 * 1e-4
    t = n * dt
    assert total == pytest.approx(qs * (t - tau * (1 - math.exp(-t / tau))), rel=1e-12)


def test_metrics_on_synthetic_doses():
    cfg = DepositionConfig(cell_m=0.5, buffer_m=2.0, levels=1)
    g = GridSpec.around(SQUARE.bounds, cfg.buffer_m, cfg.cell_m, 1, 10 ** 7)
    ha = g.cell ** 2 * 1e-4
    xc = g.x0 + (np.arange(g.nx) + 0.5) * g.cell
    yc = g.y0 + (np.arange(g.ny) + 0.5) * g.cell
    xx, yy = np.meshgrid(xc, yc)
    inside = (xx > 0) & (xx < 40) & (yy > 0) & (yy < 30)
    lit = np.where(inside & (xx < 10), 0.5, 0.0) + np.where(inside & (xx >= 10), 1.0, 0.0)
    lit = lit + np.where(inside & (xx >= 35), 0.4, 0.0)          # 1.4 L/ha strip: over-dosed
    lit = lit * ha
    offgrid = 0.002
    lit[~inside] = 0.0
    lit[0, 0] = 0.003                                            # a deposit off the field
    sprayed = lit.sum() + offgrid + 0.001
    dm = DoseMap(g, lit, sprayed, offgrid, 0.001)
    m = dm.metrics(SQUARE, 1.0)
    rates = np.array([0.5] * 10 + [1.0] * 25 + [1.4] * 5)         # per metre of x, equal area
    assert m["dose_mean_l_per_ha"] == pytest.approx(rates.mean(), rel=1e-12)
    assert m["dose_cv"] == pytest.approx(rates.std() / rates.mean(), rel=1e-12)
    assert m["underdosed_fraction"] == pytest.approx(10 / 40)
    assert m["overdosed_fraction"] == pytest.approx(5 / 40)
    assert m["offtarget_deposit_fraction"] == pytest.approx((0.003 + offgrid) / sprayed)
    assert m["drift_fraction"] == pytest.approx(0.001 / sprayed)
    assert m["mass_balance_error"] == pytest.approx(0.0, abs=1e-12)


def test_holes_count_as_off_target():
    fld = Field.builtin("hole")
    dep = Deposition(DepositionConfig(cell_m=0.5, buffer_m=2.0), fld)
    mask = dep.dose_map().field_mask(fld)
    assert mask.sum() * 0.25 == pytest.approx(fld.area, rel=0.02)


def test_batch_rows_equal_single_vehicles_bitwise():
    cfg = DepositionConfig(buffer_m=4.0)
    rng = np.random.default_rng(3)
    n, ticks = 3, 400
    pos = rng.uniform([0, 0, 2], [40, 30, 4], (n, 3))
    vel = np.column_stack([rng.uniform(2, 6, n), rng.uniform(-1, 1, n), np.zeros(n)])
    wind = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-3, 3, n), np.zeros(n)])
    cmd = np.array([True, True, False])
    batch = DepositionBatch(cfg, SQUARE, n)
    singles = [Deposition(cfg, SQUARE) for _ in range(n)]
    R = np.tile(I9, (n, 1))
    for k in range(ticks):
        p = pos + vel * 0.01 * k
        c = cmd | (k > 200)
        out = batch.step(0.01, p, vel, R, np.full(n, HOVER_T), wind, c).copy()
        for i, s in enumerate(singles):
            assert s.step(0.01, p[i], vel[i], R[i], HOVER_T, wind[i], c[i]) == out[i]
    for i, s in enumerate(singles):
        assert np.array_equal(batch.dose_map(i).litres, s.dose_map().litres)


def test_pattern_cv_and_effective_swath_known_answers():
    y = np.arange(-20, 20, 0.25) + 0.125
    flat = np.where(np.abs(y) < 3.0, 1.0, 0.0)                 # a 6 m uniform stripe
    sp = np.arange(0.5, 12.01, 0.25)
    cv = cv_vs_spacing(y, flat, sp)
    assert cv[np.argmin(np.abs(sp - 6.0))] == pytest.approx(0.0, abs=1e-12)
    # at 8 m: 6 m of 1 and 2 m of 0 -> mean 0.75, std sqrt(0.75*0.25)
    assert cv[np.argmin(np.abs(sp - 8.0))] == pytest.approx(math.sqrt(0.1875) / 0.75)
    tri = np.maximum(0.0, 1.0 - np.abs(y) / 4.0)                  # triangle: flat at S = 4 m
    cvt = cv_vs_spacing(y, tri, sp)
    assert cvt[np.argmin(np.abs(sp - 4.0))] < 1e-12
    # widest S with CV <= 25 %: CV(6.25) = sqrt(.96*.04)/.96 = 0.204, CV(6.5) = 0.289
    assert effective_swath(sp, cv) == pytest.approx(6.25)


def test_pass_states_balance_weight_and_drag():
    R, T = pass_states(5.0, 3.0, 0.0, 6.47, 0.25, 0.18)
    z = np.asarray(R).reshape(3, 3)[:, 2]
    assert T * z[2] == pytest.approx(6.47 * 9.81)
    assert T * z[0] == pytest.approx((0.25 + 0.18 * 5.0) * 5.0)


def test_coarse_grid_when_over_max_cells():
    cfg = dataclasses.replace(DepositionConfig(), max_cells=10_000)
    dep = Deposition(cfg, SQUARE)
    assert dep.cell_m > cfg.cell_m and dep.grid.nx * dep.grid.ny <= 10_000


def test_the_pattern_figures_the_readme_states():
    """docs/spray_deposition.md: the M350-class quad's effective swath is 5.25 m at 2 m / 3 m/s
    calm, 3.25 m at 3 m / 5 m/s calm and 3.25 m with a 3 m/s crosswind (centroid +1.41 m); a
    100 µm droplet from 1 m in a 15 km/h wind drifts 16.8 m (OMAFRA: ≈ 16 m)."""
    from ag_uav.jobs.experiments.swath import droplet_anchor, swath_pattern
    from ag_uav.world.deposition import DepositionConfig

    dc = DepositionConfig()  # what `ag-uav experiment swath` flies by default
    rows, _ = swath_pattern(dc, [2.0], [3.0], [0.0])
    assert rows[0]["effective_swath_m"] == pytest.approx(5.25, abs=0.26)
    rows, _ = swath_pattern(dc, [3.0], [5.0], [0.0, 3.0])
    calm, cross = rows
    assert calm["effective_swath_m"] == pytest.approx(3.25, abs=0.26)
    assert cross["effective_swath_m"] == pytest.approx(3.25, abs=0.26)
    assert calm["centroid_m"] == pytest.approx(0.0, abs=0.05)
    assert cross["centroid_m"] == pytest.approx(1.41, abs=0.15)
    drift = {(r[0], r[1]): float(r[2]) for r in droplet_anchor(dc)}
    assert drift[("100 µm", "1 m")] == pytest.approx(16.8, abs=0.5)
