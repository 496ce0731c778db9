"""``ag-uav replay``: a flight the test writes itself (CSV layout, a known trajectory) replays to
its truth; clock lag and mounting are found; bad and truncated logs are one line and exit 2."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ag_uav.cli import main
from ag_uav.navigation.replay import ReplayOptions, read_log, run_replay, score_replay
from ag_uav.navigation.replay.align import clock_lag, mount_rotation
from ag_uav.navigation.replay.data import Track
from numkit.geometry import euler_to_rots, quats_to_rots, rots_to_euler, rots_to_quats

G = 9.81


def _truth(t: np.ndarray):
    """A figure-8 at ~4 m/s with rolling, pitching and yawing (all analytic)."""
    w = 2 * math.pi / 20.0
    p = np.stack([20 * np.sin(w * t), 10 * np.sin(2 * w * t), 5 + 0.5 * np.sin(w * t)], 1)
    a = np.stack([-20 * w**2 * np.sin(w * t), -40 * w**2 * np.sin(2 * w * t),
                  -0.5 * w**2 * np.sin(w * t)], 1)
    v = np.stack([20 * w * np.cos(w * t), 20 * w * np.cos(2 * w * t),
                  0.5 * w * np.cos(w * t)], 1)
    rpy = np.stack([0.08 * np.sin(1.3 * t), 0.06 * np.cos(0.9 * t), 0.4 * np.sin(0.3 * t)], 1)
    return p, v, a, rpy


def _rates(t: np.ndarray, h: float = 1e-5) -> np.ndarray:
    """Body rate ω = vee(Rᵀ Ṙ) by a central difference of the analytic attitude."""
    Rm = euler_to_rots(*_truth(t - h)[3].T)
    Rp = euler_to_rots(*_truth(t + h)[3].T)
    R = euler_to_rots(*_truth(t)[3].T)
    W = np.einsum("nji,njk->nik", R, (Rp - Rm) / (2 * h))
    return np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], 1)


def write_flight(folder, seed: int = 1, duration: float = 60.0, imu_hz: float = 100.0):
    """imu.csv, gnss.csv (5 Hz, σ 2 cm, velocity σ 5 cm/s) and reference.csv of the known
    trajectory; IMU white noise 0.05 m/s², 0.1 °/s and constant biases."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / imu_hz)
    p, v, a, rpy = _truth(t)
    R = euler_to_rots(*rpy.T)
    f = np.einsum("nji,nj->ni", R, a + np.array([0, 0, G]))
    w = _rates(t)
    f += 0.05 * rng.standard_normal(f.shape) + np.array([0.03, -0.02, 0.04])
    w += math.radians(0.1) * rng.standard_normal(w.shape) + math.radians(0.05)
    folder.mkdir(parents=True, exist_ok=True)
    np.savetxt(folder / "imu.csv", np.c_[t, f, w], delimiter=",", comments="",
               header="t,ax,ay,az,gx,gy,gz", fmt="%.9g")
    tg = np.arange(0.0, duration, 0.2)
    pg, vg, _, _ = _truth(tg)
    pg = pg + 0.02 * rng.standard_normal(pg.shape)
    vg = vg + 0.05 * rng.standard_normal(vg.shape)
    n = tg.size
    np.savetxt(folder / "gnss.csv", np.c_[tg, pg, np.full(n, 0.02), np.full(n, 0.03), vg,
                                          np.full(n, 0.05)],
               delimiter=",", comments="", header="t,e,n,u,h_acc,v_acc,ve,vn,vu,s_acc",
               fmt="%.9g")
    tr = np.arange(0.0, duration, 0.1)
    pr, _, _, rr = _truth(tr)
    np.savetxt(folder / "reference.csv", np.c_[tr, pr, np.degrees(rr)], delimiter=",",
               comments="", header="t,e,n,u,roll,pitch,yaw", fmt="%.9g")
    return folder


def test_a_synthetic_csv_flight_replays_to_its_truth(tmp_path):
    log = read_log(write_flight(tmp_path / "flight"))
    res = run_replay(log, ReplayOptions())
    s = score_replay(res)
    assert s["against"] == "reference"
    for rule, e in s["estimators"].items():
        # KF and MCKF follow the 2 cm fixes; the PCA rules' 10-fix window (2 s at 5 Hz) bends
        # a curved track by decimetres, which the gate and latch then hold (docs/replay.md)
        tol = 0.2 if rule.startswith("pca") else 0.03
        assert e["pos_h_rms_m"] < tol, (rule, e)
        assert e["tilt_rms_deg"] < 0.4, (rule, e)
        assert e["yaw_rms_deg"] < 1.0, (rule, e)
        assert e["vel_rms_mps"] < 0.1, (rule, e)
        assert 0.3 < e["nis_pos_mean"] < 10, (rule, e)
    assert s["estimators"]["kf"]["gate_rejected"] == 0
    # the flown rule's accelerometer bias is found (truth (0.03, -0.02, 0.04) m/s²)
    assert np.allclose(res.x[-1, 0, 10:13], [0.03, -0.02, 0.04], atol=0.03)


def test_a_gnss_gap_drifts_and_is_reported(tmp_path):
    log = read_log(write_flight(tmp_path / "flight"))
    res = run_replay(log, ReplayOptions(gnss_gap=(-1.0, 10.0)))
    e = score_replay(res)["estimators"]["pca-mckf"]
    assert res.gap is not None and abs(0.5 * sum(res.gap) - 0.5 * (res.t[0] + res.t[-1])) < 0.1
    assert e["gap_drift_m"] > e["gap_start_err_m"]
    assert e["gap_drift_m"] < 3.0   # bias-corrected INS over 10 s


def test_clock_lag_and_mounting_are_found():
    t = np.arange(0.0, 40.0, 1 / 120)
    _, _, a, rpy = _truth(t)
    R = euler_to_rots(*rpy.T)
    w = _rates(t)
    f = np.einsum("nji,nj->ni", R, a + np.array([0, 0, G]))
    M = euler_to_rots(np.array([0.02]), np.array([-0.03]), np.array([1.2]))[0]
    imu = np.c_[f @ M.T, w @ M.T]   # ω_imu = M ω_body
    tr = np.arange(0.0, 40.0, 0.1)
    ref = Track(tr, _truth(tr)[0], euler_to_rots(*_truth(tr)[3].T))
    lag, corr = clock_lag(t - 0.37, imu, ref)   # the IMU's clock reads 0.37 s early
    assert abs(lag - 0.37) < 0.02 and corr > 0.95
    Mf, res = mount_rotation(t - 0.37 + lag, imu, ref)
    assert np.allclose(rots_to_euler(Mf[None])[0], [0.02, -0.03, 1.2], atol=0.01)


def test_cli_writes_the_run_folder_and_the_table(tmp_path, capsys):
    folder = write_flight(tmp_path / "flight", duration=30.0)
    rc = main(["replay", str(folder), "--out", str(tmp_path / "runs"), "--run-id", "r"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "pca-mckf *" in out and "against reference" in out
    s = json.loads((tmp_path / "runs" / "r" / "summary.json").read_text())
    assert s["reference_pos_rms_m"] < 0.2 and s["reference_tilt_rms_deg"] < 0.4
    from mcap.reader import make_reader

    with open(tmp_path / "runs" / "r" / "run.mcap", "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert {"/replay/pca-mckf", "/replay/reference", "/replay/gnss"} <= topics


@pytest.mark.parametrize("kind", ["csv-cut", "ulog-cut", "bin-cut", "empty", "text"])
def test_a_bad_or_truncated_log_is_one_line_and_exit_2(tmp_path, capsys, kind):
    if kind == "csv-cut":
        folder = write_flight(tmp_path / "flight", duration=5.0)
        text = (folder / "imu.csv").read_text()
        (folder / "imu.csv").write_text(text[: len(text) // 2 - 7])   # cut inside a row
        path = folder
    else:
        path = tmp_path / {"ulog-cut": "x.ulg", "bin-cut": "x.BIN", "empty": "e.ulg",
                           "text": "t.BIN"}[kind]
        path.write_bytes({"ulog-cut": b"ULog\x01\x12\x35\x01" + b"\x00" * 9 + b"\x10\x00B",
                          "bin-cut": b"\xa3\x95\x80\x80\x59\x46\x4d\x54",
                          "empty": b"", "text": b"hello, not a log\n"}[kind])
    rc = main(["replay", str(path), "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert err.count("\n") == 0 and err.startswith("ag-uav replay: ") and "Traceback" not in err


# ---------------------------------------------------------------- autopilot logs written here
ORIGIN = (46.7250, -117.0200, 760.0)
_T = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])   # ENU <-> NED
_F = np.diag([1.0, -1.0, -1.0])                                        # FLU <-> FRD


def _flight_ned(duration: float, imu_hz: float, seed: int = 2):
    """The figure-8 as an autopilot logs it: IMU (FRD), fixes (lat, lon, alt, NED velocity)
    at 5 Hz and the truth as its estimate (NED position, FRD → NED attitude)."""
    from ag_uav.world.geodesy import enu_to_geodetic

    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / imu_hz)
    _, _, a, rpy = _truth(t)
    R = euler_to_rots(*rpy.T)
    f = np.einsum("nji,nj->ni", R, a + np.array([0, 0, G]))
    f += 0.05 * rng.standard_normal((t.size, 3))
    w = _rates(t) + math.radians(0.1) * rng.standard_normal((t.size, 3))
    tg = np.arange(1.0, duration, 0.2)
    pg, vg, _, _ = _truth(tg)
    noisy = pg + 0.03 * rng.standard_normal(pg.shape)
    lon, lat, h = enu_to_geodetic(noisy[:, 0], noisy[:, 1], ORIGIN, noisy[:, 2])
    te = np.arange(0.0, duration, 0.05)
    pe, ve, _, re = _truth(te)
    q = rots_to_quats(_T @ euler_to_rots(*re.T) @ _F)
    return {"t": t, "f": f @ _F, "w": w @ _F, "tg": tg, "lat": lat, "lon": lon, "alt": h,
            "vg": vg @ _T, "te": te, "pe": pe @ _T, "ve": ve @ _T, "q": q}


def _ulog_msg(kind: bytes, body: bytes) -> bytes:
    import struct

    return struct.pack("<HB", len(body), kind[0]) + body


def write_ulog(path, d: dict, cut: int | None = None, params: dict | None = None) -> None:
    """A ULog by hand (docs.px4.io, *ULog File Format*): header, flag bits, formats, subscriptions
    and data of sensor_combined, vehicle_gps_position (stamped 0.11 s after its epoch),
    vehicle_local_position and vehicle_attitude."""
    import struct

    fmts = [("sensor_combined",
             "uint64_t timestamp;float[3] gyro_rad;float[3] accelerometer_m_s2;"),
            ("vehicle_gps_position", "uint64_t timestamp;int32_t lat;int32_t lon;int32_t alt;"
             "float eph;float epv;float s_variance_m_s;float vel_n_m_s;float vel_e_m_s;"
             "float vel_d_m_s;uint8_t fix_type;"),
            ("vehicle_local_position", "uint64_t timestamp;float x;float y;float z;float vx;"
             "float vy;float vz;double ref_lat;double ref_lon;float ref_alt;"),
            ("vehicle_attitude", "uint64_t timestamp;float[4] q;")]
    out = b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0)
    out += _ulog_msg(b"B", bytes(40))
    for name, spec in fmts:
        out += _ulog_msg(b"F", f"{name}:{spec}".encode())
    for key, val in (params or {}).items():   # float parameters
        k = f"float {key}".encode()
        out += _ulog_msg(b"P", bytes((len(k),)) + k + struct.pack("<f", val))
    for i, (name, _) in enumerate(fmts):
        out += _ulog_msg(b"A", struct.pack("<BH", 0, i) + name.encode())
    rows = []
    us = lambda x: int(round(x * 1e6)) + 1_000_000  # noqa: E731
    for k in range(d["t"].size):
        rows.append((us(d["t"][k]), struct.pack("<HQ6f", 0, us(d["t"][k]), *d["w"][k], *d["f"][k])))
    for k in range(d["tg"].size):
        tn = us(d["tg"][k] + 0.11)
        rows.append((tn, struct.pack("<HQiiiffffffB", 1, tn, int(round(d["lat"][k] * 1e7)),
                                     int(round(d["lon"][k] * 1e7)), int(round(d["alt"][k] * 1e3)),
                                     0.05, 0.1, 0.05, *d["vg"][k], 3)))
    for k in range(d["te"].size):
        tn = us(d["te"][k])
        rows.append((tn, struct.pack("<HQ6fddf", 2, tn, *d["pe"][k], *d["ve"][k], ORIGIN[0],
                                     ORIGIN[1], ORIGIN[2])))
        rows.append((tn, struct.pack("<HQ4f", 3, tn, *d["q"][k])))
    for _, body in sorted(rows, key=lambda r: r[0]):
        out += _ulog_msg(b"D", body)
    path.write_bytes(out if cut is None else out[:cut])


def _df_fmt(typ: int, name: str, fmt: str, cols: str) -> bytes:
    import struct

    n = 3 + struct.calcsize("<" + fmt.replace("L", "i").replace("n", "4s").replace("C", "H"))
    return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", typ, n, name.encode(), fmt.encode(),
                                         cols.encode())


def write_dataflash(path, d: dict) -> None:
    """An ArduPilot DataFlash log by hand (FMT, then IMU, GPS stamped 0.22 s after its epoch,
    and EKF1 records); with ``d["gpa"]`` = (HAcc, VAcc, SAcc) a ``GPA`` record beside each fix
    from the ``d["gpa_from"]``-th on (ArduPilot ≥ 3.4: uint16 centimetres, 'C')."""
    import struct

    out = _df_fmt(129, "IMU", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
    out += _df_fmt(130, "GPS", "BIHLLffffffI",
                   "Status,TimeMS,Week,Lat,Lng,Alt,HDop,NSats,Spd,GCrs,VZ,T")
    out += _df_fmt(131, "EKF1", "Ifffffffff", "TimeMS,Roll,Pitch,Yaw,VN,VE,VD,PN,PE,PD")
    out += _df_fmt(132, "GPA", "QBCCCC", "TimeUS,I,VDop,HAcc,VAcc,SAcc")
    rows = []
    ms = lambda x: int(round(x * 1e3)) + 1000  # noqa: E731
    for k in range(d["t"].size):
        rows.append((ms(d["t"][k]), struct.pack("<BI6f", 129, ms(d["t"][k]), *d["w"][k],
                                                *d["f"][k])))
    for k in range(d["tg"].size):
        vn, ve, vd = d["vg"][k]
        crs = math.degrees(math.atan2(ve, vn)) % 360
        tn = ms(d["tg"][k] + 0.22)
        rows.append((tn, struct.pack("<BBIHiiffffffI", 130, 3, 400_000_000 + tn, 1817,
                                     int(round(d["lat"][k] * 1e7)),
                                     int(round(d["lon"][k] * 1e7)), d["alt"][k], 0.015, 12.0,
                                     math.hypot(vn, ve), crs, vd, tn)))
        if "gpa" in d and k >= d.get("gpa_from", 0):
            cm = [int(round(x * 100)) for x in d["gpa"]]
            rows.append((tn, struct.pack("<BQB4H", 132, tn * 1000, 0, 90, *cm)))
    for k in range(d["te"].size):
        R = quats_to_rots(d["q"][k][None])
        rpy = np.degrees(rots_to_euler(R)[0])
        rows.append((ms(d["te"][k]), struct.pack("<BI9f", 131, ms(d["te"][k]), *rpy,
                                                 *d["ve"][k], *d["pe"][k])))
    for _, body in sorted(rows, key=lambda r: r[0]):
        out += b"\xa3\x95" + body
    path.write_bytes(out)


@pytest.mark.parametrize("kind", ["ulog", "dataflash"])
def test_an_autopilot_log_written_here_replays_to_its_truth(tmp_path, kind):
    d = _flight_ned(40.0, 200.0 if kind == "ulog" else 100.0)
    path = tmp_path / ("f.ulg" if kind == "ulog" else "f.BIN")
    (write_ulog if kind == "ulog" else write_dataflash)(path, d)
    log = read_log(path)
    assert log.source == kind and log.autopilot is not None and log.origin is not None
    assert abs(log.gnss_delay_s - (0.11 if kind == "ulog" else 0.22)) < 1e-9
    res = run_replay(log, ReplayOptions())
    s = score_replay(res)
    assert s["against"] == "autopilot"
    kf = s["estimators"]["kf"]
    assert kf["pos_h_rms_m"] < 0.05, kf
    # DataFlash logs carry no velocity accuracy: the reader's 0.3 m/s (not the 0.05 m/s of the
    # ULog's s_variance) leaves the tilt less well observed
    assert kf["tilt_rms_deg"] < (0.4 if kind == "ulog" else 0.6), kf
    assert kf["yaw_rms_deg"] < 1.0, kf
    assert kf["gate_rejected"] == 0, kf


def test_a_ulog_cut_short_is_one_line_and_exit_2(tmp_path, capsys):
    d = _flight_ned(5.0, 200.0)
    path = tmp_path / "cut.ulg"
    write_ulog(path, d, cut=300)   # inside the definitions
    rc = main(["replay", str(path), "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and "cut.ulg" in err


def test_a_log_with_an_origin_puts_the_tracks_on_the_map(tmp_path, capsys):
    """The ULog's replay MCAP carries foxglove.LocationFix tracks (Map panel) of every rule,
    the autopilot and the fixes, decodable with the schema written beside them."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    path = tmp_path / "f.ulg"
    write_ulog(path, _flight_ned(12.0, 100.0))
    assert main(["replay", str(path), "--out", str(tmp_path / "runs"), "--run-id", "u"]) == 0
    assert "against the autopilot's estimate, PX4 EKF2" in capsys.readouterr().out
    with open(tmp_path / "runs" / "u" / "run.mcap", "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        seen: dict[str, object] = {}
        for schema, ch, _, msg in r.iter_decoded_messages(topics=["/geo/kf", "/geo/autopilot",
                                                                   "/geo/gnss"]):
            assert schema.name == "foxglove.LocationFix"
            seen.setdefault(ch.topic, msg)
    assert set(seen) == {"/geo/kf", "/geo/autopilot", "/geo/gnss"}
    fix = seen["/geo/autopilot"]
    assert abs(fix.latitude - ORIGIN[0]) < 1e-3 and abs(fix.longitude - ORIGIN[1]) < 1e-3


def test_a_ulog_gives_its_lever_arm_and_gnss_delay(tmp_path):
    path = tmp_path / "p.ulg"
    write_ulog(path, _flight_ned(3.0, 100.0),
               params={"EKF2_GPS_POS_X": 0.1, "EKF2_GPS_POS_Y": 0.05, "EKF2_GPS_POS_Z": -0.3,
                       "EKF2_IMU_POS_X": 0.02, "EKF2_IMU_POS_Y": 0.0, "EKF2_IMU_POS_Z": 0.0,
                       "EKF2_GPS_DELAY": 150.0})
    log = read_log(path)
    assert np.allclose(log.lever_arm, (0.08, -0.05, 0.3), atol=1e-6)   # FRD → FLU
    assert abs(log.gnss_delay_s - 0.15) < 1e-6


def test_dataflash_gpa_reported_accuracy_is_read(tmp_path):
    """ArduPilot ≥ 3.4 logs the receiver's HAcc, VAcc, SAcc in GPA beside each GPS record:
    the reader takes them as σ (HDop × UERE only for fixes without one), and the replay
    follows the truth."""
    d = _flight_ned(30.0, 100.0)
    d["gpa"], d["gpa_from"] = (0.03, 0.05, 0.04), 10
    path = tmp_path / "g.BIN"
    write_dataflash(path, d)
    log = read_log(path)
    n = log.gnss_t.size
    assert n == d["tg"].size
    # the first 10 fixes: HDop 0.015 × 2 m; the rest: the reported figures
    assert np.allclose(log.gnss_var[:10], [0.03**2, 0.03**2, 0.06**2], rtol=1e-6)
    assert np.allclose(log.gnss_var[10:], [0.03**2, 0.03**2, 0.05**2], rtol=1e-6)
    assert np.allclose(log.gnss_var_v[:10], 0.3**2) and np.allclose(log.gnss_var_v[10:], 0.04**2)
    assert any(f"GPA (HAcc, VAcc, SAcc as σ) on {n - 10} of {n}" in x for x in log.notes)
    assert any("not logged on 10 fixes" in x for x in log.notes)
    kf = score_replay(run_replay(log, ReplayOptions()))["estimators"]["kf"]
    assert kf["pos_h_rms_m"] < 0.05 and kf["tilt_rms_deg"] < 0.4, kf


def test_the_replay_flies_the_simulated_flights_ins_settings_unless_told(tmp_path, capsys):
    from ag_uav.config import load_config

    e = load_config(None).estimator
    folder = write_flight(tmp_path / "flight", duration=12.0)
    info = run_replay(read_log(folder), ReplayOptions()).info
    assert info["q_margins"] == [e.ins_q_accel, e.ins_q_gyro] and info["coning"] is True
    info = run_replay(read_log(folder), ReplayOptions(q_margins=(2.0, 32.0), coning=False)).info
    assert info["q_margins"] == [2.0, 32.0] and info["coning"] is False
    assert main(["replay", str(folder), "--q-margins", "1,0", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--q-margins" in err[0]


def test_a_velocity_differenced_from_a_reference_carries_its_error():
    """The built fix's velocity variance adds the RMS of (differenced speed − logged speed):
    a record whose logged speed is off by a known σ gives that σ; no logged speed gives 0."""
    from ag_uav.navigation.replay.runner import difference_sigma

    tr = np.arange(0.0, 30.0, 0.1)
    p, v, _, _ = _truth(tr)
    sp = np.hypot(v[:, 0], v[:, 1]) + 0.12 * np.random.default_rng(3).standard_normal(tr.size)
    t = np.arange(1.0, 29.0, 0.2)
    vt = _truth(t)[1]
    assert difference_sigma(Track(tr, p), t, vt) == 0.0
    assert abs(difference_sigma(Track(tr, p, speed=sp), t, vt) - 0.12) < 0.02
