"""``ag-uav experiment spray-settings``: which height, speed, lane spacing and droplet spectrum
spray evenly in a given wind, at what work rate and with how much drift.

**Search (the pattern test, no flights).** For every release height × ground speed × droplet
spectrum single passes of the deposition model's pattern test are flown, with a full tank and an
empty one (each figure below is the worse of the two, as the mission's automatic lanes take it);
the passes out and back are overlaid alternately (:func:`ag_uav.world.pattern.cv_back_and_forth`:
with ``--along``, a wind along the legs, the pass back is flown too; without, it lays the pass
out's profile on the ground: flown the other way, it meets the crosswind on its other side, and
its mirror image across the track is the pass out's, exact for the default nozzle layout,
symmetric across it; the mission's lanes test, :func:`ag_uav.world.pattern.run_pattern`, flies
it and finds the same)
(:func:`ag_uav.world.pattern.single_pass`: a kinematic pass across a collector line, the mean
wind as a crosswind, 60 m long, collectors every 0.25 m to 20 m on each side), and its
profile p(y) (per unit flow) is overlaid at every candidate lane spacing S. Per (h, v, spectrum,
S), on a 100 m wide field whose downwind edge is at y = 0 with the outermost lane S/2 inside it
(the other lanes at (k + ½)S, k < ⌈100/S⌉, as the headland and the legs lie):

- ``cv``: the CV of the overlay Σ_j p(y − jS) over one period (the pattern test's CV);
- ``underdosed``: the share of that period below 80 % of its mean (the flight's
  ``underdosed_fraction``, taken over the field interior);
- ``offtarget``: the deposit beyond the downwind edge over everything sprayed (collectors to
  20 m, plus what the test counts airborne past them);
- ``drift_past_buffer``: the same beyond the edge plus ``--buffer`` metres;
- ``work_rate_ha_h``: the theoretical field capacity S · v · 0.36 (ha/h; no turns, no refills:
  an upper bound; the flights of ``--confirm`` give the job time).

**Against the forecast's spread.** ``--wind`` is the forecast the plan is made on. With
``--draws K`` (4) every figure above is the mean over K flown winds (:func:`flown_winds`: the
forecast's vector turned by σ_θ z₂ and its length changed by σ_U z₁, the config's
``forecast.direction_sigma_deg`` and ``forecast.speed_sigma_mps``, z from the config seed's
``"forecast"`` stream, :mod:`ag_uav.world.forecast`); the part of a drawn wind along the legs
makes the passes out and back differ, and both are flown. ``cv_exact`` (and ``*_exact``) are
the figures at the forecast itself, ``cv_p90`` the 90th percentile of the CV over the draws.

The **Pareto front** keeps the settings no other beats on all three of work rate (higher),
CV (lower) and drift past the buffer (lower); the table lists the front's points with
CV ≤ ``--cv-max`` (the effective swath's 25 % by default). Under-dosed area and off-target
deposit are reported beside them.

**Confirmation (``--confirm N``, real flights).** The N fastest front points with CV ≤
``--cv-max`` are flown on the configured mission (MuJoCo, the controller and the INS, the
engine's dose map) in one batch, and their flown dose CV, under-dosed area and off-field deposit
stand beside the pattern test's: the pattern test has no gusts, turns, leg ends or field edges.

Every axis is checked before the search as ``ag-uav fly`` checks the config key it sets
(``--heights`` → ``mission.altitude_m``, ``--speeds`` → ``mission.speed_mps``, ``--spacings``
→ ``mission.swath_m``, ``--wind`` → ``wind.speed_mps``, on the base config with its ``--set``
items): an empty axis or a value a flight would refuse is one line and exit 2, so the table
never recommends what the confirming flights cannot fly.

Writes (``--out``): ``settings.csv`` (every point), ``pareto.csv``, ``spray_settings.md`` and
``pareto.png`` (work rate against CV, coloured by the drift past the buffer).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ...world.pattern import cv_back_and_forth, single_pass
from . import check_on_config, name_axis, number_axis

NAME = "spray-settings"
HELP = ("search height, speed, lane spacing and droplet spectrum against dose CV, under-dosed "
        "area, off-target deposit and drift past a buffer in a given wind (the pattern test); "
        "Pareto front of work rate vs CV vs drift, optionally confirmed by flights")

FIELD_M = 100.0
#: droplet spectra (Dv10, Dv50, Dv90 in µm): illustrative points of ASABE S572's fine, medium and
#: coarse classes (medium = the product's default 120 / 250 / 420 µm, 19 % of the volume below
#: 150 µm; GRDC's reading of S572: fine > 20 %, coarse < 10 % below 150 µm)
SPECTRA = {"fine": (90.0, 180.0, 320.0), "medium": (120.0, 250.0, 420.0),
           "coarse": (180.0, 350.0, 560.0)}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--wind", type=float, default=None,
                   help="wind across the legs (m/s; default: the config's wind.speed_mps)")
    p.add_argument("--along", type=float, default=0.0,
                   help="wind along the legs (m/s): the passes out and back then differ")
    p.add_argument("--heights", default="2,3,4", help="release heights (m), comma-separated; "
                   "each one `ag-uav fly` accepts as mission.altitude_m (between "
                   "spray.min_height_m and spray.max_height_m of the base config), else exit 2")
    p.add_argument("--speeds", default="3,5,7", help="ground speeds (m/s), each one "
                   "mission.speed_mps accepts")
    p.add_argument("--spacings", default="2:9:0.5", metavar="LO:HI:STEP",
                   help="lane spacings (m), each one mission.swath_m accepts")
    p.add_argument("--spectra", default="fine,medium,coarse",
                   help=f"droplet spectra ({', '.join(SPECTRA)})")
    p.add_argument("--buffer", type=float, default=5.0, help="buffer (m) past the downwind edge")
    p.add_argument("--cv-max", type=float, default=0.25, help="CV limit of the table and "
                   "of the flights that confirm it")
    p.add_argument("--draws", type=int, default=4, metavar="K",
                   help="draws of the forecast's error (the config's forecast.speed_sigma_mps "
                   "and forecast.direction_sigma_deg, from its seed): every figure is the mean "
                   "over the K flown winds, the plan's exact wind beside it; 0: the exact wind "
                   "only")
    p.add_argument("--confirm", type=int, default=0, metavar="N",
                   help="fly the N fastest front points with CV <= --cv-max on the mission")
    p.add_argument("--config", default=None, help="base config (TOML)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config key of the base config")
    p.add_argument("--out", default="runs/experiment-spray-settings", metavar="DIR",
                   help="output folder")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


@dataclasses.dataclass(frozen=True)
class Case:
    height_m: float
    speed_mps: float
    spectrum: str


def _spacings(s: str) -> np.ndarray:
    try:
        lo, hi, st = (float(v) for v in s.split(":"))
    except ValueError:
        raise ValueError(f"--spacings = {s!r}: expected LO:HI:STEP") from None
    if not (0 < lo <= hi and st > 0 and math.isfinite(hi)):
        raise ValueError(f"--spacings = {s!r}: need 0 < LO <= HI and STEP > 0")
    if (hi - lo) / st > 10_000:
        raise ValueError(f"--spacings = {s!r}: more than 10000 spacings; use a larger STEP")
    return np.round(np.arange(lo, hi + 1e-9, st), 6)


def _axes(args: argparse.Namespace, wind: float) -> tuple[list[Case], np.ndarray]:
    """The search's cases and spacings, each axis checked as ``ag-uav fly`` checks the key it
    sets on the mission (:func:`~ag_uav.jobs.experiments.check_on_config`, on the base config
    and its ``--set`` items): the search holds only settings the confirming flights accept."""
    from ...config import ConfigError

    heights = number_axis("--heights", args.heights, lo=0.0, lo_open=True)
    speeds = number_axis("--speeds", args.speeds, lo=0.0, lo_open=True)
    spectra = name_axis("--spectra", args.spectra, SPECTRA)
    try:
        spacings = _spacings(args.spacings)
    except ValueError as e:
        raise ConfigError(str(e)) from None
    for name, v, ok in (("--wind", wind, 0 <= wind <= 25), ("--along", args.along,
                        abs(args.along) <= 25), ("--buffer", args.buffer, args.buffer >= 0),
                        ("--cv-max", args.cv_max, args.cv_max > 0),
                        ("--confirm", args.confirm, args.confirm >= 0),
                        ("--draws", args.draws, 0 <= args.draws <= 1000)):
        if not (ok and math.isfinite(v)):
            raise ConfigError(f"{name} = {v:g}: allowed: --wind 0..25 m/s, --along -25..25 m/s, "
                              "--buffer >= 0 m, --cv-max > 0, --confirm >= 0, --draws 0..1000")
    base = (args.config, args.set)
    check_on_config("--heights", heights, "mission.altitude_m", *base)
    check_on_config("--speeds", speeds, "mission.speed_mps", *base)
    check_on_config("--spacings", [float(s) for s in spacings], "mission.swath_m", *base)
    check_on_config("--wind", [wind], "wind.speed_mps", *base)
    return [Case(h, v, s) for h in heights for v in speeds for s in spectra], spacings


def edge_shares(y: np.ndarray, p: np.ndarray, airborne: float, spacing: float,
                buffer_m: float) -> tuple[float, float]:
    """(off-target, drift past the buffer): the shares of what a ``FIELD_M`` wide field sprays
    that land beyond its downwind edge (y > 0), and beyond the edge + ``buffer_m``, with lanes at
    y = −(k + ½)·S. ``p`` is one pass's deposit profile (per collector), ``airborne`` the share
    of one pass's volume the test carried past its collectors (counted as drift past any
    buffer)."""
    dy = y[1] - y[0]
    n = max(1, math.ceil(FIELD_M / spacing - 1e-9))
    cum = np.concatenate([[0.0], np.cumsum(p[::-1])])[::-1]   # cum[i] = Σ p[i:]
    total = p.sum() / max(1.0 - airborne, 1e-12)               # the pass's whole volume
    off = drift = 0.0
    for k in range(n):
        shift = (k + 0.5) * spacing                           # the pass lies at −shift
        # collectors wholly beyond the line (their lower side at or past it)
        i_edge = int(np.searchsorted(y, shift + 0.5 * dy - 1e-9))
        i_buf = int(np.searchsorted(y, buffer_m + shift + 0.5 * dy - 1e-9))
        off += cum[min(i_edge, len(p))]
        drift += cum[min(i_buf, len(p))]
    return ((off + n * airborne * total) / (n * total),
            (drift + n * airborne * total) / (n * total))


def case_rows(case: Case, y: np.ndarray, p: np.ndarray, airborne: float, wind: float,
              spacings: np.ndarray, buffer_m: float, back: np.ndarray | None = None
              ) -> list[dict[str, Any]]:
    """The figures of every spacing of one pass out (``p``) and back (``back``, in the frame of
    the pass out; None: ``p``, the pass back in a pure crosswind with symmetric nozzles)."""
    back = p if back is None else back
    cvs = cv_back_and_forth(y, p, back, spacings)
    dy = y[1] - y[0]
    rows = []
    for s, cv in zip(spacings, cvs, strict=True):
        k = max(1, int(round(s / dy)))
        pair = p.astype(float).copy()
        pair[k:] += back[:len(back) - k]
        per = np.bincount(np.arange(len(pair)) % (2 * k), weights=pair, minlength=2 * k)
        under = float(np.mean(per < 0.8 * per.mean())) if per.mean() > 0 else 1.0
        off, drift = edge_shares(y, 0.5 * (p + back), airborne, float(s), buffer_m)
        rows.append({"height_m": case.height_m, "speed_mps": case.speed_mps,
                     "spectrum": case.spectrum, "spacing_m": float(s), "wind_mps": wind,
                     "work_rate_ha_h": float(s) * case.speed_mps * 0.36, "cv": float(cv),
                     "underdosed": under, "offtarget": off, "drift_past_buffer": drift})
    return rows


def pareto(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows no other row beats on all of work rate (max), CV (min) and drift (min)."""
    a = np.array([[-r["work_rate_ha_h"], r["cv"], r["drift_past_buffer"]] for r in rows])
    keep = []
    for i in range(len(a)):
        dom = np.all(a <= a[i], axis=1) & np.any(a < a[i], axis=1)
        if not dom.any():
            keep.append(rows[i])
    return sorted(keep, key=lambda r: -r["work_rate_ha_h"])


FIGURES = ("cv", "underdosed", "offtarget", "drift_past_buffer")


def flown_winds(wind: float, along: float, draws: int, speed_sigma: float, direction_sigma: float,
                seed: int) -> list[tuple[float, float]]:
    """The winds (across, along the legs; m/s) the plan made on the forecast (``wind`` across,
    ``along`` along) meets in flight: ``draws`` draws of the forecast's error
    (:mod:`ag_uav.world.forecast`: speed error σ_U z₁, direction error σ_θ z₂, from the
    ``"forecast"`` stream of ``seed``), the forecast's vector turned by σ_θ z₂ and its length
    changed by σ_U z₁ (at least 0)."""
    from ...seeds import seed_sequences
    from ...world.forecast import spread_winds

    z = np.random.default_rng(seed_sequences(seed)["forecast"]).standard_normal((draws, 2))
    return spread_winds(wind, along, z, speed_sigma, direction_sigma)


def _mass_rows(c: Case, dc: Any, base: Any, m: float, cross: float, along: float,
               spacings: np.ndarray, buffer_m: float) -> list[dict[str, Any]]:
    """One mass's passes out and back in the wind (``cross``, ``along``), every spacing."""
    drag = (base.drag_linear, base.drag_quadratic)
    y, p, info = single_pass(dc, c.speed_mps, c.height_m, cross, m, *drag, wind_x=along)
    back = None
    if along != 0.0:
        _, b, _ = single_pass(dc, c.speed_mps, c.height_m, -cross, m, *drag, wind_x=-along)
        back = b[::-1].copy()
    airborne = info["drift_l"] / info["sprayed_l"] if info["sprayed_l"] > 0 else 0.0
    return case_rows(c, y, p, airborne, cross, spacings, buffer_m, back)


def search(cfg: Any, cases: list[Case], wind: float, spacings: np.ndarray, buffer_m: float,
           progress: bool = True, along: float = 0.0,
           winds: list[tuple[float, float]] | None = None) -> list[dict[str, Any]]:
    """Every case's single passes at the mission's masses (a full tank and an empty one, as
    :func:`ag_uav.world.pattern.lane_choice` tests) and drag, overlaid at every spacing; each
    figure is the worse of the two masses. With ``winds`` (the flown winds of
    :func:`flown_winds`) the figures are their means over those winds and the forecast's own
    (the plan's exact wind) stand beside them as ``*_exact``."""
    from ..._progress import progress_bar
    from ...world.deposition import DepositionConfig
    from ...world.pattern import pattern_case

    calm = dataclasses.replace(cfg, wind=dataclasses.replace(cfg.wind, speed_mps=0.0),
                               forecast=dataclasses.replace(cfg.forecast, speed_mps="auto",
                                                            speed_sigma_mps=0.0))
    base = pattern_case(calm)   # its masses, drag, nozzles
    rows: list[dict[str, Any]] = []
    bar = progress_bar(total=len(cases), desc="pattern tests", unit="case", disable=not progress)
    for c in cases:
        d10, d50, d90 = SPECTRA[c.spectrum]
        dc: DepositionConfig = dataclasses.replace(base.dep, dv10_um=d10, dv50_um=d50,
                                                   dv90_um=d90)
        per_wind = []
        for cross, al in [(wind, along), *(winds or [])]:
            per_mass = [_mass_rows(c, dc, base, m, cross, al, spacings, buffer_m)
                        for m in base.masses_kg]
            per_wind.append([{**worst[0], **{k: max(r[k] for r in worst) for k in FIGURES}}
                             for worst in zip(*per_mass, strict=True)])
        for exact, *drawn in zip(*per_wind, strict=True):
            row = {**exact, "wind_mps": wind}
            if drawn:
                row.update({f"{k}_exact": exact[k] for k in FIGURES})
                row.update({k: float(np.mean([r[k] for r in drawn])) for k in FIGURES})
                row["cv_p90"] = float(np.quantile([r["cv"] for r in drawn], 0.9))
            rows.append(row)
        bar.update(1)
    bar.close()
    return rows


def confirm(cfg_args: tuple[str | None, list[str]], points: list[dict[str, Any]], wind: float
            ) -> list[dict[str, Any]]:
    """Fly the mission at each point's settings (one batch); the flown dose beside the test's."""
    from ...config import load_config, parse_set_items
    from ...engine.missions import simulate_many

    path, sets = cfg_args
    cfgs = []
    for r in points:
        d10, d50, d90 = SPECTRA[r["spectrum"]]
        ov = {**parse_set_items(sets), "log.enabled": False, "log.render": False,
              "wind.speed_mps": wind, "mission.altitude_m": r["height_m"],
              "mission.speed_mps": r["speed_mps"], "mission.swath_m": r["spacing_m"],
              "mission.headland_m": "auto", "spray.dv10_um": d10, "spray.dv50_um": d50,
              "spray.dv90_um": d90}
        cfgs.append(load_config(path, ov))
    out = []
    for r, res in zip(points, simulate_many(cfgs, progress=True, errors="return"), strict=True):
        s = {} if isinstance(res, Exception) else res.summary
        out.append({**{k: r[k] for k in ("height_m", "speed_mps", "spectrum", "spacing_m")},
                    "cv_test": r["cv"], "cv_flown": s.get("dose_cv"),
                    "underdosed_test": r["underdosed"],
                    "underdosed_flown": s.get("underdosed_fraction"),
                    "offtarget_flown": s.get("offtarget_deposit_fraction"),
                    "job_time_s": s.get("job_time_s"),
                    "error": str(res) if isinstance(res, Exception) else ""})
    return out


def plot(rows: list[dict[str, Any]], front: list[dict[str, Any]], path: Path, title: str
         ) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    drift = np.array([100 * r["drift_past_buffer"] for r in rows])
    sc = ax.scatter([r["work_rate_ha_h"] for r in rows], [100 * r["cv"] for r in rows], s=10,
                    c=drift, cmap="viridis", alpha=0.5)
    ax.scatter([r["work_rate_ha_h"] for r in front], [100 * r["cv"] for r in front], s=40,
               facecolors="none", edgecolors="red", label="Pareto front")
    ax.axhline(25.0, color="grey", lw=0.8, ls="--", label="CV 25 % (effective swath)")
    ax.set_xlabel("work rate, lane × speed (ha/h)")
    ax.set_ylabel("dose CV of the overlaid pattern (%)")
    ax.set_ylim(0, min(100.0, max(100 * r["cv"] for r in rows) * 1.05))
    fig.colorbar(sc, ax=ax, label="drift past the buffer (% of sprayed)")
    import textwrap

    ax.set_title("\n".join(textwrap.wrap(title, 90)), fontsize=8)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _table(front: list[dict[str, Any]], cv_max: float) -> tuple[list[str], list[list[str]]]:
    header = ["h (m)", "v (m/s)", "droplets", "lanes (m)", "work rate (ha/h)", "CV",
              "under-dosed", "off-target", "drift past buffer"]
    body = [[f"{r['height_m']:g}", f"{r['speed_mps']:g}", r["spectrum"], f"{r['spacing_m']:g}",
             f"{r['work_rate_ha_h']:.1f}", f"{100 * r['cv']:.0f} %",
             f"{100 * r['underdosed']:.0f} %", f"{100 * r['offtarget']:.2f} %",
             f"{100 * r['drift_past_buffer']:.3f} %"]
            for r in front if r["cv"] <= cv_max]
    if front and "cv_exact" in front[0]:
        header[6:6] = ["CV p90", "CV exact wind"]
        for b, r in zip(body, [r for r in front if r["cv"] <= cv_max], strict=True):
            b[6:6] = [f"{100 * r['cv_p90']:.0f} %", f"{100 * r['cv_exact']:.0f} %"]
    return header, body


def main(args: argparse.Namespace) -> int:
    from ...config import load_config, parse_set_items
    from ..batch import markdown_table, print_table
    from . import write_csv

    cfg = load_config(args.config, parse_set_items(args.set))
    wind = cfg.wind.speed_mps if args.wind is None else float(args.wind)
    cases, spacings = _axes(args, wind)
    t0 = time.perf_counter()
    fc = cfg.forecast
    winds = (flown_winds(wind, args.along, args.draws, fc.speed_sigma_mps,
                         fc.direction_sigma_deg, cfg.seed) if args.draws else None)
    rows = search(cfg, cases, wind, spacings, args.buffer, progress=not args.quiet,
                  along=args.along, winds=winds)
    wall = time.perf_counter() - t0
    front = pareto(rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "settings.csv", rows)
    write_csv(out / "pareto.csv", front)
    spread = (f"; mean over {args.draws} draws of the forecast's error ({fc.speed_sigma_mps:g} "
              f"m/s, {fc.direction_sigma_deg:g} deg)" if args.draws else "; exact wind")
    title = (f"{len(cases)} pattern tests x {len(spacings)} lane spacings, {wind:g} m/s "
             f"crosswind forecast{spread}, buffer {args.buffer:g} m ({wall:.0f} s)")
    header, body = _table(front, args.cv_max)
    print_table(header, body, f"Pareto front (work rate, CV, drift), CV <= "
                              f"{100 * args.cv_max:g} %: {title}")
    md = f"{title}\n\n" + markdown_table(header, body)
    if args.confirm > 0:
        pts = [r for r in front if r["cv"] <= args.cv_max][:args.confirm]
        flown = confirm((args.config, args.set), pts, wind)
        write_csv(out / "confirm.csv", flown)
        fh = ["h (m)", "v (m/s)", "droplets", "lanes (m)", "CV test", "CV flown",
              "under-dosed test", "under-dosed flown", "off the field (flown)", "job time (s)"]

        def pct(v: Any, nd: int = 0) -> str:
            return "–" if v is None else f"{100 * v:.{nd}f} %"

        fb = [[f"{r['height_m']:g}", f"{r['speed_mps']:g}", r["spectrum"],
               f"{r['spacing_m']:g}", pct(r["cv_test"]), pct(r["cv_flown"]),
               pct(r["underdosed_test"]), pct(r["underdosed_flown"]),
               pct(r["offtarget_flown"], 2),
               "–" if r["job_time_s"] is None else f"{r['job_time_s']:.0f}"] for r in flown]
        print_table(fh, fb, "Confirmed by flights of the mission (pattern test vs flown)")
        md += "\n" + markdown_table(fh, fb)
    (out / "spray_settings.md").write_text(md)
    plot(rows, front, out / "pareto.png", title)
    print(f"wrote {out / 'settings.csv'}, {out / 'pareto.csv'}, {out / 'spray_settings.md'}, "
          f"{out / 'pareto.png'}")
    return 0
