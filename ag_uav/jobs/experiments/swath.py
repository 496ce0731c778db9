"""``ag-uav experiment swath``: a spray pattern test of the deposition model (issue 18).

As a pattern test does (ASABE S386-style; the effective swath for multirotors as in Martin,
Woldt & Latheef, *Drones* 3(4):83, 2019: the widest lane spacing with CV ≤ 25 %), single passes
are flown across a line of collectors at several heights, speeds and crosswinds, and the deposit
profile across the flight line is read from the dose map (mean over a 10 m stretch of track in
the middle of a 60 m pass; collectors every 0.25 m, out to 20 m on each side). The vehicle is
kinematic (:func:`pass_states`): constant ground
speed along +x at y = 0, the tilt and thrust that balance its weight and the configured air drag
at its airspeed (``vehicle.drag_linear`` / ``drag_quadratic``), no MuJoCo, so a case takes well
under a second. The crosswind blows along +y (towards the collectors' positive side).

Overlaying the profile at lane spacing S (Σ_j p(y − jS); with symmetric nozzles the back-and-
forth and racetrack overlays coincide in the ground frame) gives the CV against S; the effective
swath is the widest S (0.25 m steps up to 20 m) with CV ≤ 25 %.

Prints and writes (``--out``): ``swath.csv`` (one row per case: height, speed, wind, effective
swath, CV at the configured swath, centroid shift of the deposit, drift fraction, share of the
deposit beyond the buffer), ``profiles.csv`` (the deposit profiles) and ``swath.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ...world.deposition import DepositionBatch, DepositionConfig

NAME = "swath"
HELP = ("spray pattern test of the deposition model: single passes across a collector line at "
        "several heights, speeds and crosswinds; deposit profile, CV vs lane spacing, effective "
        "swath")

PASS_M = 60.0          # length of the sprayed pass
WINDOW_M = 10.0        # collectors: mean over this stretch of track in the middle
CV_LIMIT = 0.25
COLLECTOR_M = 0.25     # collector spacing = the map's cell in this test


def _floats(s: str) -> list[float]:
    return [float(v) for v in s.split(",") if v.strip()]


def pass_states(speed: float, height: float, wind_y: float, mass_kg: float,
                drag_lin: float, drag_quad: float) -> tuple[np.ndarray, float]:
    """Body→world R (row-major, 9) and total thrust of a steady level pass along +x: thrust
    vector T = m g ẑ + (c₁ + c₂|v_a|) v_a balances weight and drag at airspeed v_a = v − W."""
    va = np.array([speed, -wind_y, 0.0])
    tv = np.array([0.0, 0.0, mass_kg * 9.81]) + (drag_lin + drag_quad * np.linalg.norm(va)) * va
    z = tv / np.linalg.norm(tv)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z]).ravel(), float(np.linalg.norm(tv))


def single_pass(cfg: DepositionConfig, speed: float, height: float, wind_y: float,
                mass_kg: float = 6.47, drag_lin: float = 0.25, drag_quad: float = 0.18,
                dt: float = 0.01, turb: float = 0.2) -> tuple[np.ndarray, np.ndarray, dict]:
    """One pass; returns (y of the collectors, deposit L/ha, bookkeeping dict). The steady pass
    has no gust samples, so ambient turbulence enters as σ_a = ``turb`` × wind (0.2: the Dryden
    "mean" preset's σ_u at 3 m, :mod:`ag_uav.world.wind`) unless the config sets its own."""
    R, thrust = pass_states(speed, height, wind_y, mass_kg, drag_lin, drag_quad)
    sig = cfg.ambient_sigma_mps or turb * abs(wind_y)
    cfg = dataclasses.replace(cfg, cell_m=COLLECTOR_M, buffer_m=max(cfg.buffer_m, 20.0),
                              ambient_sigma_mps=sig)
    dep = DepositionBatch(cfg, None, 1, bounds=(-PASS_M / 2, -1.0, PASS_M / 2, 1.0))
    x = -PASS_M / 2 - 2.0 * speed
    n = int(round((PASS_M + 4.0 * speed) / (speed * dt)))
    inp = np.zeros((1, 20))
    inp[0, 6:15] = R
    inp[0, 15] = thrust
    inp[0, 17] = wind_y
    inp[0, 3] = speed
    inp[0, 2] = height
    for _ in range(n):
        x += speed * dt
        inp[0, 0] = x
        inp[0, 19] = 1.0 if -PASS_M / 2 <= x <= PASS_M / 2 else 0.0
        dep.step_packed(dt, inp)
    dm = dep.dose_map(0)
    xc, yc = dm.centres()
    cols = np.abs(xc) <= WINDOW_M / 2
    prof = dm.l_per_ha[:, cols].mean(axis=1)
    info = {"sprayed_l": dm.sprayed_l, "drift_l": dm.drift_l,
            "outside_l": dm.outside_grid_l, "grid_l": float(dm.litres.sum())}
    return yc, prof, info


def cv_vs_spacing(y: np.ndarray, prof: np.ndarray, spacings: np.ndarray) -> np.ndarray:
    """CV of the overlaid deposit Σ_j p(y − jS) over one period, for each spacing S."""
    dy = y[1] - y[0]
    out = np.empty(len(spacings))
    for i, s in enumerate(spacings):
        k = max(1, int(round(s / dy)))
        per = np.zeros(k)
        for j in range(len(prof)):
            per[j % k] += prof[j]
        out[i] = per.std() / per.mean() if per.mean() > 0 else math.inf
    return out


def effective_swath(spacings: np.ndarray, cv: np.ndarray, limit: float = CV_LIMIT) -> float:
    """The widest spacing with CV ≤ ``limit`` (0 if none)."""
    ok = np.nonzero(cv <= limit)[0]
    return float(spacings[ok[-1]]) if len(ok) else 0.0


def swath_pattern(cfg: DepositionConfig, heights, speeds, winds, mass_kg: float = 6.47,
                  drag_lin: float = 0.25, drag_quad: float = 0.18,
                  spacings: np.ndarray | None = None, turb: float = 0.2
                  ) -> tuple[list[dict], dict]:
    """Every (height, speed, wind) case: a row of pattern figures and its profile."""
    sp = np.arange(0.5, 20.01, 0.25) if spacings is None else spacings
    rows, profiles = [], {}
    for h in heights:
        for v in speeds:
            for w in winds:
                y, p, info = single_pass(cfg, v, h, w, mass_kg, drag_lin, drag_quad, turb=turb)
                cv = cv_vs_spacing(y, p, sp)
                tot = p.sum()
                cen = float((y * p).sum() / tot) if tot > 0 else math.nan
                i_cfg = int(np.argmin(np.abs(sp - cfg.swath_m)))
                rows.append({"height_m": h, "speed_mps": v, "wind_mps": w,
                             "effective_swath_m": effective_swath(sp, cv),
                             "cv_at_swath": float(cv[i_cfg]), "peak_l_per_ha": float(p.max()),
                             "centroid_m": cen,
                             "beyond_5m_fraction": float(p[y > 5.0].sum() / tot) if tot else 0.0,
                             "drift_fraction": info["drift_l"] / info["sprayed_l"]})
                profiles[(h, v, w)] = (y, p)
    return rows, profiles


#: OMAFRA Hort Matters 2013 (omafra.gov.on.ca .../2013/16hrt13a2f1.htm): how far a droplet drifts
#: in a 15 km/h wind (20 °C, 40 % RH): (diameter µm, release height m) -> metres
OMAFRA_DRIFT = {(200, 0.5): "≤ 0.25", (200, 1.0): "≈ 3", (100, 0.5): "≈ 6", (100, 1.0): "≈ 16"}


def droplet_anchor(cfg: DepositionConfig) -> list[list[str]]:
    """Still-air fall time h / v_t times a 15 km/h wind, against OMAFRA's figure."""
    from ...world.deposition import terminal_velocity

    rows = []
    for (d, h), pub in OMAFRA_DRIFT.items():
        vt = terminal_velocity(d * 1e-6, cfg.liquid_density, cfg.air_density, cfg.air_viscosity)
        rows.append([f"{d} µm", f"{h:g} m", f"{h / vt * 15 / 3.6:.1f}", pub])
    return rows


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--heights", default="2,3,4", help="release heights (m), comma-separated")
    p.add_argument("--speeds", default="3,5,7", help="ground speeds (m/s)")
    p.add_argument("--winds", default="0,1.5,3", help="crosswinds (m/s)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a DepositionConfig field (e.g. outwash_layer_m=0.2)")
    p.add_argument("--mass", type=float, default=6.47, help="vehicle mass (kg); hover thrust")
    p.add_argument("--turbulence", type=float, default=0.2,
                   help="ambient turbulence sigma as a share of the crosswind")
    p.add_argument("--out", default="runs/experiment-swath", metavar="DIR", help="output folder")


def _overrides(items: list[str]) -> dict[str, Any]:
    import tomllib

    out: dict[str, Any] = {}
    for it in items:
        k, _, v = it.partition("=")
        out[k.strip()] = tomllib.loads(f"v = {v}")["v"]
        if isinstance(out[k.strip()], list):
            out[k.strip()] = tuple(tuple(x) if isinstance(x, list) else x
                                   for x in out[k.strip()])
    return out


def main(args: argparse.Namespace) -> int:
    from ..batch import markdown_table, print_table
    from . import write_csv

    cfg = DepositionConfig(**_overrides(args.set))
    t0 = time.perf_counter()
    rows, profiles = swath_pattern(cfg, _floats(args.heights), _floats(args.speeds),
                                   _floats(args.winds), mass_kg=args.mass, turb=args.turbulence)
    wall = time.perf_counter() - t0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "swath.csv", rows)
    prow = [{"height_m": h, "speed_mps": v, "wind_mps": w, "y_m": float(a), "l_per_ha": float(b)}
            for (h, v, w), (y, p) in profiles.items() for a, b in zip(y, p, strict=True)]
    write_csv(out / "profiles.csv", prow)
    header = ["h (m)", "v (m/s)", "wind (m/s)", "eff. swath (m)", f"CV @ {cfg.swath_m:g} m",
              "peak (L/ha)", "centroid (m)", "> 5 m downwind", "drift"]
    table = [[f"{r['height_m']:g}", f"{r['speed_mps']:g}", f"{r['wind_mps']:g}",
              f"{r['effective_swath_m']:.2f}", f"{100 * r['cv_at_swath']:.0f} %",
              f"{r['peak_l_per_ha']:.2f}", f"{r['centroid_m']:+.2f}",
              f"{100 * r['beyond_5m_fraction']:.1f} %",
              f"{100 * r['drift_fraction']:.2f} %"] for r in rows]
    print_table(header, table, f"Pattern test ({cfg.rate_l_per_ha:g} L/ha, {wall:.1f} s)")
    anchor = droplet_anchor(cfg)
    print_table(["droplet", "release h", "model (m)", "OMAFRA (m)"], anchor,
                "Single droplets in a 15 km/h wind, no downwash (fall time x wind)")
    (out / "swath.md").write_text(markdown_table(header, table) + "\n"
                                  + markdown_table(["droplet", "release h", "model (m)",
                                                    "OMAFRA (m)"], anchor))
    print(f"wrote {out / 'swath.csv'}, {out / 'profiles.csv'}, {out / 'swath.md'}")
    return 0
