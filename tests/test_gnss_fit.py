"""Allan deviation, the GNSS noise fit and ``ag-uav gnss fit`` on logs the tests write
themselves (a user's clone has no ../shared)."""

from __future__ import annotations

import gzip
import math
import tomllib

import numpy as np
import pytest

from ag_uav.analysis.allan import (
    avar_gm,
    avar_gm_continuous,
    avar_rw,
    loglog_slope,
    octave_m,
    overlapping_avar,
    scatter_gm,
)
from ag_uav.analysis.gnss_fit import (
    fit_axis,
    fit_log,
    preset_components,
    preset_toml,
    simulate_stats,
)
from ag_uav.analysis.gnss_log import read_gnss_log, select_epochs
from ag_uav.cli import main
from ag_uav.vehicle.gps import GaussMarkov, GpsSensor, gps_preset, validate_overrides
from ag_uav.world.geodesy import enu_frame

ORIGIN = (53.2804, -9.0578, 66.8)


def _slope(y: np.ndarray) -> float:
    m = octave_m(y.size, max_frac=0.01)  # >= 100 clusters behind each value
    av, _ = overlapping_avar(y, m)
    return loglog_slope(m * 1.0, np.sqrt(av))


def test_white_noise_slope_minus_half():
    y = np.random.default_rng(1).standard_normal(1 << 15)
    assert _slope(y) == pytest.approx(-0.5, abs=0.05)


def test_random_walk_slope_plus_half():
    y = np.cumsum(np.random.default_rng(2).standard_normal(1 << 15))
    assert _slope(y) == pytest.approx(0.5, abs=0.07)


def test_random_walk_avar_exact_at_small_m():
    q = 0.3
    y = np.cumsum(q * np.random.default_rng(3).standard_normal(200_000))
    m = np.array([1, 2, 4])
    av, _ = overlapping_avar(y, m)
    np.testing.assert_allclose(av, avar_rw(q, m), rtol=0.03)


def test_gm_discrete_matches_continuous_and_the_generator():
    # the exact discrete form tends to IEEE 952's continuous one for tau0 << T
    tau = np.array([1.0, 4.0, 16.0, 64.0, 256.0])
    np.testing.assert_allclose(avar_gm(2.0, 30.0, tau / 0.01, 0.01),
                               avar_gm_continuous(2.0, 30.0, tau), rtol=2e-3)
    # and is what the product's Gauss-Markov generator shows
    gm = GaussMarkov(1.0, 10.0, 7)
    y = gm.sample(400_000, 1.0)
    m = np.array([1, 4, 16, 64])
    av, _ = overlapping_avar(y, m)
    np.testing.assert_allclose(av, avar_gm(1.0, 10.0, m, 1.0), rtol=0.06)
    # expected variance about the mean over a short record
    segs = y[:300_000].reshape(-1, 50)
    assert segs.var(axis=1).mean() == pytest.approx(scatter_gm(1.0, 10.0, 50, 1.0), rel=0.05)


def test_fit_recovers_gm_correlation_time():
    rng = np.random.default_rng(11)
    n, tc = 30_000, 40.0
    gm = GaussMarkov(0.05, tc, np.random.SeedSequence(5)).sample(n, 1.0)
    y = gm + 0.01 * rng.standard_normal(n)
    m = octave_m(n)
    av, _ = overlapping_avar(y, m)
    f = fit_axis("E", av, m, 1.0, n, float(y.var()), model="white+gm")
    assert f.gm_tau_s == pytest.approx(tc, rel=0.25)
    assert f.gm_sigma == pytest.approx(0.05, rel=0.15)
    assert f.white == pytest.approx(0.01, rel=0.25)
    assert f.rw_q == 0.0
    assert f.rms_log_err < 0.1


def _static_errors(n: int, seed: int) -> np.ndarray:
    """White 2 mm + GM 8 mm (tau 20 s) per axis, vertical x2: a static RTK-like receiver."""
    rng = np.random.default_rng(seed)
    gm = np.column_stack([GaussMarkov(0.008, 20.0, np.random.SeedSequence([seed, i]))
                          .sample(n, 1.0) for i in range(3)])
    e = gm + 0.002 * rng.standard_normal((n, 3))
    e[:, 2] *= 2.0
    return e


def _ecef(enu: np.ndarray) -> np.ndarray:
    rot, p0 = enu_frame(ORIGIN)
    return enu @ rot + p0


def _write_ubx_pvt(path, enu: np.ndarray, carr: list[int]) -> None:
    from pyubx2 import GET, UBXMessage

    from ag_uav.world.geodesy import ecef_to_geodetic

    lon, lat, h = ecef_to_geodetic(_ecef(enu))
    out = bytearray()
    for k in range(enu.shape[0]):
        out += b"$GPTXT,01,01,02,noise between frames*00\r\n" if k % 50 == 0 else b""
        out += UBXMessage("NAV", "NAV-PVT", GET, iTOW=100_000 + 1000 * k, fixType=3,
                          gnssFixOk=1, diffSoln=1, carrSoln=carr[k], lat=float(lat[k]),
                          lon=float(lon[k]), height=int(round(h[k] * 1000)), hAcc=14,
                          vAcc=20, numSV=18).serialize()
    path.write_bytes(bytes(out))


def test_ubx_nav_pvt_written_by_pyubx2_parses(tmp_path):
    n = 400
    enu = _static_errors(n, 3)
    carr = [2] * n
    carr[10:20] = [1] * 10  # RTK float for 10 epochs
    p = tmp_path / "static.ubx"
    _write_ubx_pvt(p, enu, carr)
    log = read_gnss_log(p)
    assert log.source == "UBX NAV-PVT"
    assert log.t.size == n and log.t[-1] == pytest.approx(n - 1.0)
    sel = select_epochs(log)
    assert sel.keep == ("rtk-fixed",)
    assert int(sel.mask.sum()) == n - 10
    assert "dropped 10" in sel.line and "10 rtk-float" in sel.line
    assert len(sel.segments) == 2  # the float epochs cut the series
    got = log.enu(sel.mask)
    want = enu[sel.mask] - enu[sel.mask].mean(axis=0)
    np.testing.assert_allclose(got, want, atol=7e-3)  # NAV-PVT lat/lon step 1e-7 deg ~ 1.1 cm
    assert log.h_acc[0] == pytest.approx(0.014) and log.v_acc[0] == pytest.approx(0.020)
    fit = fit_log(log, sel)
    assert fit.ratios["hAcc"] == pytest.approx(fit.stats["h_rms"] / 0.014, rel=1e-9)


def test_ubx_nav_sol_with_gga_quality_gz(tmp_path):
    from pynmeagps import NMEAMessage
    from pyubx2 import GET, UBXMessage

    n = 120
    enu = _static_errors(n, 4)
    xyz = _ecef(enu)
    out = bytearray()
    for k in range(n):
        itow = 45_018_000 + 1000 * k  # GPS time of week; UTC = GPS - 18 s
        sod = (itow / 1000 - 18) % 86400
        out += UBXMessage("NAV", "NAV-SOL", GET, iTOW=itow, gpsFix=3, gpsfixOK=1, diffSoln=1,
                          ecefX=int(round(xyz[k, 0] * 100)), ecefY=int(round(xyz[k, 1] * 100)),
                          ecefZ=int(round(xyz[k, 2] * 100)), pAcc=2).serialize()
        hh, mm, ss = int(sod // 3600), int(sod % 3600 // 60), sod % 60
        out += NMEAMessage("GN", "GGA", GET, time=f"{hh:02d}{mm:02d}{ss:05.2f}", lat=53.28,
                           NS="N", lon=9.05, EW="W", quality=4 if k >= 20 else 1, numSV=12,
                           HDOP=0.7, alt=11.8, altUnit="M", sep=56.0,
                           sepUnit="M").serialize()
    p = tmp_path / "rover.ubx.gz"
    p.write_bytes(gzip.compress(bytes(out)))
    log = read_gnss_log(p)
    assert "NAV-SOL" in log.source and "GPS-UTC 18 s" in log.source
    sel = select_epochs(log)
    assert sel.keep == ("rtk-fixed",) and int(sel.mask.sum()) == n - 20
    assert log.p_acc[0] == pytest.approx(0.02)
    got = log.enu(sel.mask)
    want = enu[20:] - enu[20:].mean(axis=0)
    np.testing.assert_allclose(got, want, atol=0.01)  # NAV-SOL is in whole centimetres


def test_nmea_gga_gst_log_parses(tmp_path):
    from pynmeagps import NMEAMessage
    from pyubx2 import GET

    from ag_uav.world.geodesy import ecef_to_geodetic

    n = 200
    enu = 50.0 * _static_errors(n, 8)  # decimetres: above NMEA's 1e-5 minute grid
    lon, lat, h = ecef_to_geodetic(_ecef(enu))
    out = bytearray()
    for k in range(n):
        sod = 43_200 + k
        tm = f"{sod // 3600:02d}{sod % 3600 // 60:02d}{sod % 60:02d}.00"
        out += NMEAMessage("GP", "GGA", GET, time=tm, lat=float(lat[k]), NS="N",
                           lon=float(lon[k]), EW="W", quality=2, numSV=9, HDOP=0.9,
                           alt=round(float(h[k]) - 56.0, 3), altUnit="M", sep=56.0,
                           sepUnit="M").serialize()
        out += NMEAMessage("GP", "GST", GET, time=tm, rangeRms=1.0, stdMajor=0.5,
                           stdMinor=0.4, orient=0.0, stdLat=0.3, stdLong=0.4,
                           stdAlt=0.9).serialize()
    p = tmp_path / "fixes.nmea"
    p.write_bytes(bytes(out))
    log = read_gnss_log(p)
    assert log.source == "NMEA GGA + GST"
    sel = select_epochs(log)
    assert sel.keep == ("dgps",) and int(sel.mask.sum()) == n
    assert log.h_acc[0] == pytest.approx(0.5) and log.v_acc[0] == pytest.approx(0.9)
    got = log.enu(sel.mask)
    want = enu - enu.mean(axis=0)
    np.testing.assert_allclose(got[:, :2], want[:, :2], atol=0.02)
    np.testing.assert_allclose(got[:, 2], want[:, 2], atol=0.06)


def test_constant_positions_one_line_exit_2(tmp_path, capsys):
    p = tmp_path / "still.csv"
    p.write_text("time_s,e_m,n_m,u_m\n" + "".join(f"{k},1.0,2.0,3.0\n" for k in range(64)))
    assert "does not vary" in _one_line_exit2(capsys, ["gnss", "fit", str(p)])


def test_csv_and_preset_block_round_trip(tmp_path):
    n = 3000
    enu = _static_errors(n, 5)
    p = tmp_path / "fixes.csv"
    rows = ["# a static receiver", "time_s,e_m,n_m,u_m,fix,h_acc_m,v_acc_m"]
    rows += [f"{k:.1f},{e:.5f},{nn:.5f},{u:.5f},rtk-fixed,0.01,0.02"
             for k, (e, nn, u) in enumerate(enu)]
    p.write_text("\n".join(rows) + "\n")
    log = read_gnss_log(p)
    fit = fit_log(log, select_epochs(log))
    h = fit.axes["H"]
    total = math.sqrt(h.white**2 + h.gm_sigma**2)
    assert total == pytest.approx(math.hypot(0.008, 0.002), rel=0.25)
    assert 8.0 <= h.gm_tau_s <= 50.0
    cfg = preset_components(fit)
    GpsSensor.from_config(cfg, 0)
    block = tomllib.loads(preset_toml(fit, "mine"))
    assert block["gps"]["preset"] == "perfect"
    validate_overrides("perfect", block["gps"]["overrides"])
    # the product's generator on the fitted preset shows the log's scatter (RMS over seeds)
    sims = simulate_stats(cfg, fit.n, fit.dt, range(8))
    rms = math.sqrt(np.mean([s["h_rms"] ** 2 for s in sims]))
    assert rms == pytest.approx(fit.stats["h_rms"], rel=0.3)


# Figures of the two u-blox M8P logs (jdesbonnet/GNSS_RTK_data) as `ag-uav gnss fit` measures
# them (docs/gnss.md): epochs kept, horizontal RMS about the mean (m), horizontal Allan
# deviation at 60 s (m).
M8P_LOGS = {"m8p-rtk-static": (1121, 0.009963, 0.00236),
            "m8p-standalone": (2555, 2.455, 0.3842)}


@pytest.mark.parametrize("name", sorted(M8P_LOGS))
def test_m8p_presets_reproduce_their_logs(name):
    n, h_rms, adev60 = M8P_LOGS[name]
    sims = simulate_stats(gps_preset(name), n, 1.0, range(20))
    for key, want in (("h_rms", h_rms), ("adev60_h", adev60)):
        rms = math.sqrt(np.mean([s[key] ** 2 for s in sims]))
        assert rms == pytest.approx(want, rel=0.3), key


def test_cli_gnss_fit_prints_table_and_writes_files(tmp_path, capsys):
    enu = _static_errors(600, 6)
    p = tmp_path / "f.csv"
    p.write_text("time_s,e_m,n_m,u_m\n" + "\n".join(
        f"{k},{e:.5f},{nn:.5f},{u:.5f}" for k, (e, nn, u) in enumerate(enu)) + "\n")
    assert main(["gnss", "fit", str(p), "--out", str(tmp_path), "--seeds", "3"]) == 0
    out = capsys.readouterr().out
    assert "Allan deviation (m), measured / model" in out
    assert "gm_tau_s" in out and "[gps.overrides]" in out
    assert "kept 600 of 600 epochs (3d)" in out
    assert (tmp_path / "f-allan.png").stat().st_size > 1000
    tomllib.loads((tmp_path / "f-preset.toml").read_text())


def test_cli_choices_match_the_library():
    from ag_uav.analysis.gnss_fit import MODELS
    from ag_uav.analysis.gnss_log import KEEP_SETS
    from ag_uav.cli import gnss

    assert gnss.MODEL_CHOICES == MODELS
    assert set(gnss.FIX_CHOICES) == {"auto", *KEEP_SETS}


def _one_line_exit2(capsys, args) -> str:
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err
    return err


def test_cli_bad_logs_one_line_exit_2(tmp_path, capsys):
    junk = tmp_path / "junk.bin"
    junk.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    assert "not a UBX, NMEA or CSV" in _one_line_exit2(capsys, ["gnss", "fit", str(junk)])
    junk.write_bytes(b"\xb5\x62" + junk.read_bytes())  # sync bytes, then garbage
    assert "no NAV-PVT, NAV-SOL or GGA" in _one_line_exit2(capsys, ["gnss", "fit", str(junk)])
    enu = _static_errors(300, 7)
    good = tmp_path / "good.ubx"
    _write_ubx_pvt(good, enu, [2] * 300)
    cut = tmp_path / "cut.ubx.gz"
    cut.write_bytes(gzip.compress(good.read_bytes())[:-400])
    assert "gzip" in _one_line_exit2(capsys, ["gnss", "fit", str(cut)])
    short = tmp_path / "short.ubx"
    short.write_bytes(good.read_bytes()[:100 * 8 + 10])
    assert "needed" in _one_line_exit2(capsys, ["gnss", "fit", str(short)])
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,e_m,n_m,u_m\n0,1,2,x\n")
    assert "u_m = 'x'" in _one_line_exit2(capsys, ["gnss", "fit", str(bad)])
    assert "no such file" in _one_line_exit2(capsys, ["gnss", "fit", str(tmp_path / "no")])
    assert "--compare" in _one_line_exit2(capsys, ["gnss", "fit", str(good), "--compare",
                                                   "nope"])
