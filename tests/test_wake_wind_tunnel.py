"""The multirotor wake from its geometry (ag_uav.world.wake) and the wind-tunnel experiment
(ag_uav.jobs.experiments.wind_tunnel) against the measured trial of Grant et al. 2022."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ag_uav.world.deposition import Deposition, DepositionConfig
from ag_uav.world.wake import JET_B, MultirotorWake, centreline_speed, fall_time


def test_merged_jet_centreline_is_the_round_jet_formula_at_three_depths():
    w = MultirotorWake(mass_kg=6.47, n_rotors=4, rotor_d_m=0.533, arm_m=0.4475)
    vh = math.sqrt(6.47 * 9.81 / (2 * 1.225 * 4 * math.pi * 0.533 ** 2 / 4))
    u0 = 2.0 * vh
    d0 = math.sqrt(4) * 0.533 / math.sqrt(2.0)           # D_eq / √2 of the whole vehicle
    # the merged jet carries the whole thrust as its momentum flux
    assert 1.225 * u0 ** 2 * math.pi * d0 ** 2 / 4 == pytest.approx(6.47 * 9.81)
    s_r = JET_B * 0.533 / math.sqrt(2.0)
    s_m = 2.5 * 2 * 0.4475
    u_m = u0 if s_m < s_r else u0 * s_r / s_m            # continuity at the merge depth
    z0 = s_m - JET_B * u0 * d0 / u_m
    for z in (3.0, 5.0, 8.0):
        assert z > s_m
        assert w.centreline(z) == pytest.approx(JET_B * u0 * d0 / (z - z0), rel=1e-9)
    # far below it decays √n times slower than one rotor's own jet would
    far = 200.0
    assert w.centreline(far) / (u0 * s_r / far) == pytest.approx(2.0, rel=0.05)
    assert w.centreline(0.5) == pytest.approx(u0)        # the cores
    assert max(w.centreline(z) for z in np.linspace(0.1, 20, 200)) <= u0 + 1e-12


def test_fall_time_through_the_merged_jet_matches_integration():
    a, s_r, s_m, bd0, vt = 10.0, 1.0, 2.0, 4.0, 0.8
    s1, s2 = 0.2, 6.0
    n = 200_000
    s = np.linspace(s1, s2, n + 1)
    u = np.array([centreline_speed(a, s_r, s_m, bd0, x) for x in s])
    dt = np.diff(s) / (vt + 0.5 * (u[1:] + u[:-1]))
    assert fall_time(vt, a, s_r, s_m, bd0, s1, s2) == pytest.approx(dt.sum(), rel=1e-6)


def test_the_wake_skews_and_weakens_in_wind():
    w = MultirotorWake(mass_kg=15.8, n_rotors=8, rotor_d_m=0.533, arm_m=0.75)
    calm, windy = w.centreline(6.0), w.centreline(6.0, airspeed=4.5)
    assert windy < calm                                    # lengths shrink with cos χ
    assert w.v_induced(airspeed=4.5) < w.v_induced()


WALL_JET = {"jet_merge_lengths": 2.5, "outwash_impaction_st50": 0.24, "wall_jet_growth": 0.098}
#: the hover law checked on the tunnel: the wall jet, the impingement region, ε₀ from the tunnel
TUNNEL = {**WALL_JET, "impingement_diameters": 1.2, "wake_escape": 0.6}


def test_the_hover_law_is_the_one_documented():
    from ag_uav.world.deposition_config import HOVER_LAW, LAWS

    assert HOVER_LAW == TUNNEL and LAWS["hover"] is HOVER_LAW and LAWS["default"] == {}
    assert DepositionConfig(**HOVER_LAW).wall_jet_growth == 0.098


@pytest.mark.parametrize("opts", [{}, {"jet_merge_lengths": 2.5, "outwash_impaction_st50": 0.24},
                                  WALL_JET, TUNNEL])
def test_mass_balance_closes_with_the_wake_options(opts):
    from ag_uav.world.field import Field

    fld = Field.from_coords([(0, 0), (40, 0), (40, 30), (0, 30)])
    cfg = dataclasses.replace(DepositionConfig(), **opts)
    dep = Deposition(cfg, fld)
    R = np.eye(3).ravel()
    for i in range(300):
        dep.step(0.02, np.array([5.0 + 5 * 0.02 * i, 15.0, 4.0]), np.array([5.0, 0.0, 0.0]), R,
                 63.5, np.array([0.0, 3.0, 0.0]), True)
    m = dep.metrics()
    assert m["sprayed_l"] > 0
    assert abs(m["mass_balance_error"]) < 1e-12


def test_wind_tunnel_one_condition_against_the_measured_trial():
    from ag_uav.jobs.experiments import wind_tunnel as wt

    measured = wt.read_measured(None)
    assert len(measured) == 9                               # 3 winds x 3 nozzles, 2 L
    rows, summ = wt.compare(DepositionConfig(), wt.Trial(), measured, [3.0], ["medium"], [2.0])
    assert len(rows) == 14 and len(summ) == 1
    s = summ[0]
    assert sum(r["model_norm"] for r in rows) == pytest.approx(1.0)
    assert sum(r["measured_norm"] for r in rows) == pytest.approx(1.0)
    # the measured figures: 9.5 % of the deposit at >= 2 m, the peak 1 m downwind
    assert s["downwind_measured"] == pytest.approx(0.095, abs=0.001)
    assert s["downwind_reps_lo"] <= s["downwind_measured"] <= s["downwind_reps_hi"]
    assert s["downwind_reps_lo"] < s["downwind_reps_hi"]   # the replicates' own spread
    assert s["peak_measured_m"] == 1.0
    assert 0.25 < s["ratio"] < 4.0
    assert abs(s["peak_model_m"] - s["peak_measured_m"]) <= 1.0
    up = [r["model_norm"] for r in rows if r["distance_m"] <= -2.0]
    assert sum(up) < 0.1                                    # little lands 2-3 m upwind


def test_wind_tunnel_bad_nozzle_is_a_one_line_error(capsys, tmp_path):
    from ag_uav.cli import main

    rc = main(["experiment", "wind-tunnel", "--nozzles", "foggy", "--out", str(tmp_path)])
    assert rc == 2
    assert "--nozzles = 'foggy'" in capsys.readouterr().out


def test_wind_tunnel_reads_another_payloads_rows(tmp_path):
    """--measured with rows of another payload (here the 2 L figures relabelled 10 L, one
    condition) runs and writes the same table; the 10 L rotor-on spectrum is used."""
    from importlib import resources

    from ag_uav.cli import main

    text = resources.files("ag_uav.data").joinpath(
        "grant2022_deposition_slides_2L.csv").read_text().splitlines()
    keep = [text[0]] + [ln for ln in text[1:] if ",TT11001 (medium),2,3," in ln]
    assert len(keep) == 1 + 14 * 3
    f = tmp_path / "ten.csv"
    f.write_text("\n".join(ln.replace(",TT11001 (medium),2,", ",TT11001 (medium),10,")
                           for ln in keep) + "\n")
    out = tmp_path / "out"
    assert main(["experiment", "wind-tunnel", "--measured", str(f), "--out", str(out)]) == 0
    md = (out / "wind_tunnel.md").read_text()
    assert "| 3 | medium | 10 |" in md
    assert (out / "wind_tunnel.csv").read_text().count("\n") == 15


def test_wall_jet_travel_is_the_settling_law():
    from ag_uav.world.deposition_kernels import wall_jet

    beta, r_j, u_g = 0.098, 0.75, 12.0
    for vt, tp in ((0.1, 0.01), (0.5, 0.05), (2.0, 0.2)):
        ride, dj, var = wall_jet(beta, r_j, 0.24, tp, vt, u_g)
        st_g = tp * u_g / r_j
        assert ride == pytest.approx(0.24 ** 2 / (st_g ** 2 + 0.24 ** 2))
        assert dj == pytest.approx(beta * r_j)
        # integrate dr/dt = u_g r_j / r for the settling time δ_j / v_t
        r, dt = r_j, 1e-4
        for _ in range(int(dj / vt / dt)):
            r += u_g * r_j / r * dt
        assert math.sqrt(2.0 * var) == pytest.approx(r - r_j, rel=2e-3)
    # without impaction everything rides
    assert wall_jet(beta, r_j, 0.0, 0.2, 2.0, u_g)[0] == 1.0


def test_wall_jet_narrows_the_hover_outwash_of_fines():
    from ag_uav.world.deposition import footprints, pack_input

    cfg = DepositionConfig(dv10_um=83.0, dv50_um=148.0, dv90_um=229.0)
    inp = pack_input([0.0, 0.0, 2.3], [0.0, 0.0, 0.0], np.eye(3).ravel(), 63.5,
                     [1.5, 0.0, 0.0], 1)
    layer = footprints(cfg, inp)
    wj = footprints(dataclasses.replace(cfg, **WALL_JET), inp)
    fine = int(np.argmax(layer["d_m"] > 60e-6))
    assert np.sqrt(wj["wvar"][fine]) < 0.5 * np.sqrt(layer["wvar"][fine])
    assert np.all(wj["wvar"] <= layer["wvar"] + 1e-12)


def test_wind_tunnel_fine_low_wind_with_the_wall_jet():
    """One condition at one wind (1.5 m/s, fine): the layer law puts 4.5 x the measured share
    at >= 2 m; the wall jet brings it within a factor 2."""
    from ag_uav.jobs.experiments import wind_tunnel as wt

    measured = wt.read_measured(None)
    args = (wt.Trial(), measured, [1.5], ["fine"], [2.0])
    _, base = wt.compare(DepositionConfig(), *args)
    _, wj = wt.compare(DepositionConfig(**WALL_JET), *args)
    assert base[0]["ratio"] > 2.0
    assert 0.5 <= wj[0]["ratio"] <= 2.0
    assert wj[0]["median_abs_log10_2_20m"] < base[0]["median_abs_log10_2_20m"]


def test_impinging_fall_time_matches_integration():
    from ag_uav.world.deposition_kernels import impinging_fall_time

    a, s_r, s_m, bd0 = 12.0, 2.26, 3.75, 6.0 * 1.07
    for vt, h_i, s1, s2 in ((0.2, 1.28, 0.4, 2.4), (1.3, 1.28, 0.4, 2.4), (2.0, 0.9, 1.8, 2.4)):
        u_i = centreline_speed(a, s_r, s_m, bd0, s2 - h_i)
        s, t, dt = s1, 0.0, 1e-5
        while s < s2 - 1e-9:                  # depth s; in the region w = u_i (s2 - s) / h_i
            u = centreline_speed(a, s_r, s_m, bd0, s) if s < s2 - h_i else u_i * (s2 - s) / h_i
            s += (vt + u) * dt
            t += dt
        assert impinging_fall_time(vt, a, s_r, s_m, bd0, s1, s2, h_i) == pytest.approx(t, rel=2e-3)
    # no region: the free jet's fall time
    assert impinging_fall_time(1.0, a, s_r, s_m, bd0, 0.4, 2.4, 1e-9) == pytest.approx(
        fall_time(1.0, a, s_r, s_m, bd0, 0.4, 2.4), rel=1e-6)


def test_wind_tunnel_medium_high_wind_with_the_hover_law():
    """One condition at one wind (4.5 m/s, medium): with the impingement region the in-swath
    peak sits 1 m downwind as measured and the downwind share is within a factor 2."""
    from ag_uav.jobs.experiments import wind_tunnel as wt

    args = (wt.Trial(), wt.read_measured(None), [4.5], ["medium"], [2.0])
    _, wj = wt.compare(DepositionConfig(**{**TUNNEL, "impingement_diameters": 0.0}), *args)
    _, hov = wt.compare(DepositionConfig(**TUNNEL), *args)
    assert wj[0]["ratio"] < 0.5                             # the free jet: too little shift
    assert 0.5 <= hov[0]["ratio"] <= 2.0
    assert hov[0]["peak_model_m"] == hov[0]["peak_measured_m"] == 1.0


def test_wind_tunnel_cli_runs_the_hover_law(tmp_path):
    from ag_uav.cli import main

    rc = main(["experiment", "wind-tunnel", "--law", "hover", "--winds", "4.5", "--nozzles",
               "medium", "--out", str(tmp_path)])
    assert rc == 0
    md = (tmp_path / "wind_tunnel.md").read_text()
    assert "1 of 1" in md and "+1 m, +1 m" in md          # within 2 x; the peak as measured
