"""Readers of recorded flights: a documented CSV folder, the Phantom 4 RTK set's path folder,
PX4 ULog (``pyulog``) and ArduPilot DataFlash (``pymavlink``); each returns a
:class:`~ag_uav.navigation.replay.data.FlightLog` in the INS's frames (body FLU, world ENU).

A file that cannot be used (missing, empty, cut short before any usable data, a field the reader
needs absent) raises :class:`~ag_uav.navigation.replay.data.ReplayError` with one line naming
the file and what is wrong.

**CSV folder** (``docs/replay.md`` documents it): ``imu.csv`` with columns ``t`` (s), ``ax,
ay, az`` (specific force, m/s², body FLU: +g on z at rest), ``gx, gy, gz`` (rad/s, FLU);
``gnss.csv`` with ``t`` and either ``lat, lon, alt`` (°, °, m) or ``e, n, u`` (m, local ENU),
the reported 1σ accuracy ``h_acc, v_acc`` (m) and optionally ``ve, vn, vu`` (m/s) with
``s_acc`` (m/s); optionally ``reference.csv`` with ``t, e, n, u`` (or ``lat, lon, alt``) and
optionally ``roll, pitch, yaw`` (°, ZYX, FLU → ENU).  Times on one clock.

**Phantom 4 RTK path folder** (Hurwitz & Klein 2023, CC-BY-4.0): ``IMU_avg.csv`` (or
``IMU_1.csv``): ``time`` s, Xsens DOT specific force m/s² and rate °/s in the sensor's own axes
(mounted at an unknown orientation); ``GT.csv``: the drone's RTK record at 10 Hz (North, East,
Down m; compass heading, pitch, roll °).  Its clock and the IMU's both start at 0 and its
mounting is unknown: :mod:`~ag_uav.navigation.replay.align` finds both.
"""

from __future__ import annotations

import contextlib
import csv
import io
from pathlib import Path

import numpy as np

from numkit.geometry import euler_to_rots, quats_to_rots

from ...world.geodesy import lonlat_to_enu
from .data import (
    DEG,
    IMU,
    FlightLog,
    ReplayError,
    Track,
    frd_to_flu,
    ned_frd_to_enu_flu,
)

__all__ = ["read_log", "read_csv_folder", "read_phantom", "read_ulog", "read_dataflash"]

#: the least IMU span (s) a replay runs on
MIN_IMU_S = 1.0


def read_log(path: str | Path, imu_file: str | None = None, uere_m: float | None = None
             ) -> FlightLog:
    """Any supported log, by what ``path`` is (module docstring); ``uere_m``: σ per unit HDOP
    for a DataFlash log's fixes (default :data:`UERE_M`)."""
    p = Path(path)
    if not p.exists():
        raise ReplayError(f"{p}: no such file or folder")
    if p.is_dir():
        if (p / "GT.csv").exists():
            return read_phantom(p, imu_file)
        if (p / "imu.csv").exists():
            return read_csv_folder(p)
        raise ReplayError(f"{p}: a folder must hold imu.csv + gnss.csv (the CSV layout) or "
                          "GT.csv + IMU_avg.csv / IMU_1.csv (a Phantom 4 RTK path)")
    if p.stat().st_size == 0:
        raise ReplayError(f"{p}: the file is empty")
    with open(p, "rb") as f:
        head = f.read(8)
    if head.startswith(b"ULog"):
        return read_ulog(p)
    if head.startswith(b"\xa3\x95"):
        return read_dataflash(p, UERE_M if uere_m is None else uere_m)
    raise ReplayError(f"{p}: not a PX4 ULog, an ArduPilot DataFlash .BIN or a log folder "
                      "(imu.csv + gnss.csv, or a Phantom 4 RTK path)")


# ------------------------------------------------------------------------------ CSV
def _table(path: Path, need: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """A CSV with a header row → {column (stripped): float array}; a short or non-numeric row,
    or a missing column, is a ReplayError naming the row or the column."""
    if not path.exists():
        raise ReplayError(f"{path}: no such file")
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        raise ReplayError(f"{path}: the file is empty")
    head = [h.strip() for h in rows[0]]
    body = [r for r in rows[1:] if r and any(c.strip() for c in r)]
    if not body:
        raise ReplayError(f"{path}: a header and no data rows")
    try:
        a = np.array([[float(c) for c in r] for r in body if len(r) == len(head)])
    except ValueError as e:
        raise ReplayError(f"{path}: a value that is not a number ({e})") from None
    if len(a) != len(body):
        bad = next(i for i, r in enumerate(body) if len(r) != len(head))
        raise ReplayError(f"{path}: row {bad + 2} has {len(body[bad])} fields, the header "
                          f"{len(head)} (the file is cut short or malformed)")
    out = {h: a[:, j] for j, h in enumerate(head)}
    miss = [c for c in need if c not in out]
    if miss:
        raise ReplayError(f"{path}: column {miss[0]!r} is missing (has: {', '.join(head)})")
    return out


def _enu_cols(path: Path, tb: dict[str, np.ndarray], origin) -> tuple[np.ndarray, tuple]:
    """ENU positions of a table with e, n, u or lat, lon, alt columns (the origin: the first
    row's, when it has none yet)."""
    if {"e", "n", "u"} <= tb.keys():
        return np.stack([tb["e"], tb["n"], tb["u"]], axis=1), origin
    if {"lat", "lon", "alt"} <= tb.keys():
        if origin is None:
            origin = (float(tb["lat"][0]), float(tb["lon"][0]), float(tb["alt"][0]))
        return lonlat_to_enu(tb["lon"], tb["lat"], origin, tb["alt"]), origin
    raise ReplayError(f"{path}: needs columns e, n, u or lat, lon, alt")


def _check_imu(path: Path, t: np.ndarray) -> float:
    """The IMU's nominal rate (Hz, median interval); ReplayError if too short or not
    increasing."""
    if t.size < 2 or t[-1] - t[0] < MIN_IMU_S:
        raise ReplayError(f"{path}: less than {MIN_IMU_S:g} s of IMU data ({t.size} samples): "
                          "the log is cut short or holds no IMU")
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0))
        raise ReplayError(f"{path}: IMU time does not increase at sample {i + 1} "
                          f"(t = {t[i]:.6g} then {t[i + 1]:.6g} s)")
    return 1.0 / float(np.median(d))


def read_csv_folder(folder: Path) -> FlightLog:
    imu = _table(folder / "imu.csv", ("t", "ax", "ay", "az", "gx", "gy", "gz"))
    gn = _table(folder / "gnss.csv", ("t", "h_acc", "v_acc"))
    t = imu["t"]
    rate = _check_imu(folder / "imu.csv", t)
    p, origin = _enu_cols(folder / "gnss.csv", gn, None)
    var = np.stack([gn["h_acc"] ** 2, gn["h_acc"] ** 2, gn["v_acc"] ** 2], axis=1)
    v = var_v = None
    if {"ve", "vn", "vu"} <= gn.keys():
        v = np.stack([gn["ve"], gn["vn"], gn["vu"]], axis=1)
        s = gn.get("s_acc", np.full(len(gn["t"]), 0.1))
        var_v = np.stack([s**2] * 3, axis=1)
    ref = None
    if (folder / "reference.csv").exists():
        rt = _table(folder / "reference.csv", ("t",))
        rp, origin = _enu_cols(folder / "reference.csv", rt, origin)
        R = None
        if {"roll", "pitch", "yaw"} <= rt.keys():
            R = euler_to_rots(rt["roll"] * DEG, rt["pitch"] * DEG, rt["yaw"] * DEG)
        ref = Track(rt["t"], rp, R, label="reference")
    f = np.stack([imu[k] for k in ("ax", "ay", "az", "gx", "gy", "gz")], axis=1)
    return FlightLog("csv", str(folder), t, f, gn["t"], p, var, v, var_v, origin, ref,
                     imu_rate_hz=rate)


# ------------------------------------------------------------------------------ Phantom 4 RTK
def read_phantom(folder: Path, imu_file: str | None = None) -> FlightLog:
    """A Phantom 4 RTK path folder (module docstring): the IMU in its sensor axes (the replay's
    alignment finds the mounting and the clock lag), the RTK record as the reference, no GNSS
    (built from the reference: ``--gnss-from-reference``)."""
    name = imu_file or ("IMU_avg.csv" if (folder / "IMU_avg.csv").exists() else "IMU_1.csv")
    imu = _table(folder / name, ("time", "Acc_X", "Acc_Y", "Acc_Z", "Gyr_X", "Gyr_Y", "Gyr_Z"))
    gt = _table(folder / "GT.csv", ("time", "North", "East", "Down", "compass_heading(degrees)",
                                    "pitch(degrees)", "roll(degrees)"))
    t, keep = np.unique(imu["time"], return_index=True)   # the files repeat a few stamps
    rate = _check_imu(folder / name, t)
    f = np.stack([imu["Acc_X"], imu["Acc_Y"], imu["Acc_Z"], imu["Gyr_X"] * DEG,
                  imu["Gyr_Y"] * DEG, imu["Gyr_Z"] * DEG], axis=1)[keep]
    p = np.stack([gt["East"], gt["North"], -gt["Down"]], axis=1)
    R_nf = euler_to_rots(gt["roll(degrees)"] * DEG, gt["pitch(degrees)"] * DEG,
                            gt["compass_heading(degrees)"] * DEG)
    ref = Track(gt["time"], p, ned_frd_to_enu_flu(R_nf), label="RTK reference (GT.csv)",
                speed=gt.get("speed(m/s)"))
    empty = np.zeros((0, 3))
    log = FlightLog("phantom", str(folder), t, f, np.zeros(0), empty, empty, None, None,
                    None, ref, imu_rate_hz=rate)
    log.notes.append(f"IMU {name} in the Xsens DOT's own axes: mounting found from the rates")
    return log


# ------------------------------------------------------------------------------ ULog
def _ulog_topic(u, names: tuple[str, ...]):
    for n in names:
        for d in u.data_list:
            if d.name == n and d.multi_id == 0 and len(d.data["timestamp"]):
                return d.data
    return None


def read_ulog(path: Path) -> FlightLog:
    """PX4 ULog: ``sensor_combined`` (FRD), ``vehicle_gps_position`` / ``sensor_gps`` (lat,
    lon, alt, eph, epv, NED velocity, s_variance_m_s), EKF2's ``vehicle_local_position`` and
    ``vehicle_attitude`` as the autopilot's estimate."""
    from pyulog import ULog

    try:
        with contextlib.redirect_stdout(io.StringIO()):   # pyulog prints its warnings
            u = ULog(str(path))
    except Exception as e:  # pyulog raises several kinds on a damaged file
        raise ReplayError(f"{path}: not a readable ULog ({type(e).__name__}: {e})".split("\n")[0]
                          ) from None
    sc = _ulog_topic(u, ("sensor_combined",))
    if sc is None:
        raise ReplayError(f"{path}: no sensor_combined (IMU) data: the log is cut short or "
                          "the topic was not logged")
    t = sc["timestamp"] * 1e-6
    f = np.stack([sc[f"accelerometer_m_s2[{i}]"] for i in range(3)]
                 + [sc[f"gyro_rad[{i}]"] for i in range(3)], axis=1).astype(float)
    acc, gyr = slice(IMU.ACC, IMU.ACC_END), slice(IMU.GYRO, IMU.GYRO_END)
    f[:, acc], f[:, gyr] = frd_to_flu(f[:, acc]), frd_to_flu(f[:, gyr])
    rate = _check_imu(path, t)
    log = FlightLog("ulog", str(path), t, f, np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)),
                    imu_rate_hz=rate, gnss_delay_s=0.11)
    g = _ulog_topic(u, ("vehicle_gps_position", "sensor_gps"))
    if g is not None:
        _ulog_gnss(log, g)
    if getattr(u, "file_corruption", False):
        log.notes.append("the file is damaged or cut short: replayed what pyulog could read")
    _ulog_ekf(log, u)
    _lever_from_params(log, u.initial_parameters, "EKF2_GPS_POS_", "EKF2_IMU_POS_")
    d = u.initial_parameters.get("EKF2_GPS_DELAY")
    if d is not None:
        log.gnss_delay_s = float(d) * 1e-3
        log.notes.append(f"GNSS delay {log.gnss_delay_s:g} s (the log's EKF2_GPS_DELAY; "
                         "--gnss-delay)")
    else:
        log.notes.append("GNSS delay 0.11 s (PX4 EKF2_GPS_DELAY default; --gnss-delay)")
    return log


def _lever_from_params(log: FlightLog, prm: dict, gps: str, imu: str) -> None:
    """The lever arm IMU → antenna from the autopilot's parameters (body FRD positions of
    the antenna and the IMU, ``<prefix>X/Y/Z``), where they are set."""
    ax = ("X", "Y", "Z")
    if not all(gps + a in prm for a in ax):
        return
    r = np.array([float(prm[gps + a]) - float(prm.get(imu + a, 0.0)) for a in ax])
    log.lever_arm = tuple(float(x) + 0.0 for x in frd_to_flu(r))
    log.notes.append(f"lever arm from the parameters {gps}X/Y/Z − {imu}X/Y/Z: "
                     f"{np.round(log.lever_arm, 3).tolist()} m (body FLU)")


def _ulog_gnss(log: FlightLog, g: dict) -> None:
    if "lat" in g:
        lat, lon = g["lat"] * 1e-7, g["lon"] * 1e-7
        alt = g["alt"] * 1e-3
    else:
        lat, lon, alt = g["latitude_deg"], g["longitude_deg"], g["altitude_msl_m"]
    ok = (g["fix_type"] >= 3) & (lat != 0)
    if not ok.any():
        log.notes.append("no 3-D GNSS fix in the log")
        return
    lat, lon, alt = lat[ok], lon[ok], alt[ok]
    log.origin = (float(lat[0]), float(lon[0]), float(alt[0]))
    log.gnss_t = g["timestamp"][ok] * 1e-6
    log.gnss_p = lonlat_to_enu(lon, lat, log.origin, alt)
    eph, epv = g["eph"][ok].astype(float), g["epv"][ok].astype(float)
    log.gnss_var = np.stack([eph**2, eph**2, epv**2], axis=1)
    log.gnss_v = np.stack([g["vel_e_m_s"][ok], g["vel_n_m_s"][ok], -g["vel_d_m_s"][ok]], axis=1)
    s = g["s_variance_m_s"][ok].astype(float)
    log.gnss_var_v = np.stack([np.maximum(s, 0.01) ** 2] * 3, axis=1)


def _ulog_ekf(log: FlightLog, u) -> None:
    lp = _ulog_topic(u, ("vehicle_local_position",))
    att = _ulog_topic(u, ("vehicle_attitude",))
    if lp is None:
        return
    t = lp["timestamp"] * 1e-6
    p = np.stack([lp["y"], lp["x"], -lp["z"]], axis=1).astype(float)
    v = np.stack([lp["vy"], lp["vx"], -lp["vz"]], axis=1).astype(float)
    if log.origin is not None and lp["ref_lat"][-1] != 0:
        off = lonlat_to_enu(lp["ref_lon"][-1], lp["ref_lat"][-1], log.origin, lp["ref_alt"][-1])
        p += off
    R = None
    if att is not None:
        q = np.stack([att[f"q[{i}]"] for i in range(4)], axis=1).astype(float)
        Ra = ned_frd_to_enu_flu(quats_to_rots(q))
        R = np.stack([np.interp(t, att["timestamp"] * 1e-6, Ra[:, i // 3, i % 3])
                      for i in range(9)], axis=1).reshape(-1, 3, 3)
    log.autopilot = Track(t, p, R, v, label="PX4 EKF2")


# ------------------------------------------------------------------------------ DataFlash
#: the per-axis horizontal σ per unit of HDOP (m) for logs without a reported accuracy
UERE_M = 2.0


def _df_messages(path: Path) -> dict[str, list[dict]]:
    from pymavlink import DFReader

    want = ("IMU", "GPS", "GPA", "EKF1", "AHRS2", "ATT", "PARM")
    out: dict[str, list[dict]] = {k: [] for k in want}
    # pymavlink prints each damaged message on standard output: kept off the terminal
    with contextlib.redirect_stdout(io.StringIO()):
        try:
            m = DFReader.DFReader_binary(str(path), zero_time_base=True)
        except Exception as e:
            raise ReplayError(f"{path}: not a readable DataFlash log ({type(e).__name__}: {e})"
                              .split("\n")[0]) from None
        while True:
            try:
                msg = m.recv_match(type=list(want))
            except Exception:  # a damaged message: what came before it is kept
                break
            if msg is None:
                break
            out[msg.get_type()].append(msg.to_dict())
    return out


def _df_t(rows: list[dict], keys=("TimeUS", "TimeMS")) -> np.ndarray:
    k = next((k for k in keys if k in rows[0]), None)
    if k is None:
        return np.zeros(0)
    return np.array([r[k] for r in rows], dtype=float) * (1e-6 if k == "TimeUS" else 1e-3)


def read_dataflash(path: Path, uere_m: float = 2.0) -> FlightLog:
    """ArduPilot DataFlash: ``IMU`` (FRD), ``GPS`` (Lat, Lng, Alt, HDop, Spd, GCrs, VZ) with
    the receiver's reported accuracy from ``GPA`` (HAcc, VAcc, SAcc, m and m/s; logged by
    ArduPilot since 3.4 beside each ``GPS`` record) where the log has it, else σ = HDop ×
    ``uere_m``; ``EKF1`` (or ``AHRS2`` / ``ATT``) as the autopilot's estimate."""
    msgs = _df_messages(path)
    imu = msgs["IMU"]
    if not imu:
        raise ReplayError(f"{path}: no IMU messages: the log is cut short or holds no IMU")
    t = _df_t(imu)
    t, idx = np.unique(t, return_index=True)
    f = np.array([[imu[i][k] for k in ("AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ")]
                  for i in idx], dtype=float)
    acc, gyr = slice(IMU.ACC, IMU.ACC_END), slice(IMU.GYRO, IMU.GYRO_END)
    f[:, acc], f[:, gyr] = frd_to_flu(f[:, acc]), frd_to_flu(f[:, gyr])
    rate = _check_imu(path, t)
    log = FlightLog("dataflash", str(path), t, f, np.zeros(0), np.zeros((0, 3)),
                    np.zeros((0, 3)), imu_rate_hz=rate, gnss_delay_s=0.22)
    log.notes.append("GNSS delay 0.22 s (ArduPilot EKF's GPS delay default; --gnss-delay)")
    _df_gnss(log, msgs, uere_m)
    _df_ekf(log, msgs)
    prm = {r["Name"]: r["Value"] for r in msgs["PARM"] if "Name" in r}
    _lever_from_params(log, prm, "GPS_POS1_", "INS_POS1_")
    return log


def _df_gnss(log: FlightLog, msgs: dict[str, list[dict]], uere_m: float) -> None:
    g = [r for r in msgs["GPS"] if r.get("Status", 0) >= 3 and r.get("Lat", 0) != 0]
    n_all = len(g)
    g = [r for r in g if r.get("HDop", 0) > 0]   # HDop 0: no accuracy, the fix is left out
    if len(g) < n_all:
        log.notes.append(f"{n_all - len(g)} 3-D fixes with HDop 0 (no accuracy) left out")
    if not g:
        log.notes.append("no 3-D GNSS fix in the log: the INS coasts on the IMU alone")
        return
    tg = _df_t(g, ("TimeUS", "T"))
    lat = np.array([r["Lat"] for r in g])
    lon = np.array([r["Lng"] for r in g])
    alt = np.array([r["Alt"] for r in g])
    log.origin = (float(lat[0]), float(lon[0]), float(alt[0]))
    log.gnss_t = tg
    log.gnss_p = lonlat_to_enu(lon, lat, log.origin, alt)
    hd = np.array([r.get("HDop", np.nan) for r in g], dtype=float)
    sh = hd * uere_m
    log.gnss_var = np.stack([sh**2, sh**2, (2 * sh) ** 2], axis=1)
    spd = np.array([r["Spd"] for r in g])
    crs = np.array([r["GCrs"] for r in g]) * DEG
    vz = np.array([r.get("VZ", 0.0) for r in g])
    log.gnss_v = np.stack([spd * np.sin(crs), spd * np.cos(crs), -vz], axis=1)
    log.gnss_var_v = np.full((len(g), 3), 0.3**2)
    n_gpa = _df_gpa(log, msgs["GPA"], g)
    if n_gpa < len(g):
        which = f" on {len(g) - n_gpa} fixes" if n_gpa else ""
        log.notes.append(f"GNSS accuracy not logged{which}: σ_e = σ_n = HDop × {uere_m:g} m "
                         "(--uere), σ_u = 2 σ_e; velocity σ 0.3 m/s")


def _df_gpa(log: FlightLog, gpa: list[dict], g: list[dict]) -> int:
    """The receiver's reported accuracy (``GPA``: HAcc, VAcc, SAcc; the first receiver's,
    ``I`` = 0) onto the fixes it was logged with (the nearest stamp within 0.1 s; HAcc > 0):
    σ_e = σ_n = HAcc, σ_u = VAcc, the velocity's σ = SAcc per axis (as PX4's eph, epv and
    s_variance are read).  Returns the number of fixes given a reported accuracy."""
    gpa = [r for r in gpa if r.get("I", 0) == 0 and r.get("HAcc", 0) > 0]
    if not gpa or not log.gnss_t.size:
        return 0
    ta, tg = _df_t(gpa, ("TimeUS",)), log.gnss_t   # both on the boot clock
    if ta.size < 2:
        return 0
    order = np.argsort(ta, kind="stable")
    gpa, ta = [gpa[i] for i in order], ta[order]
    j = np.clip(np.searchsorted(ta, tg), 1, ta.size - 1)
    j = np.where(np.abs(ta[j - 1] - tg) <= np.abs(ta[j] - tg), j - 1, j)
    ok = np.abs(ta[j] - tg) <= 0.1
    h = np.array([gpa[i]["HAcc"] for i in j], dtype=float)
    v = np.array([gpa[i].get("VAcc", 0.0) for i in j], dtype=float)
    sp = np.array([gpa[i].get("SAcc", 0.0) for i in j], dtype=float)
    v = np.where(v > 0, v, 2.0 * h)
    log.gnss_var[ok] = np.stack([h, h, v], axis=1)[ok] ** 2
    okv = ok & (sp > 0)
    log.gnss_var_v[okv] = (sp[okv, None] * np.ones(3)) ** 2
    n = int(ok.sum())
    if n:
        log.notes.append(f"GNSS accuracy from GPA (HAcc, VAcc, SAcc as σ) on {n} of "
                         f"{len(g)} fixes: HAcc median {np.median(h[ok]):.3g} m")
    return n


def _df_ekf(log: FlightLog, msgs: dict[str, list[dict]]) -> None:
    def live(rows: list[dict]) -> bool:   # EKF1 logs zeros before it starts (or for ever)
        return any(abs(r["Roll"]) + abs(r["Pitch"]) + abs(r["Yaw"]) > 0 for r in rows)

    kind = next((k for k in ("EKF1", "AHRS2", "ATT") if msgs[k] and live(msgs[k])), None)
    if kind is None:
        return
    rows = msgs[kind]
    t = _df_t(rows)
    eul = np.array([[r["Roll"], r["Pitch"], r["Yaw"]] for r in rows], dtype=float) * DEG
    R = ned_frd_to_enu_flu(euler_to_rots(*eul.T))
    p = np.full((len(rows), 3), np.nan)
    v = None
    if kind == "EKF1":
        p = np.array([[r["PE"], r["PN"], -r["PD"]] for r in rows], dtype=float)
        v = np.array([[r["VE"], r["VN"], -r["VD"]] for r in rows], dtype=float)
        if log.gnss_t.size:  # the EKF's origin is not logged: its offset to the first fix
            pe, _ = Track(t, p).at(log.gnss_t - log.gnss_delay_s)   # at the fixes' epochs
            d = log.gnss_p - pe
            off = np.nanmedian(d, axis=0)
            if np.all(np.isfinite(off)):
                p = p + off
                log.notes.append("ArduPilot EKF1's origin is not logged: its track is shifted "
                                 "by the median of (GNSS − EKF1), "
                                 f"({', '.join(f'{c:.2f}' for c in off)}) m ENU")
    ok = ~np.all(np.abs(eul) < 1e-12, axis=1)   # EKF1 logs zeros before it starts
    if not ok.any():
        return
    log.autopilot = Track(t[ok], p[ok], R[ok], None if v is None else v[ok],
                          label=f"ArduPilot {kind}")
