"""``ag-uav experiment vehicles``: the vehicle presets side by side on the same job, and a rotor
stopped half-way through it.

**The job** (every preset of ``--presets`` on the default field, or ``--field``; ``--big`` adds
the 38 ha example field): each flight is ``ag-uav fly --set vehicle.preset=NAME`` with the seed,
so its figures are those of the summary: the work rate (the field area covered per hour of job
time, ``field_area × coverage / job_time``, base visits included), the sorties (each on a fresh
battery, so as many batteries), the fill per sortie, the battery energy and the energy per
hectare, the dose CV and the under-dosed area (below 80 % of the rate), and the drift past the
buffer (the share of the sprayed liquid landing beyond ``spray.offtarget_buffer_m``).

**Rotor failures** (``--faults N``): per preset, ``N`` seeds of the same job with rotor
``seed mod rotors`` stopped at half the planned job time and ``vehicle.rotor_fault.response``
(``--response``): when the failure detector found it, what the autopilot did and how the
flight ended (completed, landed with its touchdown speed and where, or crashed).

Writes into ``--out`` (``runs/experiment-vehicles``): ``vehicles.csv`` and ``vehicles.md`` (the
job table), ``vehicles.png`` (work rate, energy per hectare and dose CV per preset), and with
``--faults`` ``faults.csv`` and ``faults.md``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from . import name_axis, write_csv

NAME = "vehicles"
HELP = ("the vehicle presets on the same job: work rate with base visits, sorties, batteries, "
        "energy, dose CV, under-dosed area, drift; --faults N: a rotor stopped half-way, N "
        "seeds per preset")
BIG_FIELD = "examples/field_38ha.geojson"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ...config.schema import VEHICLE_PRESETS

    p.add_argument("--presets", default=",".join(VEHICLE_PRESETS),
                   help=f"comma-separated presets ({', '.join(VEHICLE_PRESETS)})")
    p.add_argument("--field", default=None, help="the job's field (default: the config's)")
    p.add_argument("--big", action="store_true",
                   help=f"fly {BIG_FIELD} too (long: minutes to tens of minutes per preset)")
    p.add_argument("--faults", type=int, default=0, metavar="N",
                   help="rotor-failure campaign: N seeds per preset (0: none)")
    p.add_argument("--response", default="auto",
                   help="vehicle.rotor_fault.response of the campaign")
    p.add_argument("--seed", type=int, default=0, help="seed of the job flights")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a config override applied to every flight")
    p.add_argument("--out", default="runs/experiment-vehicles", metavar="DIR",
                   help="output folder")


def _configs(args: argparse.Namespace, presets: list[str]) -> list[tuple[str, str, Any]]:
    """(preset, field label, config) of each job flight."""
    from ...config import load_config, parse_set_items

    base = {**parse_set_items(args.set), "log.enabled": False, "seed": args.seed}
    if args.field:
        base["mission.field"] = args.field
    fields = [("default" if not args.field else Path(args.field).name, base)]
    if args.big:
        fields.append((Path(BIG_FIELD).name, {**base, "mission.field": BIG_FIELD,
                                              "log.channels": "light"}))
    return [(p, label, load_config(None, {**over, "vehicle.preset": p}))
            for label, over in fields for p in presets]


def job_row(preset: str, field: str, s: dict[str, Any]) -> dict[str, Any]:
    """One flight's figures (module docstring) from its summary."""
    from ...config.vehicles import STATED_WORK_RATE

    area_ha = float(s.get("field_area_m2") or 0.0) / 1e4
    cov = float(s.get("coverage_fraction") or 0.0)
    job_s = s.get("job_time_s") or s.get("sim_time_s") or 0.0
    energy = s.get("energy_wh")
    return {
        "preset": preset, "field": field, "completed": bool(s.get("completed")),
        "field_ha": round(area_ha, 3), "coverage": round(cov, 5),
        "job_time_s": round(float(job_s), 1),
        "work_rate_ha_per_h": round(area_ha * cov / (job_s / 3600.0), 3) if job_s else None,
        "stated_rate_ha_per_h": (STATED_WORK_RATE[preset][0] if preset in STATED_WORK_RATE
                                 else None),
        "sorties": s.get("sorties"), "batteries": s.get("sorties"),
        "fill_l": s.get("fill_l", s.get("config", {}).get("spray", {}).get("tank_l")),
        "litres": s.get("litres_sprayed_l"), "energy_wh": energy,
        "energy_wh_per_ha": (round(energy / (area_ha * cov), 1)
                             if energy and area_ha * cov > 0 else None),
        "dose_cv": s.get("dose_cv"),
        "underdosed_m2": (round(float(s["underdosed_fraction"]) * area_ha * 1e4, 1)
                          if s.get("underdosed_fraction") is not None else None),
        "drift_fraction": s.get("drift_fraction"),
        "crash": s.get("crash_reason") or "",
    }


def fault_row(preset: str, seed: int, s: dict[str, Any]) -> dict[str, Any]:
    """One rotor-failure flight: the fault, its detection, the response and the end."""
    rf = s.get("rotor_fault") or {}
    if s.get("crashed"):
        end = f"crashed: {s.get('crash_reason')}"
    elif rf.get("landed_s") is not None:
        end = f"landed at t={rf['landed_s']} s, touchdown {rf.get('touchdown_mps')} m/s"
    else:
        end = "completed" if s.get("completed") else (s.get("incomplete_reason") or "cut")
    return {"preset": preset, "seed": seed, "rotor": rf.get("rotor"), "at_s": rf.get("at_s"),
            "detected_s": rf.get("detected_s"), "delay_s": rf.get("detection_delay_s"),
            "action": rf.get("action"), "completed": bool(s.get("completed")),
            "crashed": bool(s.get("crashed")), "landed_s": rf.get("landed_s"),
            "touchdown_mps": rf.get("touchdown_mps"), "landed_xy": rf.get("landed_xy"),
            "base_xy": s.get("base_xy"), "end": end}


def _fault_configs(args: argparse.Namespace, jobs: list[tuple[str, str, Any]]
                   ) -> list[tuple[str, int, Any]]:
    from ...config import ConfigError, config_from_dict
    from ...config.vehicles import FRAME_ROTORS
    from ...engine.missions import mission_setup

    if args.response not in ("auto", "continue", "home", "land"):
        raise ConfigError(f"--response = {args.response!r}: allowed: auto, continue, home, land")
    out = []
    for preset, _label, cfg in jobs[:len(set(j[0] for j in jobs))]:
        half = round(mission_setup(cfg)[2].duration / 2.0, 1)
        n = FRAME_ROTORS[cfg.vehicle.frame]
        d = cfg.to_dict()
        for seed in range(args.faults):
            over = {"seed": seed, "vehicle.rotor_fault.rotor": seed % n,
                    "vehicle.rotor_fault.at_s": half,
                    "vehicle.rotor_fault.response": args.response}
            out.append((preset, seed, config_from_dict(_nested(d, over))))
    return out


def _nested(d: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``d`` (a config as a dict) with dotted keys set."""
    import copy

    out = copy.deepcopy(d)
    for key, v in over.items():
        node = out
        *path, last = key.split(".")
        for k in path:
            node = node.setdefault(k, {})
        node[last] = v
    return out


def _simulate(cfgs: list[Any]) -> list[Any]:
    """Each config's run, flown in one batch per preset (a batch steps models of one layout)."""
    from ...engine.missions import simulate_many

    out: list[Any] = [None] * len(cfgs)
    groups: dict[str, list[int]] = {}
    for i, c in enumerate(cfgs):
        groups.setdefault(c.vehicle.preset, []).append(i)
    for idx in groups.values():
        for i, r in zip(idx, simulate_many([cfgs[i] for i in idx]), strict=True):
            out[i] = r
    return out


def _plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [f"{r['preset']}\n{r['field']}" for r in rows]
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, key, title in ((axs[0], "work_rate_ha_per_h", "work rate (ha/h, base visits)"),
                           (axs[1], "energy_wh_per_ha", "battery energy (Wh/ha)"),
                           (axs[2], "dose_cv", "dose CV")):
        vals = [float(r[key]) if r[key] is not None else 0.0 for r in rows]
        ax.bar(range(len(rows)), vals, color="tab:blue")
        if key == "work_rate_ha_per_h":
            for i, r in enumerate(rows):
                if r["stated_rate_ha_per_h"]:
                    ax.plot([i - 0.4, i + 0.4], [r["stated_rate_ha_per_h"]] * 2, "r--",
                            label="stated (sheet)")
            if any(r["stated_rate_ha_per_h"] for r in rows):
                ax.legend(fontsize=8)
        ax.set_xticks(range(len(rows)), labels, fontsize=8)
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(args: argparse.Namespace) -> int:
    from ...config.schema import VEHICLE_PRESETS
    from ..batch import markdown_table, print_table

    presets = name_axis("--presets", args.presets, VEHICLE_PRESETS)
    jobs = _configs(args, presets)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    res = _simulate([c for _p, _f, c in jobs])
    rows = [job_row(p, f, r.summary) for (p, f, _c), r in zip(jobs, res, strict=True)]
    write_csv(out / "vehicles.csv", rows)
    header = ["preset", "field", "done", "coverage", "job time", "work rate (ha/h)", "stated",
              "sorties", "fill (L)", "energy (Wh)", "Wh/ha", "dose CV", "under-dosed (m²)",
              "drift"]

    def f(v: Any, fmt: str) -> str:
        return "–" if v is None else fmt.format(v)

    table = [[r["preset"], r["field"], "yes" if r["completed"] else "no",
              f(r["coverage"] * 100, "{:.2f} %"), f(r["job_time_s"], "{:.0f} s"),
              f(r["work_rate_ha_per_h"], "{:.2f}"), f(r["stated_rate_ha_per_h"], "{:.1f}"),
              f(r["sorties"], "{}"), f(r["fill_l"], "{:.1f}"), f(r["energy_wh"], "{:.0f}"),
              f(r["energy_wh_per_ha"], "{:.0f}"),
              f(None if r["dose_cv"] is None else 100 * r["dose_cv"], "{:.1f} %"),
              f(r["underdosed_m2"], "{:.0f}"),
              f(None if r["drift_fraction"] is None else 100 * r["drift_fraction"], "{:.3f} %")]
             for r in rows]
    print_table(header, table, f"Vehicles on the same job ({time.perf_counter() - t0:.0f} s)")
    md = markdown_table(header, table)
    _plot(rows, out / "vehicles.png")
    if args.faults > 0:
        md += "\n" + _faults(args, jobs, out)
    (out / "vehicles.md").write_text(md)
    print(f"wrote {out / 'vehicles.csv'}, {out / 'vehicles.md'}, {out / 'vehicles.png'}")
    return 0


def _faults(args: argparse.Namespace, jobs: list[tuple[str, str, Any]], out: Path) -> str:
    """The rotor-failure campaign: faults.csv, faults.md; its markdown."""
    from ..batch import markdown_table, print_table

    runs = _fault_configs(args, jobs)
    res = _simulate([c for _p, _s, c in runs])
    rows = [fault_row(p, s, r.summary) for (p, s, _c), r in zip(runs, res, strict=True)]
    write_csv(out / "faults.csv", rows)
    header = ["preset", "seed", "rotor", "at (s)", "detected after", "response", "end"]
    table = [[r["preset"], str(r["seed"]), str(r["rotor"]), f"{r['at_s']}",
              "–" if r["delay_s"] is None else f"{r['delay_s']} s", str(r["action"]),
              r["end"]] for r in rows]
    print_table(header, table, f"A rotor stopped half-way ({args.response})")
    summary = []
    for p in dict.fromkeys(r["preset"] for r in rows):
        mine = [r for r in rows if r["preset"] == p]
        done = sum(r["completed"] for r in mine)
        soft = sum((r["touchdown_mps"] is not None and r["touchdown_mps"] < 1.0
                    and not r["crashed"] and r["landed_s"] is not None) for r in mine)
        summary.append([p, str(len(mine)), str(done), str(soft),
                        str(sum(r["crashed"] for r in mine))])
    sh = ["preset", "seeds", "completed", "landed < 1 m/s", "crashed"]
    print_table(sh, summary, "Outcomes")
    (out / "faults.md").write_text(markdown_table(header, table) + "\n"
                                   + markdown_table(sh, summary))
    print(f"wrote {out / 'faults.csv'}, {out / 'faults.md'}")
    return markdown_table(sh, summary)
