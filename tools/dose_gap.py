"""What a flown dose's gap to the planner's pattern test is made of, by the wind's parts.

A development tool of the repository (not part of the installed package); the figures of
``docs/spray_deposition.md`` ("Why the wake law's flown dose departs from its pattern test"):

    python tools/dose_gap.py --set spray.deposition_law=wake --set forecast.speed_sigma_mps=0 \\
        --set forecast.direction_sigma_deg=0

The mission is flown once (the engine: MuJoCo, the controller, the INS; ``--set`` as
``ag-uav fly`` takes it) and every tick's input row of the dose model (position, velocity,
attitude, rotor thrust, the wind at the vehicle, the nozzle command) is kept with the flown
wind's mean (its direction meandering). The rows are then replayed through the same compiled
deposition (:class:`~ag_uav.world.deposition.DepositionBatch`, one row per variant) with the
wind's parts taken out one at a time; the flight path stays the flown one:

* ``flown``: the rows as flown (equals the flight's own dose rows);
* ``no gust``: the wind the mean with its meander (the Dryden gusts out);
* ``steady``: the configured mean wind, no gust and no meander;
* ``gust along`` / ``gust across``: the mean and only the gust's part along / across the legs;
* ``gust, vehicle smoothed``: the gusts kept, the attitude and the thrust low-passed over 2 s
  (what the vehicle's own response to the gusts adds);
* ``wind low-passed 1 s`` / ``3 s``: the wind the law sees low-passed (first order) over 1 s /
  3 s, longer than the trailing pair's roll-up time t* = b₀/w₀ (a law that responds to the
  airspeed only over its formation time sees less than this).

Per variant: the dose CV, the under- and over-dosed shares over the field (the summary's
rows) and over the interior ``--margin`` m inside the boundary (no headland laps, turns or
leg ends), with the interior's CV split into the part across the legs (the stripes: the mean
profile across the legs) and the rest (along the legs). ``--laws default,hover,wake`` replays
the same flown path, lanes and flow by each law (which of the law's parts makes the gap).
``--edges`` adds, per edge of the boundary, the under-dosed share and the mean dose of the
cells within 12 m of it (each cell with its nearest edge), the edge upwind or downwind.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from typing import Any

import numpy as np

import ag_uav
from ag_uav.config.load import parse_set_items
from ag_uav.engine import stages
from ag_uav.engine.missions import simulate
from ag_uav.world.deposition import DepositionBatch, DepositionConfig
from ag_uav.world.deposition_layout import INPUT
from ag_uav.world.field import load_field
from ag_uav.world.pattern import lane_choice, mission_direction, mission_swath

I = INPUT.at
WIND = slice(I.WIND, I.WIND + 3)
VARIANTS = ("flown", "no gust", "steady", "gust along", "gust across",
            "gust, vehicle smoothed", "wind low-passed 1 s", "wind low-passed 3 s")


def capture(cfg: Any) -> tuple[np.ndarray, np.ndarray, float, dict[str, Any]]:
    """Fly ``cfg``'s mission; (input rows (T, INPUT.size) of the ticks the vehicle was active,
    the flown wind's mean at those ticks (T, 3), dt, the summary)."""
    rows: list[np.ndarray] = []
    means: list[np.ndarray] = []
    now = {"mean": np.zeros(3), "dt": 0.0}
    d_step, p_step = stages.Disturbance.step, stages.Depositing.step

    def disturbance(self: Any, k: int = 0) -> None:
        d_step(self, k)
        now["mean"] = self.wind.mean[0].copy()

    def depositing(self: Any) -> None:
        p_step(self)
        if self.b.act[0]:
            for _, dep in self.groups:
                rows.append(dep.inp[0].copy())
                means.append(now["mean"])
            now["dt"] = float(self.b.dt)

    stages.Disturbance.step, stages.Depositing.step = disturbance, depositing
    try:
        res = simulate(cfg)
    finally:
        stages.Disturbance.step, stages.Depositing.step = d_step, p_step
    return np.array(rows), np.array(means), now["dt"], res.summary


def lowpass(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """First-order low-pass y' = (x − y)/τ along axis 0, from y₀ = x₀."""
    a = 1.0 - math.exp(-dt / tau)
    y = np.empty_like(x)
    acc = x[0].copy()
    for i in range(len(x)):
        acc += a * (x[i] - acc)
        y[i] = acc
    return y


def variant_rows(inp: np.ndarray, mean: np.ndarray, dt: float, cfg: Any,
                 legs_deg: float) -> dict[str, np.ndarray]:
    """The input rows of every variant (module docstring)."""
    w = cfg.wind
    d = math.radians(w.direction_deg)
    steady = np.array([-w.speed_mps * math.sin(d), -w.speed_mps * math.cos(d), 0.0])
    t = math.radians(legs_deg)
    along = np.array([math.cos(t), math.sin(t), 0.0])
    across = np.array([-math.sin(t), math.cos(t), 0.0])
    gust = inp[:, WIND] - mean
    out = {}
    for name in VARIANTS:
        x = inp.copy()
        if name == "no gust":
            x[:, WIND] = mean
        elif name == "steady":
            x[:, WIND] = steady
        elif name in ("gust along", "gust across"):
            e = along if name == "gust along" else across
            x[:, WIND] = mean + np.outer(gust @ e, e)
        elif name.startswith("wind low-passed"):
            x[:, WIND] = lowpass(inp[:, WIND], dt, float(name.split()[2]))
        elif name == "gust, vehicle smoothed":
            x[:, I.R:I.R_END] = lowpass(inp[:, I.R:I.R_END], dt, 2.0)
            x[:, I.THRUST] = lowpass(inp[:, I.THRUST:I.THRUST + 1], dt, 2.0)[:, 0]
        out[name] = x
    return out


def stripes(dm: Any, fld: Any, margin: float, legs_deg: float) -> tuple[float, float]:
    """The interior's CV split: (across the legs: the mean profile binned every 0.5 m across
    them, along them: the rest), each as a share of the interior's mean."""
    xc, yc = dm.centres()
    gx, gy = np.meshgrid(xc, yc)
    m = dm.field_mask(fld, margin)
    d = dm.l_per_ha[m]
    t = math.radians(legs_deg)
    u = (-gx * math.sin(t) + gy * math.cos(t))[m]
    k = np.floor(u / 0.5).astype(int)
    k -= k.min()
    prof = np.bincount(k, d) / np.maximum(np.bincount(k), 1)
    mu = d.mean()
    return float(prof[k].std() / mu), float((d - prof[k]).std() / mu)


def edges(dm: Any, fld: Any, wind_to: np.ndarray, depth: float = 12.0) -> list[str]:
    """Per edge of the field's outer boundary (its cells within ``depth`` m, each cell counted
    with its nearest edge): the share below 80 % of the field's mean dose and the mean dose over
    the field's, the edge labelled upwind or downwind by its outward normal against the mean
    wind's direction ``wind_to`` (a unit vector, where it blows to)."""
    import shapely

    xc, yc = dm.centres()
    gx, gy = np.meshgrid(xc, yc)
    m = dm.field_mask(fld)
    pts = shapely.points(gx[m], gy[m])
    d = dm.l_per_ha[m]
    mu = d.mean()
    ring = np.asarray(fld.polygon.exterior.coords)
    if shapely.Polygon(ring).exterior.is_ccw is False:
        ring = ring[::-1]
    dist = np.stack([shapely.distance(pts, shapely.LineString(ring[j:j + 2]))
                     for j in range(len(ring) - 1)])
    near, out = dist.argmin(axis=0), []
    for j in range(len(ring) - 1):
        e = ring[j + 1] - ring[j]
        normal = np.array([e[1], -e[0]]) / np.hypot(*e)      # outward on a CCW ring
        sel = (near == j) & (dist[j] < depth)
        side = "upwind" if normal @ wind_to < 0 else "downwind"
        out.append(f"{side} {math.degrees(math.atan2(e[1], e[0])) % 360:.0f}°: "
                   f"{100 * (d[sel] < 0.8 * mu).mean():.0f} % under, {d[sel].mean() / mu:.2f}")
    return out


def replay(cfg: Any, margin: float, laws: list[str] | None = None,
           overrides: dict[str, Any] | None = None, dep: dict[str, Any] | None = None
           ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Fly ``cfg``'s mission once, replay every variant by each of ``laws`` (default: the
    flown law; ``dep``: fields of its :class:`DepositionConfig` replaced) on the flown path,
    lanes and flow; (rows, the flight's summary)."""
    inp, mean, dt, summary = capture(cfg)
    lc = lane_choice(cfg)
    legs = lc.case.legs_deg if lc.case is not None else None
    if legs is None:
        legs = mission_direction(cfg) or 0.0
    fld = load_field(cfg.mission.field)
    rows_in = variant_rows(inp, mean, dt, cfg, legs)
    stack = np.stack([rows_in[n] for n in VARIANTS], axis=1)
    rate = cfg.spray.rate_l_per_ha
    out = []
    for law in laws or [cfg.spray.deposition_law]:
        c_law = ag_uav.load_config(None, dict(overrides or {}, **{"spray.deposition_law": law}))
        dc = dataclasses.replace(DepositionConfig.from_config(c_law, swath_m=mission_swath(cfg)),
                                 **(dep or {}))
        batch = DepositionBatch(dc, fld, len(VARIANTS))
        for k in range(stack.shape[0]):
            batch.step_packed(dt, stack[k])
        batch.finish()
        for i, name in enumerate(VARIANTS):
            dm = batch.dose_map(i)
            m = dm.metrics(fld, rate, cfg.spray.dose_margin_m)
            mi = dm.metrics(fld, rate, margin)
            across, along = stripes(dm, fld, margin, legs)
            d = math.radians(cfg.wind.direction_deg)
            out.append({"law": law, "variant": name, "cv": m["dose_cv"],
                        "under": m["underdosed_fraction"], "over": m["overdosed_fraction"],
                        "cv_in": mi["dose_cv"], "under_in": mi["underdosed_fraction"],
                        "across_in": across, "along_in": along,
                        "edges": edges(dm, fld, -np.array([math.sin(d), math.cos(d)]))})
    summary = dict(summary, pattern_cv=lc.cv, lanes_m=lc.swath_m, legs_deg=legs)
    return out, summary


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a config override, as ag-uav fly takes it (repeatable)")
    p.add_argument("--margin", type=float, default=8.0,
                   help="the interior: this far inside the boundary (m)")
    p.add_argument("--laws", default="", metavar="LAW,...",
                   help="replay the flown path by these deposition laws too (default: the flown "
                        "one)")
    p.add_argument("--dep", action="append", default=[], metavar="FIELD=VALUE",
                   help="replay with a field of the law's DepositionConfig replaced, e.g. "
                        "impingement_diameters=0 (repeatable; the flight is flown without it)")
    p.add_argument("--edges", action="store_true",
                   help="per edge of the boundary: the under-dosed share and the mean dose of "
                        "the cells within 12 m of it, upwind or downwind")
    args = p.parse_args(argv)
    ov = parse_set_items(args.set)
    dep = {k: float(v) for k, v in (d.split("=", 1) for d in args.dep)}
    cfg = ag_uav.load_config(None, ov)
    laws = [x.strip() for x in args.laws.split(",") if x.strip()] or None
    rows, s = replay(cfg, args.margin, laws, ov, dep)
    test = ("set by hand" if s["pattern_cv"] is None
            else f"pattern test CV {100 * s['pattern_cv']:.1f} %")
    print(f"lanes {s['lanes_m']:g} m (legs {s['legs_deg']:.0f}°; {test}); the flight's dose CV "
          f"{100 * s['dose_cv']:.1f} %")
    print(f"{'law':8s} {'variant':24s} {'CV':>6s} {'under':>6s} {'over':>6s} | interior "
          f"({args.margin:g} m in): {'CV':>6s} {'under':>6s} {'across':>6s} {'along':>6s}")
    for r in rows:
        print(f"{r['law']:8s} {r['variant']:24s} " + " ".join(
            f"{100 * r[k]:6.1f}" for k in ("cv", "under", "over")) + " |" + " " * 19
            + " ".join(f"{100 * r[k]:6.1f}" for k in ("cv_in", "under_in", "across_in",
                                                       "along_in")))
        if args.edges:
            print(" " * 9 + "edges (12 m in): " + "; ".join(r["edges"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
