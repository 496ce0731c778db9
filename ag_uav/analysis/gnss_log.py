"""Reading a GNSS receiver's log of fixes: u-blox UBX (``pyubx2``), NMEA 0183, or a CSV of
fixes; any of them gzip-compressed (``.gz``).

What is read, per epoch: time, position, the solution type (:data:`FIX_CLASSES`) and the
accuracy the receiver reported.

* UBX: ``NAV-PVT`` when the log has it (lat/lon/height, ``fixType``, ``gnssFixOK``,
  ``diffSoln``, ``carrSoln`` 1 = RTK float / 2 = RTK fixed, ``hAcc``, ``vAcc``); otherwise
  ``NAV-SOL`` (ECEF position in cm, ``gpsFix``, ``gpsfixOK``, ``diffSoln``, 3-D ``pAcc``).
  ``NAV-SOL`` cannot tell an RTK solution from a code-differential one: when the log also
  carries NMEA ``GGA`` (u-blox receivers interleave them), each epoch takes GGA's quality
  (4 = RTK fixed, 5 = RTK float, 2 = DGPS, 1 = autonomous), matched on the time of day; the
  GPS − UTC offset (leap seconds) is the most frequent difference between a GGA's UTC time and
  the ``iTOW`` of the ``NAV-SOL`` before it.  u-blox interface description (UBX-13003221,
  u-blox 8 / M8 receiver description, sections UBX-NAV-PVT and UBX-NAV-SOL).
* NMEA: ``GGA`` (lat, lon, altitude + geoid separation = ellipsoidal height, quality) with
  ``GST`` (1-σ latitude / longitude / altitude error) as the reported accuracy when present.
* CSV (comma-separated, one header row naming the columns, ``#`` comment lines allowed):
  ``time_s`` and either ``lat_deg, lon_deg, height_m`` (WGS-84) or ``e_m, n_m, u_m`` (a local
  frame in metres); optional ``fix`` (a class name of :data:`FIX_CLASSES` or a GGA quality
  digit 0–6), ``h_acc_m``, ``v_acc_m``, ``p_acc_m`` (reported accuracies).

Anything that cannot be read (not a log, a gzip stream cut short, a bad value, no fixes) raises
:class:`GnssLogError` with one line naming the file and what was wrong.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import zlib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..world.geodesy import ecef_to_geodetic, enu_frame, geodetic_to_ecef

__all__ = ["FIX_CLASSES", "KEEP_SETS", "GnssLog", "GnssLogError", "Selection", "read_gnss_log",
           "select_epochs"]

#: solution types, worst to best
FIX_CLASSES = ("none", "time-only", "2d", "3d", "dgps", "rtk-float", "rtk-fixed")
_GGA_Q = {0: "none", 1: "3d", 2: "dgps", 3: "3d", 4: "rtk-fixed", 5: "rtk-float", 6: "none"}
#: ``--fix`` choices: the classes each keeps
KEEP_SETS = {
    "rtk-fixed": ("rtk-fixed",),
    "rtk": ("rtk-fixed", "rtk-float"),
    "differential": ("dgps", "rtk-float", "rtk-fixed"),
    "3d": ("3d",),
}


class GnssLogError(ValueError):
    """The log cannot be used (one line naming the file and the fault)."""


@dataclass
class GnssLog:
    """Epochs of a log: ``t`` (s from the first epoch), ``pos`` (n, 3) in ``frame`` ("ecef",
    or "enu" for a CSV in local metres), ``fix`` (n,) class names, reported accuracies
    ``h_acc``, ``v_acc``, ``p_acc`` (m, NaN where the log gives none) and ``source`` (which
    messages or columns were read)."""

    path: str
    source: str
    t: np.ndarray
    pos: np.ndarray
    frame: str
    fix: np.ndarray
    h_acc: np.ndarray
    v_acc: np.ndarray
    p_acc: np.ndarray

    def enu(self, mask: np.ndarray) -> np.ndarray:
        """East, north, up (m) of the ``mask`` epochs about their mean position (a local
        tangent plane at the mean: WGS-84 ECEF → ENU, :mod:`ag_uav.world.geodesy`)."""
        p = self.pos[mask]
        if self.frame == "enu":
            return p - p.mean(axis=0)
        mean = p.mean(axis=0)
        lon, lat, h = ecef_to_geodetic(mean[None, :])
        rot, p0 = enu_frame((float(lat[0]), float(lon[0]), float(h[0])))
        return (p - p0) @ rot.T


def _read_bytes(path: Path) -> bytes:
    raw = path.read_bytes()
    if raw[:2] == b"\x1f\x8b":
        try:
            raw = gzip.decompress(raw)
        except (EOFError, OSError, zlib.error) as e:
            raise GnssLogError(f"{path}: gzip stream unreadable ({e})") from None
    if not raw:
        raise GnssLogError(f"{path}: empty file, no GNSS fixes")
    return raw


def read_gnss_log(path: str | Path) -> GnssLog:
    """Read a UBX, NMEA or CSV log (see module docstring); ``.gz`` is decompressed."""
    p = Path(path)
    if not p.is_file():
        raise GnssLogError(f"{p}: no such file")
    raw = _read_bytes(p)
    head = raw[:65536]
    if b"\xb5\x62" in head or head.lstrip()[:1] == b"$":
        return _read_ubx_nmea(p, raw)
    text = head.decode("utf-8", errors="replace")
    if "time_s" in text:
        return _read_csv(p, raw)
    raise GnssLogError(f"{p}: not a UBX, NMEA or CSV GNSS log (no UBX sync bytes, no '$' "
                       "sentence, no CSV header with time_s)")


_UBX_WANT = {b"\x01\x07": "pvt", b"\x01\x06": "sol"}  # (class, id) of NAV-PVT, NAV-SOL


def _collect(raw: bytes, p: Path) -> dict[str, list]:
    """The NAV-PVT, NAV-SOL, GGA and GST messages of a UBX/NMEA stream: every frame is split
    off unparsed and only these are parsed (RXM-RAWX and the like make most of a log)."""
    from pynmeagps import NMEAReader
    from pyubx2 import NMEA_PROTOCOL, UBX_PROTOCOL, UBXReader

    out: dict[str, list] = {"pvt": [], "sol": [], "gga": [], "gst": [], "sol_for_gga": []}
    last_itow = None
    rd = UBXReader(io.BytesIO(raw), protfilter=NMEA_PROTOCOL | UBX_PROTOCOL, quitonerror=0,
                   parsing=0)
    try:
        for frame, _ in rd:
            if frame is None:
                continue
            if frame[:2] == b"\xb5\x62":
                key = _UBX_WANT.get(bytes(frame[2:4]))
                if key is None:
                    continue
                msg = UBXReader.parse(frame)
                out[key].append(msg)
                if key == "sol":
                    last_itow = msg.iTOW
            elif frame[3:6] in (b"GGA", b"GST"):
                msg = NMEAReader.parse(frame)
                if frame[3:6] == b"GGA":
                    out["gga"].append(msg)
                    out["sol_for_gga"].append(last_itow)
                else:
                    out["gst"].append(msg)
    except Exception as e:  # pyubx2 / pynmeagps raise their own types on a damaged frame
        raise GnssLogError(f"{p}: damaged UBX/NMEA data ({type(e).__name__}: {e})") from None
    return out


def _sod(tm) -> float:
    """Seconds of the day of a GGA/GST ``time`` (datetime.time or 'hhmmss.ss')."""
    if hasattr(tm, "hour"):
        return tm.hour * 3600 + tm.minute * 60 + tm.second + tm.microsecond * 1e-6
    s = str(tm)
    return int(s[:2]) * 3600 + int(s[2:4]) * 60 + float(s[4:])


def _num(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _gga_arrays(msgs: list) -> tuple[np.ndarray, np.ndarray, list[str]]:
    sod = np.array([_sod(m.time) for m in msgs])
    h = np.array([_num(m.alt) + (_num(m.sep) if _num(m.sep) == _num(m.sep) else 0.0)
                  for m in msgs])
    ll = np.array([[_num(m.lat), _num(m.lon)] for m in msgs])
    q = [_GGA_Q.get(int(_num(m.quality)) if _num(m.quality) == _num(m.quality) else 0, "none")
         for m in msgs]
    return sod, np.column_stack([ll, h]), q


def _read_ubx_nmea(p: Path, raw: bytes) -> GnssLog:
    c = _collect(raw, p)
    if c["pvt"]:
        return _from_pvt(p, c["pvt"])
    if c["sol"]:
        return _from_sol(p, c)
    if c["gga"]:
        return _from_gga(p, c)
    raise GnssLogError(f"{p}: no NAV-PVT, NAV-SOL or GGA fixes in the log")


def _from_pvt(p: Path, msgs: list) -> GnssLog:
    t = np.unwrap(np.array([m.iTOW for m in msgs], dtype=float) / 1000.0, period=604800.0)
    llh = np.array([[m.lat, m.lon, m.height / 1000.0] for m in msgs], dtype=float)
    fix = []
    for m in msgs:
        ok = bool(m.gnssFixOk) and m.fixType in (3, 4)
        if not ok:
            fix.append("2d" if m.fixType == 2 and m.gnssFixOk
                       else "time-only" if m.fixType == 5 else "none")
        elif m.carrSoln == 2:
            fix.append("rtk-fixed")
        elif m.carrSoln == 1:
            fix.append("rtk-float")
        else:
            fix.append("dgps" if m.diffSoln else "3d")
    h_acc = np.array([m.hAcc for m in msgs], dtype=float) / 1000.0
    v_acc = np.array([m.vAcc for m in msgs], dtype=float) / 1000.0
    pos = geodetic_to_ecef(llh[:, 0], llh[:, 1], llh[:, 2])
    return _make(p, "UBX NAV-PVT", t, pos, "ecef", fix, h_acc, v_acc,
                 np.hypot(h_acc, v_acc))


#: GPS − UTC (s) from these UTC dates on (IERS Bulletin C; none announced after 2017-01-01)
_LEAPS = ((1981, 7), (1982, 7), (1983, 7), (1985, 7), (1988, 1), (1990, 1), (1991, 1),
          (1992, 7), (1993, 7), (1994, 7), (1996, 1), (1997, 7), (1999, 1), (2006, 1),
          (2009, 1), (2012, 7), (2015, 7), (2017, 1))


def _leap(c: dict[str, list]) -> tuple[float, str] | None:
    """GPS − UTC (s) and how it was found: from the GPS week of the first NAV-SOL with a valid
    week (the leap-second table), else the most frequent whole-second difference between a
    NAV-SOL's iTOW and the UTC time of the GGA after it."""
    import datetime as dt

    m0 = next((m for m in c["sol"] if getattr(m, "wknSet", 0) and m.week > 0), None)
    if m0 is not None:
        day = dt.date(1980, 1, 6) + dt.timedelta(days=7 * int(m0.week) + m0.iTOW // 86_400_000)
        return float(sum((day.year, day.month) >= ym for ym in _LEAPS)), "GPS week"
    d: Counter = Counter()
    for m, itow in zip(c["gga"], c["sol_for_gga"], strict=True):
        if itow is not None:
            d[round((itow / 1000.0 - _sod(m.time)) % 86400.0) % 86400] += 1
    return (float(d.most_common(1)[0][0]), "message order") if d else None


def _from_sol(p: Path, c: dict[str, list]) -> GnssLog:
    msgs = c["sol"]
    itow = np.array([m.iTOW for m in msgs], dtype=float) / 1000.0
    pos = np.array([[m.ecefX, m.ecefY, m.ecefZ] for m in msgs], dtype=float) / 100.0
    fix = []
    for m in msgs:
        if not (m.gpsfixOK and m.gpsFix in (3, 4)):
            fix.append("2d" if m.gpsFix == 2 and m.gpsfixOK
                       else "time-only" if m.gpsFix == 5 else "none")
        else:
            fix.append("dgps" if m.diffSoln else "3d")
    src = "UBX NAV-SOL"
    found = _leap(c) if c["gga"] else None
    if found is not None:
        leap, how = found
        q = {round(_sod(m.time) * 10): _GGA_Q.get(int(_num(m.quality)), "none")
             for m in c["gga"] if _num(m.quality) == _num(m.quality)}
        for i, tw in enumerate(itow):
            g = q.get(round(((tw - leap) % 86400.0) * 10))
            if g is not None and fix[i] in ("3d", "dgps"):
                fix[i] = g
        src += f" + NMEA GGA quality (GPS-UTC {leap:.0f} s, from the {how})"
    p_acc = np.array([m.pAcc for m in msgs], dtype=float) / 100.0
    nan = np.full(len(msgs), np.nan)
    t = np.unwrap(itow, period=604800.0)
    return _make(p, src, t, pos, "ecef", fix, nan, nan.copy(), p_acc)


def _from_gga(p: Path, c: dict[str, list]) -> GnssLog:
    sod, llh, fix = _gga_arrays(c["gga"])
    ok = np.isfinite(llh).all(axis=1)
    if not ok.any():
        raise GnssLogError(f"{p}: no GGA sentence with a position")
    h_acc = np.full(len(sod), np.nan)
    v_acc = np.full(len(sod), np.nan)
    src = "NMEA GGA"
    if c["gst"]:
        gst = {round(_sod(m.time) * 10): m for m in c["gst"]}
        for i, s in enumerate(sod):
            g = gst.get(round(s * 10))
            if g is not None:
                h_acc[i] = math.hypot(_num(g.stdLat), _num(g.stdLong))
                v_acc[i] = _num(g.stdAlt)
        src += " + GST"
    t = np.unwrap(sod, period=86400.0)
    llh = np.where(ok[:, None], llh, 0.0)
    pos = geodetic_to_ecef(llh[:, 0], llh[:, 1], llh[:, 2])
    fix = [f if o else "none" for f, o in zip(fix, ok, strict=True)]
    return _make(p, src, t, pos, "ecef", fix, h_acc, v_acc, np.hypot(h_acc, v_acc))


def _make(p: Path, src: str, t: np.ndarray, pos: np.ndarray, frame: str, fix: list[str],
          h_acc: np.ndarray, v_acc: np.ndarray, p_acc: np.ndarray) -> GnssLog:
    order = np.argsort(t, kind="stable")
    t = np.asarray(t, dtype=float)[order]
    return GnssLog(str(p), src, t - t[0], np.asarray(pos, dtype=float)[order], frame,
                   np.array(fix, dtype=object)[order], np.asarray(h_acc)[order],
                   np.asarray(v_acc)[order], np.asarray(p_acc)[order])


_CSV_POS = (("lat_deg", "lon_deg", "height_m"), ("e_m", "n_m", "u_m"))


def _csv_fix(v: str, p: Path, line: int) -> str:
    s = v.strip().lower()
    if s in FIX_CLASSES:
        return s
    if s.isdigit() and int(s) in _GGA_Q:
        return _GGA_Q[int(s)]
    raise GnssLogError(f"{p}: line {line}: fix = {v!r} is invalid; allowed: "
                       f"{', '.join(FIX_CLASSES)} or a GGA quality 0-6")


def _read_csv(p: Path, raw: bytes) -> GnssLog:
    lines = [ln for ln in raw.decode("utf-8", errors="replace").splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]
    rows = list(csv.reader(lines))
    head = [h.strip() for h in rows[0]]
    cols = next((c for c in _CSV_POS if all(k in head for k in c)), None)
    if "time_s" not in head or cols is None:
        raise GnssLogError(f"{p}: CSV header {','.join(head)!r} lacks time_s and lat_deg, "
                           "lon_deg, height_m (or e_m, n_m, u_m)")
    idx = {k: head.index(k) for k in head}
    num_keys = ["time_s", *cols] + [k for k in ("h_acc_m", "v_acc_m", "p_acc_m") if k in idx]
    vals = {k: [] for k in num_keys}
    fix: list[str] = []
    for ln, row in enumerate(rows[1:], start=2):
        if len(row) != len(head):
            raise GnssLogError(f"{p}: line {ln}: {len(row)} fields, the header has {len(head)}")
        for k in num_keys:
            v = _num(row[idx[k]])
            if not math.isfinite(v):
                raise GnssLogError(f"{p}: line {ln}: {k} = {row[idx[k]]!r} is invalid; must "
                                   "be a finite number")
            vals[k].append(v)
        fix.append(_csv_fix(row[idx["fix"]], p, ln) if "fix" in idx else "3d")
    if not fix:
        raise GnssLogError(f"{p}: CSV has a header but no fixes")
    a = {k: np.array(v) for k, v in vals.items()}
    n = len(fix)
    nan = np.full(n, np.nan)
    pos = np.column_stack([a[k] for k in cols])
    frame = "enu" if cols[0] == "e_m" else "ecef"
    if frame == "ecef":
        pos = geodetic_to_ecef(pos[:, 0], pos[:, 1], pos[:, 2])
    h, v = a.get("h_acc_m", nan), a.get("v_acc_m", nan.copy())
    pa = a.get("p_acc_m", np.hypot(h, v))
    return _make(p, f"CSV ({', '.join(head)})", a["time_s"], pos, frame, fix, h, v, pa)


@dataclass
class Selection:
    """Epochs kept for the fit: ``mask``, the class(es) kept, the rate (Hz), contiguous
    ``segments`` (index ranges into the kept epochs; a gap longer than 1.5 sample intervals
    splits them) and a line saying how many were kept and dropped and why."""

    mask: np.ndarray
    keep: tuple[str, ...]
    dt: float
    segments: list[tuple[int, int]]
    line: str


def select_epochs(log: GnssLog, fix: str = "auto", min_epochs: int = 32) -> Selection:
    """The epochs of one solution type: ``fix`` is a key of :data:`KEEP_SETS`, or "auto": the
    most frequent class among 3d, dgps, rtk-float, rtk-fixed (an RTK log keeps its RTK-fixed
    epochs, a standalone one its 3-D fixes)."""
    counts = Counter(log.fix.tolist())
    if fix == "auto":
        cands = [(counts.get(k, 0), i, k) for i, k in enumerate(FIX_CLASSES[3:])]
        best = max(cands)
        if best[0] == 0:
            raise GnssLogError(f"{log.path}: no epoch with a 3-D fix or better "
                               f"(fix types: {dict(counts)})")
        keep: tuple[str, ...] = (best[2],)
    elif fix in KEEP_SETS:
        keep = KEEP_SETS[fix]
    else:
        raise GnssLogError(f"--fix = {fix!r} is invalid; allowed: auto, "
                           f"{', '.join(KEEP_SETS)}")
    mask = np.isin(log.fix, keep)
    n = int(mask.sum())
    dropped = ", ".join(f"{counts[k]} {k}" for k in FIX_CLASSES if k not in keep and counts[k])
    if n < min_epochs:
        raise GnssLogError(f"{log.path}: {n} epochs of fix type {'/'.join(keep)} (of "
                           f"{log.t.size}); at least {min_epochs} are needed")
    t = log.t[mask]
    steps = np.diff(t)
    dt = float(np.median(steps))
    if not dt > 0:
        raise GnssLogError(f"{log.path}: epochs do not advance in time (median step {dt} s)")
    cut = np.flatnonzero(steps > 1.5 * dt) + 1
    bounds = [0, *cut.tolist(), n]
    segs = [(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    line = (f"kept {n} of {log.t.size} epochs ({'/'.join(keep)}), dropped "
            f"{log.t.size - n} (other fix types: {dropped or 'none'}); "
            f"{len(segs)} contiguous segment(s) at {1.0 / dt:g} Hz")
    return Selection(mask, keep, dt, segs, line)
