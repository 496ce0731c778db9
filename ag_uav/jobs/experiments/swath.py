"""``ag-uav experiment swath``: a spray pattern test of the deposition model.

As a pattern test does (ASABE S386-style; the effective swath for multirotors as in Martin,
Woldt & Latheef, *Drones* 3(4):83, 2019: the widest lane spacing with CV ≤ 25 %), single passes
are flown across a line of collectors at several heights, speeds and crosswinds, and the deposit
profile across the flight line is read from the dose map (mean over a 10 m stretch of track in
the middle of a 60 m pass; collectors every 0.25 m, out to 20 m on each side). The vehicle is
kinematic (:func:`pass_states`): constant ground
speed along +x at y = 0, the tilt and thrust that balance its weight and the configured air drag
at its airspeed (``vehicle.drag_linear`` / ``drag_quadratic``), no MuJoCo, so a case takes well
under a second. The crosswind blows along +y (towards the collectors' positive side). The test
itself lives in :mod:`ag_uav.world.pattern` (the planner chooses a mission's lanes by it).

Overlaying the profile at lane spacing S (Σ_j p(y − jS); with symmetric nozzles the back-and-
forth and racetrack overlays coincide in the ground frame) gives the CV against S; the effective
swath is the widest S (0.25 m steps up to 20 m) with CV ≤ 25 %.

Prints and writes (``--out``): ``swath.csv`` (one row per case: height, speed, wind, effective
swath, CV at the configured swath, centroid shift of the deposit, drift fraction, share of the
deposit beyond the buffer), ``profiles.csv`` (the deposit profiles) and ``swath.md``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from ...world.deposition import DepositionConfig
from ...world.deposition_config import LAWS
from ...world.pattern import (  # noqa: F401 - the pattern test lives in the world stage
    CV_LIMIT,
    cv_vs_spacing,
    effective_swath,
    pass_states,
    single_pass,
    swath_pattern,
)
from . import flight_axes, toml_overrides

NAME = "swath"
HELP = ("spray pattern test of the deposition model: single passes across a collector line at "
        "several heights, speeds and crosswinds; deposit profile, CV vs lane spacing, effective "
        "swath")


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
    p.add_argument("--heights", default="2,3,4", help="release heights (m), comma-separated; "
                   "each one mission.altitude_m accepts")
    p.add_argument("--speeds", default="3,5,7", help="ground speeds (m/s)")
    p.add_argument("--winds", default="0,1.5,3", help="crosswinds (m/s)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a DepositionConfig field (e.g. outwash_layer_m=0.2), or with a "
                        "dotted key a mission config key (e.g. vehicle.preset=x8-40l: its rotors, "
                        "arm, nozzles, spectrum, drag and full-tank mass)")
    p.add_argument("--law", default="default", choices=sorted(LAWS),
                   help="the deposition law: default (the outwash layer calibrated on the T40), "
                        "hover (the options checked on the wind tunnel) or wake (hover and the "
                        "forward-flight vortex pair); --set overrides it")
    p.add_argument("--mass", type=float, default=None,
                   help="vehicle mass (kg; hover thrust); default 6.47, or with a dotted --set "
                        "the config's vehicle with a full tank")
    p.add_argument("--turbulence", type=float, default=0.2,
                   help="ambient turbulence sigma as a share of the crosswind")
    p.add_argument("--out", default="runs/experiment-swath", metavar="DIR", help="output folder")


def _vehicle(args: argparse.Namespace) -> tuple[DepositionConfig, float, tuple[float, float]]:
    """The deposition config, mass and drag (linear, quadratic along x) of the test: the
    M350-class defaults, or with dotted ``--set`` keys the mission config's vehicle (rotors,
    arm, nozzles, spectrum, drag; the mass with a full tank); the law and the field ``--set``
    items on top."""
    import dataclasses

    from ...config import ConfigError, load_config, parse_set_items

    dotted = [s for s in args.set if "." in s.partition("=")[0]]
    fields = [s for s in args.set if s not in dotted]
    mass, drag = 6.47, (0.25, 0.18)
    try:
        over = {**LAWS[args.law], **toml_overrides(fields)}
        if dotted:
            c = load_config(None, parse_set_items(dotted))
            v, sp = c.vehicle, c.spray
            mass = v.mass_kg + v.payload_kg + v.unknown_payload_kg + sp.tank_l * sp.density_kg_per_l
            drag = (float(v.drag_linear[0]), float(v.drag_quadratic[0]))
            cfg = dataclasses.replace(DepositionConfig.from_config(c, swath_m=6.0), **over)
        else:
            cfg = DepositionConfig(**over)
    except (ValueError, TypeError) as e:
        raise ConfigError(f"--set: {e}") from None
    return cfg, (mass if args.mass is None else args.mass), drag


def main(args: argparse.Namespace) -> int:
    from ...config import ConfigError
    from ..batch import markdown_table, print_table
    from . import write_csv

    winds, heights, speeds = flight_axes(args)
    if not (math.isfinite(args.turbulence) and args.turbulence >= 0):
        raise ConfigError(f"--turbulence = {args.turbulence:g}: must be >= 0 (a share of the "
                          "crosswind)")
    cfg, mass, drag = _vehicle(args)
    t0 = time.perf_counter()
    rows, profiles = swath_pattern(cfg, heights, speeds, winds, mass_kg=mass, drag_lin=drag[0],
                                   drag_quad=drag[1], turb=args.turbulence)
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
