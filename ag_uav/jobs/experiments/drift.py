"""``ag-uav experiment drift``: a simulated field drift trial in the manner of ISO 22866.

A treated strip (``--passes`` back-and-forth passes at the lane spacing ``swath_m``, the outer
pass half a lane inside the strip's downwind edge) is sprayed upwind of collector lines at 1,
2, 3, 5, 10, 15, 20, 30 and 50 m from the edge; the wind blows across the passes, towards the
collectors. The vehicle is kinematic (:func:`ag_uav.jobs.experiments.swath.pass_states`: the
tilt and thrust of a steady level pass), and every droplet class's landing law is the one the
loop uses (:func:`ag_uav.world.deposition.footprints`, the same compiled function). The deposit
is evaluated analytically, not on a bounded grid: per class, the part the wake carries down
lands as a Gaussian, the part that escapes at the wake's edge as the inverse-Gaussian first
passage of a settling droplet through the turbulent surface layer (``scipy.stats.invgauss``)
blurred by the edge ring, so the tail runs on to any distance. Deposits are of the tracer (what
a trial's collectors measure): evaporation shrinks the droplets but keeps their tracer; what is
still aloft after ``airborne_after_s`` is not deposited.

Writes into ``--out`` (``runs/experiment-drift``): ``drift.csv`` (one row per case and
distance: crosswind, release height, speed, spectrum, temperature, RH, distance, deposit in %
of the applied rate), ``cases.csv`` (per case: buffers for < 1 % and < 0.1 %, each with its
low and high bound from the uncertain inputs (:mod:`.drift_range`), evaporated and airborne
shares of the sprayed volume, the place in the JKI band at the central, low and high inputs),
``drift.png`` (deposit against distance, log scale, with the published curves and the band
shaded) and ``drift.md`` (the buffer table, the comparison with the published field
measurements with the ratio at each distance, and the band check: :func:`band_check`).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import time
from pathlib import Path

import numpy as np

from ...world.deposition import DepositionConfig
from ...world.drift_bounds import DY, FAR, pass_profile  # noqa: F401 - the profile's law
from . import drift_range, flight_axes, name_axis, number_axis, toml_overrides

NAME = "drift"
HELP = ("simulated drift trial (ISO 22866 style): a treated strip upwind of collector lines at "
        "1-50 m; deposit in %% of the applied rate against crosswind, release height, speed, "
        "droplet spectrum, temperature and humidity, with buffers and published curves")

DISTANCES = (1.0, 2.0, 3.0, 5.0, 10.0, 15.0, 20.0, 30.0, 50.0)
#: what the buffers' bounds are (:mod:`.drift_range`)
BOUNDS_NOTE = ("low: wake_escape halved, an unstable surface layer, the wind's direction "
               "meandering 20°; high: wake_escape doubled, a stable layer, a steady direction")
#: how the band table reads
BAND_NOTE = ("Place in the band from JKI field crops (F) to JKI fruit, early (E), from 5 m: "
             "inside / above E / below F, with the ratio to the nearest edge")
#: illustrative spectra (Dv10, Dv50, Dv90 in µm); "medium" is the product default
SPECTRA = {"fine": (80.0, 160.0, 290.0), "medium": (120.0, 250.0, 420.0),
           "coarse": (180.0, 360.0, 600.0)}

#: JKI basic drift values, % of the applied rate, 90th percentile, one application (JKI 2010
#: "Tabelle der Abdrifteckwerte", Rautmann, Streloke & Winkler 2001, Mitt. Biol. Bundesanst.
#: Land- Forstwirtsch. 383:133-141; as tabulated in the R package pfm, ``drift_data_JKI``)
JKI = {
    "JKI field crops (ground boom)": {1: 2.77, 3: 0.95, 5: 0.57, 10: 0.29, 15: 0.20, 20: 0.15,
                                      30: 0.10, 50: 0.06},
    "JKI fruit, late (orchard airblast)": {3: 15.73, 5: 8.41, 10: 3.60, 15: 1.81, 20: 1.09,
                                           30: 0.54, 50: 0.22},
    "JKI fruit, early (orchard airblast)": {3: 29.20, 5: 19.89, 10: 11.81, 15: 5.55,
                                            20: 2.77, 30: 1.04, 50: 0.30},
}
#: Bonds et al. 2024 (J. ASABE 67(1):27-41, review of published UASS trials): UASS drift is
#: "lower than aerial, higher than ground boom, and similar to orchard airblast"; so the band
#: from the field-crop curve to the early-fruit curve is where a drone's deposit is expected.
BAND = ("JKI field crops (ground boom)", "JKI fruit, early (orchard airblast)")
#: the distances (m) the band is checked at: from 5 m out, where both curves have a value
BAND_DISTANCES = tuple(d for d in DISTANCES if d >= 5 and all(d in JKI[b] for b in BAND))


def band_check(dep: dict[float, float]) -> list[tuple[float, str, float, str]]:
    """Each deposit (% of the rate, by distance) against the band from the field-crop curve F
    (low edge) to the early-fruit curve E (high edge) at :data:`BAND_DISTANCES`:
    (distance, "above" / "inside" / "below", ratio to the nearest edge, that edge "E" / "F").
    Above: dep / E > 1; below: dep / F < 1; inside: the ratio to the edge nearer in log scale
    (dep / F if dep / F < E / dep, else dep / E)."""
    lo, hi = JKI[BAND[0]], JKI[BAND[1]]
    out = []
    for d in BAND_DISTANCES:
        if d not in dep:
            continue
        v = dep[d]
        if v > hi[d]:
            out.append((d, "above", v / hi[d], "E"))
        elif v < lo[d]:
            out.append((d, "below", v / lo[d], "F"))
        elif v / lo[d] < hi[d] / v:
            out.append((d, "inside", v / lo[d], "F"))
        else:
            out.append((d, "inside", v / hi[d], "E"))
    return out


def band_verdict(checks: list[tuple[float, str, float, str]]) -> str:
    """One line from :func:`band_check`: "inside", or where the deposit leaves the band and the
    furthest it gets from the edge (e.g. "above E at 30, 50 m (up to 1.6 ×)")."""
    parts = []
    for side, edge in (("above", "E"), ("below", "F")):
        out = [(d, r) for d, s, r, _ in checks if s == side]
        if out:
            worst = max(r for _, r in out) if side == "above" else min(r for _, r in out)
            at = ", ".join(f"{d:g}" for d, _ in out)
            parts.append(f"{side} {edge} at {at} m ({'up' if side == 'above' else 'down'} "
                         f"to {worst:#.2g} ×)")
    return "; ".join(parts) if parts else "inside"


@dataclasses.dataclass(frozen=True)
class Case:
    wind: float
    height: float
    speed: float
    spectrum: str
    temp_c: float
    rh: float


def single_pass_profile(cfg: DepositionConfig, case: Case, mass_kg: float = 6.47,
                        drag_lin: float = 0.25, drag_quad: float = 0.18
                        ) -> tuple[np.ndarray, np.ndarray, dict]:
    """:func:`ag_uav.world.drift_bounds.pass_profile` of ``case``."""
    return pass_profile(cfg, case.wind, case.height, case.speed, mass_kg, drag_lin, drag_quad)


def strip_deposit(y: np.ndarray, dens: np.ndarray, lane: float, passes: int,
                  dist: np.ndarray) -> np.ndarray:
    """Deposit (% of the applied rate) at ``dist`` past the strip's downwind edge: passes at
    −(j + ½)·lane, each laying ``lane`` × density (the applied rate per pass and metre)."""
    out = np.zeros(len(dist))
    for j in range(passes):
        out += np.interp(dist + (j + 0.5) * lane, y, dens, left=0.0, right=0.0)
    return 100.0 * lane * out


def buffer_m(dist: np.ndarray, dep: np.ndarray, thr: float) -> float:
    """The distance beyond which the deposit stays below ``thr`` % (nan: not within FAR)."""
    above = np.nonzero(dep >= thr)[0]
    if not len(above):
        return float(dist[0])
    i = above[-1]
    return float(dist[i + 1]) if i + 1 < len(dist) else math.nan


def run_cases(base: DepositionConfig, cases: list[Case], passes: int, mass_kg: float
              ) -> tuple[list[dict], list[dict], dict]:
    """Every case: rows per distance, one summary row per case, and the fine curves."""
    from ..._progress import progress_bar

    rows, summ, curves = [], [], {}
    fine = np.arange(0.5, FAR + 1e-9, 0.5)
    bar = progress_bar(total=len(cases), desc="drift", unit="case")
    for c in cases:
        bar.update(1)
        dv = SPECTRA[c.spectrum]
        cfg = dataclasses.replace(base, dv10_um=dv[0], dv50_um=dv[1], dv90_um=dv[2],
                                  temperature_c=c.temp_c, rh_percent=c.rh)
        y, dens, book = single_pass_profile(cfg, c, mass_kg)
        dep = strip_deposit(y, dens, cfg.swath_m, passes, np.asarray(DISTANCES))
        depf = strip_deposit(y, dens, cfg.swath_m, passes, fine)
        curves[c] = (fine, depf)
        for d, v in zip(DISTANCES, dep, strict=True):
            rows.append({"crosswind_mps": c.wind, "release_height_m": c.height,
                         "speed_mps": c.speed, "spectrum": c.spectrum, "temperature_c": c.temp_c,
                         "rh_percent": c.rh, "distance_m": d, "deposit_percent": float(v)})
        summ.append({"crosswind_mps": c.wind, "release_height_m": c.height,
                     "speed_mps": c.speed, "spectrum": c.spectrum, "temperature_c": c.temp_c,
                     "rh_percent": c.rh, "buffer_1pct_m": buffer_m(fine, depf, 1.0),
                     "buffer_0p1pct_m": buffer_m(fine, depf, 0.1),
                     "jki_band": band_verdict(band_check(dict(zip(DISTANCES, dep.tolist(),
                                                                   strict=True)))),
                     "escaped_fraction": book["escaped"],
                     "evaporated_fraction": book["evaporated"],
                     "airborne_fraction": book["airborne"]})
    bar.close()
    return rows, summ, curves


def bound_buffers(base: DepositionConfig, cases: list[Case], passes: int, mass_kg: float
                  ) -> dict:
    """Per case the buffers (< 1 %, < 0.1 %) at the low and the high bound of the uncertain
    inputs (:mod:`.drift_range`) and the bound's place in the JKI band (:func:`band_verdict`):
    {case: {"low": (m, m, verdict), "high": (m, m, verdict)}}."""
    out: dict = {c: {} for c in cases}
    for which in drift_range.BOUNDS:
        cfg, sig = drift_range.bound_config(base, which)
        _, _, curves = run_cases(cfg, cases, passes, mass_kg)
        for c in cases:
            x, dep = curves[c]
            d = drift_range.meander(x, dep, sig)
            at = dict(zip(BAND_DISTANCES, np.interp(BAND_DISTANCES, x, d).tolist(), strict=True))
            out[c][which] = (buffer_m(x, d, 1.0), buffer_m(x, d, 0.1),
                             band_verdict(band_check(at)))
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--winds", default="1,3,5", help="crosswinds at the release height (m/s; "
                   "each one wind.speed_mps accepts)")
    p.add_argument("--heights", default="2,3", help="release heights (m; each one "
                   "mission.altitude_m accepts: between spray.min_height_m and max_height_m)")
    p.add_argument("--speeds", default="5", help="ground speeds (m/s)")
    names = ", ".join(f"{k} {v[0]:g}/{v[1]:g}/{v[2]:g}" for k, v in SPECTRA.items())
    p.add_argument("--spectra", default="fine,medium,coarse",
                   help=f"droplet spectra (Dv10/Dv50/Dv90: {names} µm)")
    p.add_argument("--temps", default="20", help="air temperatures (°C)")
    p.add_argument("--rhs", default="40,60,80", help="relative humidities (%%)")
    p.add_argument("--passes", type=int, default=10, help="passes of the treated strip")
    p.add_argument("--mass", type=float, default=6.47, help="vehicle mass (kg)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a DepositionConfig field (e.g. wake_escape=0.2)")
    p.add_argument("--out", default="runs/experiment-drift", metavar="DIR", help="output folder")


def _plot(path: Path, curves: dict, base_cases: list[Case]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5.5))
    for c in base_cases:
        if c in curves:
            x, d = curves[c]
            keep = x <= 60
            ax.plot(x[keep], np.maximum(d[keep], 1e-6),
                    label=f"model {c.height:g} m, {c.wind:g} m/s, {c.spectrum}")
    for name, vals in JKI.items():
        ax.plot(list(vals), list(vals.values()), "o--", ms=4, label=name)
    ax.fill_between(BAND_DISTANCES, [JKI[BAND[0]][d] for d in BAND_DISTANCES],
                    [JKI[BAND[1]][d] for d in BAND_DISTANCES], color="0.5", alpha=0.15,
                    label="band: field crops to fruit, early (from 5 m)")
    ax.set_yscale("log")
    ax.set_xlabel("distance from the treated strip's edge (m)")
    ax.set_ylabel("deposit (% of the applied rate)")
    ax.set_ylim(1e-3, 100)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("Drift trial (ISO 22866 style): model against JKI basic drift values")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _comparison(rows: list[dict], base_cases: list[Case]) -> tuple[list[str], list[list[str]]]:
    header = ["case", "curve"] + [f"{d:g} m" for d in DISTANCES]
    table = []
    for c in base_cases:
        dep = {r["distance_m"]: r["deposit_percent"] for r in rows
               if (r["crosswind_mps"], r["release_height_m"], r["speed_mps"], r["spectrum"],
                   r["temperature_c"], r["rh_percent"]) == dataclasses.astuple(c)}
        if not dep:
            continue
        label = f"{c.height:g} m, {c.wind:g} m/s"
        table.append([label, "model (%)"] + [f"{dep[d]:.3g}" for d in DISTANCES])
        for name, vals in JKI.items():
            table.append([label, f"model / {name}"]
                         + [f"{dep[d] / vals[d]:.2g}" if d in vals else "—" for d in DISTANCES])
    for name, vals in JKI.items():
        table.append(["published", f"{name} (%)"]
                     + [f"{vals[d]:g}" if d in vals else "—" for d in DISTANCES])
    return header, table


def _band_table(rows: list[dict], summ: list[dict], base_cases: list[Case]
                ) -> tuple[list[str], list[list[str]]]:
    """Per plotted case: its place in the JKI band at each distance from 5 m (the ratio to the
    nearest edge, F field crops / E early fruit) and the verdict at the central, low and high
    inputs."""
    header = (["case"] + [f"{d:g} m" for d in BAND_DISTANCES]
              + ["central", "low bound", "high bound"])
    table = []
    for c in base_cases:
        key = dataclasses.astuple(c)
        dep = {r["distance_m"]: r["deposit_percent"] for r in rows
               if (r["crosswind_mps"], r["release_height_m"], r["speed_mps"], r["spectrum"],
                   r["temperature_c"], r["rh_percent"]) == key}
        s = next((s for s in summ
                  if (s["crosswind_mps"], s["release_height_m"], s["speed_mps"], s["spectrum"],
                      s["temperature_c"], s["rh_percent"]) == key), None)
        if not dep or s is None:
            continue
        cells = [f"{st} {r:#.2g} {e}" for _, st, r, e in band_check(dep)]
        table.append([f"{c.height:g} m, {c.wind:g} m/s"] + cells
                     + [s["jki_band"], s.get("jki_band_low", "—"), s.get("jki_band_high", "—")])
    return header, table


def _cases(args: argparse.Namespace) -> tuple[DepositionConfig, list[Case], list[Case]]:
    """The deposition config, the cases of the axes and the ones plotted (each height and wind
    at the first speed and temperature, the middle humidity, medium droplets).  Every axis is
    checked (one line, exit 2): not empty, numbers, the flight envelope
    (:func:`~ag_uav.jobs.experiments.flight_axes`), temperatures and humidities within
    :class:`DepositionConfig`'s limits, ``--passes`` >= 1."""
    from ...config import ConfigError

    winds, heights, speeds = flight_axes(args)
    spectra = name_axis("--spectra", args.spectra, SPECTRA)
    temps = number_axis("--temps", args.temps)
    rhs = number_axis("--rhs", args.rhs)
    if args.passes < 1:
        raise ConfigError(f"--passes = {args.passes}: must be >= 1")
    try:
        base = DepositionConfig(**toml_overrides(args.set))
        for t, rh in itertools.product(temps, rhs):
            DepositionConfig(temperature_c=t, rh_percent=rh)   # validates
    except (ValueError, TypeError) as e:
        raise ConfigError(f"--temps/--rhs/--set: {e}") from None
    cases = [Case(*v) for v in itertools.product(winds, heights, speeds, spectra, temps, rhs)]
    spec, rh_mid = "medium" if "medium" in spectra else spectra[0], sorted(rhs)[len(rhs) // 2]
    plotted = [Case(w, h, speeds[0], spec, temps[0], rh_mid) for h in heights for w in winds]
    return base, cases, plotted


def main(args: argparse.Namespace) -> int:
    from ..batch import markdown_table, print_table
    from . import write_csv

    base, cases, base_cases = _cases(args)
    t0 = time.perf_counter()
    rows, summ, curves = run_cases(base, cases, args.passes, args.mass)
    rng = bound_buffers(base, cases, args.passes, args.mass)
    for s, c in zip(summ, cases, strict=True):
        for which, (b1, b01, band) in rng[c].items():
            s[f"buffer_1pct_{which}_m"], s[f"buffer_0p1pct_{which}_m"] = b1, b01
            s[f"jki_band_{which}"] = band
    wall = time.perf_counter() - t0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "drift.csv", rows)
    write_csv(out / "cases.csv", summ)
    _plot(out / "drift.png", curves, base_cases)
    bh = ["wind (m/s)", "h (m)", "v (m/s)", "spectrum", "T (°C)", "RH (%)",
          "< 1 % beyond (m) (low–high)", "< 0.1 % beyond (m) (low–high)", "escaped",
          "evaporated", "airborne", "JKI band (from 5 m)"]
    bt = [[f"{s['crosswind_mps']:g}", f"{s['release_height_m']:g}", f"{s['speed_mps']:g}",
           s["spectrum"], f"{s['temperature_c']:g}", f"{s['rh_percent']:g}",
           f"{s['buffer_1pct_m']:g} ({s['buffer_1pct_low_m']:g}–{s['buffer_1pct_high_m']:g})",
           f"{s['buffer_0p1pct_m']:g} ({s['buffer_0p1pct_low_m']:g}–"
           f"{s['buffer_0p1pct_high_m']:g})",
           f"{100 * s['escaped_fraction']:.1f} %", f"{100 * s['evaporated_fraction']:.2f} %",
           f"{100 * s['airborne_fraction']:.3f} %", s["jki_band"]] for s in summ]
    print_table(bh, bt, f"Drift trial: buffers ({len(cases)} cases, {wall:.1f} s)")
    ch, ct = _comparison(rows, base_cases)
    print_table(ch, ct, "Deposit (% of the applied rate) beside the JKI basic drift values")
    gh, gt = _band_table(rows, summ, base_cases)
    print_table(gh, gt, BAND_NOTE)
    (out / "drift.md").write_text(
        "## Buffers\n\nIn brackets the low and high bounds (" + BOUNDS_NOTE + ").\n\n"
        + markdown_table(bh, bt) + "\n## Against published measurements\n\n"
        + markdown_table(ch, ct) + "\n## In the band of the JKI curves\n\n" + BAND_NOTE
        + ".\n\n" + markdown_table(gh, gt))
    print(f"wrote {out / 'drift.csv'}, {out / 'cases.csv'}, {out / 'drift.png'}, "
          f"{out / 'drift.md'}")
    return 0
