"""The PNG figures of a run, from its log alone (:func:`plot`): map, dose, spray job, errors,
controller, estimators.  Each figure is written atomically (:mod:`ag_uav.record.atomic`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .rundata import RunData, Series, run_data, sortie_of, summary_json


def _scene_lines(scene: Any, entity_id: str) -> list[tuple[np.ndarray, tuple[float, ...]]]:
    out = []
    for e in getattr(scene, "entities", []):
        if e.id != entity_id:
            continue
        for ln in e.lines:
            pts = np.array([[p.x, p.y] for p in ln.points]) if ln.points else np.zeros((0, 2))
            closed = ln.type == 1  # LINE_LOOP
            if closed and len(pts):
                pts = np.vstack([pts, pts[:1]])
            out.append((pts, (ln.color.r, ln.color.g, ln.color.b, ln.color.a)))
    return out


def _scene_triangles(scene: Any, entity_id: str) -> list[np.ndarray]:
    out = []
    for e in getattr(scene, "entities", []):
        if e.id != entity_id:
            continue
        for tri in e.triangles:
            pts = np.array([[p.x, p.y] for p in tri.points])
            out += [pts[i:i + 3] for i in range(0, len(pts) - 2, 3)]
    return out


def _grid(axs: Any) -> None:
    for a in np.atleast_1d(axs).ravel():
        a.grid(alpha=0.3)


def _save(fig: Any, path: Path, dpi: int) -> Path:
    """Write ``fig`` to ``path`` (tight bounding box) and close it; the path."""
    import matplotlib.pyplot as plt

    from ..record.atomic import atomic_path

    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=path.suffix[1:] or "png")
    finally:
        plt.close(fig)
    return path



def plot(run: str | Path | RunData, out_dir: str | Path) -> list[Path]:
    """PNG figures of a run: map, errors, controller, estimators (those with data).

    ``run``: a run folder, its ``.mcap`` or a :class:`RunData` already read.  Each figure is
    written atomically; a log with nothing to draw raises
    :class:`~ag_uav.analysis.logscan.LogError`."""
    import matplotlib

    matplotlib.use("Agg")

    from .logscan import LogError

    d = run_data(run, images=False)
    if not d.series and not d.scenes:
        raise LogError(f"{d.path}: nothing to plot (no readable state, GPS, estimator or scene "
                       "messages)")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    st = d.series.get("/drone/state")
    gps = d.series.get("/gps")
    spr = d.series.get("/drone/spray")
    ests = {k.split("/")[-1]: v for k, v in d.series.items() if k.startswith("/estimator/")}
    summ = summary_json(d)
    paths = [_plot_map(d, summ, out / "map.png")]
    dose = _dose_of(d)
    if dose is not None:
        paths.append(_plot_dose(dose, d.scenes.get("/field"), summ, out / "dose.png"))
    if spr is not None and len(spr.t):
        paths.append(_plot_spray(spr, summ, out / "spray.png"))
    if st is not None:
        paths.append(_plot_errors(st, ests, out / "errors.png"))
        paths.append(_plot_controller(d, st, out / "controller.png"))
    if ests or gps is not None:
        paths.append(_plot_estimators(gps_fix_error(d.series), ests, out / "estimators.png"))
    return paths


def _draw_field(ax: Any, field_scene: Any, sprayed_scene: Any) -> None:
    """The field (filled, outlined; holes red), the sprayed area and the planned path."""
    from matplotlib.collections import PolyCollection

    if field_scene is not None:
        tris = _scene_triangles(field_scene, "field")
        if tris:
            tan = (0.85, 0.78, 0.6)
            ax.add_collection(PolyCollection(tris, facecolor=tan, edgecolor=tan, lw=0.5,
                                             zorder=0))
    if sprayed_scene is not None:
        tris = _scene_triangles(sprayed_scene, "sprayed")
        if tris:
            ax.add_collection(PolyCollection(tris, facecolor=(0.3, 0.75, 1.0, 0.35),
                                             edgecolor="none", zorder=1))
            ax.plot([], [], color=(0.3, 0.75, 1.0), lw=6, alpha=0.5, label="sprayed area")
    if field_scene is None:
        return
    first_field = first_hole = True
    for pts, col in _scene_lines(field_scene, "field"):
        is_hole = col[0] > 0.8 and col[1] < 0.5   # the scene draws holes red, parts gold
        lbl = None
        if is_hole and first_hole:
            lbl, first_hole = "obstacle", False
        elif not is_hole and first_field:
            lbl, first_field = "field", False
        ax.plot(pts[:, 0], pts[:, 1], color="darkgoldenrod" if not is_hole else "firebrick",
                lw=2, zorder=2, label=lbl)
    spray_lbl = transit_lbl = True
    for pts, col in _scene_lines(field_scene, "plan"):
        spray = col[1] > 0.7 and col[0] < 0.3
        lbl = None
        if spray and spray_lbl:
            lbl, spray_lbl = "planned path (spray)", False
        elif not spray and transit_lbl:
            lbl, transit_lbl = "planned path (transit)", False
        ax.plot(pts[:, 0], pts[:, 1], color="forestgreen" if spray else "grey",
                ls="-" if spray else ":", lw=1.0, zorder=3, label=lbl)


def _draw_tracks(ax: Any, st: Series | None, sortie: np.ndarray | None,
                 summ: dict[str, Any]) -> None:
    """The true track (one colour per sortie), the base and the estimated track."""
    import matplotlib.pyplot as plt

    if st is not None and sortie is not None and sortie.max() > 1:
        # one colour per sortie; the track on the ground at the base is not drawn
        ns = int(sortie.max())
        cmap = plt.get_cmap("tab10" if ns <= 10 else "tab20")
        for k in range(1, ns + 1):
            m = sortie == k
            x = np.where(m, st["pos.x"], np.nan)
            y = np.where(m, st["pos.y"], np.nan)
            ax.plot(x, y, color=cmap((k - 1) % cmap.N), lw=1.0, zorder=5,
                    label=f"sortie {k}" if k <= 20 else None)
    elif st is not None:
        ax.plot(st["pos.x"], st["pos.y"], color="black", lw=1.2, zorder=5, label="true track")
    if summ.get("base_xy") and (summ.get("sorties") or 0) > 1:
        bx, by = summ["base_xy"]
        ax.scatter([bx], [by], marker="*", s=260, color="crimson", edgecolor="k", zorder=8,
                   label="base (refill, battery swap)")
    if st is not None:
        if np.isfinite(st["est.x"]).any():
            ax.plot(st["est.x"], st["est.y"], color="royalblue", lw=1.0, ls="--", zorder=6,
                    label="estimated track")


def _map_title(d: RunData, summ: dict[str, Any]) -> str:
    title = f"Top-down map: {d.path.parent.name}"
    if summ.get("sorties"):
        ns_ = int(summ["sorties"])
        title += (f"\n{ns_} sortie{'s' if ns_ != 1 else ''}, "
                  f"{summ.get('litres_sprayed_l', 0):.1f} L, "
                  f"{summ.get('energy_wh', 0):.0f} Wh, coverage "
                  f"{100 * (summ.get('coverage_fraction') or 0):.1f} %, off-target "
                  f"{summ.get('off_target_m2') or 0:.0f} m²")
    return title


def _plot_map(d: RunData, summ: dict[str, Any], path: Path) -> Path:
    """map.png: field, plan, sprayed area (off-target in red), GPS fixes, tracks."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 7))
    st = d.series.get("/drone/state")
    gps = d.series.get("/gps")
    field_scene = d.scenes.get("/field")
    sprayed_scene = d.scenes.get("/sprayed")
    _draw_field(ax, field_scene, sprayed_scene)
    if gps is not None and len(gps.t):
        ax.scatter(gps["pose.position.x"], gps["pose.position.y"], s=4, color="orange",
                   alpha=0.6, zorder=4, label="GPS fixes")
    sortie = sortie_of(st, d.series.get("/drone/spray")) if st is not None else None
    if sprayed_scene is not None and field_scene is not None and summ.get("off_target_m2"):
        _plot_off_target(ax, field_scene, sprayed_scene, summ)
    _draw_tracks(ax, st, sortie, summ)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("east x [m]")
    ax.set_ylabel("north y [m]")
    ax.set_title(_map_title(d, summ))
    if sortie is not None and sortie.max() > 1:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, framealpha=0.85,
                  ncol=2 if sortie.max() > 10 else 1)
    else:
        ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    ax.grid(alpha=0.3)
    return _save(fig, path, 110)


def _plot_spray(spr: Series, summ: dict[str, Any], path: Path) -> Path:
    """spray.png: tank and mass, battery (and its reserve), electrical power."""
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    axs[0].plot(spr.t, spr["tank_l"], color="tab:blue", lw=1.0, label="tank [L]")
    axs[0].plot(spr.t, spr["mass_kg"], color="k", lw=1.0, label="vehicle mass [kg]")
    axs[0].legend(fontsize=8)
    axs[1].plot(spr.t, 100 * spr["battery_frac"], color="tab:green", lw=1.0,
                label="battery left [%]")
    res = summ.get("config", {}).get("battery", {}).get("reserve_frac")
    if res is not None:
        axs[1].axhline(100 * float(res), color="firebrick", ls="--", lw=0.8, label="reserve")
    axs[1].legend(fontsize=8)
    axs[2].plot(spr.t, spr["power_w"], color="tab:orange", lw=0.6, label="power [W]")
    axs[2].legend(fontsize=8)
    axs[2].set_xlabel("sim time [s]")
    _grid(axs)
    fig.suptitle("Spray job: tank and mass, battery, electrical power")
    return _save(fig, path, 100)


def _plot_errors(st: Series, ests: dict[str, Series], path: Path) -> Path:
    """errors.png: tracking errors, and the estimators' errors, over time."""
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    t = st.t
    for k, c in (("err.x", "tab:red"), ("err.y", "tab:green"), ("err.z", "tab:blue")):
        axs[0].plot(t, st[k], color=c, lw=0.9, label=k.replace("err.", "") + " (true - ref)")
    axs[0].plot(t, st["err.horiz"], color="k", lw=1.2, label="horizontal")
    axs[0].set_ylabel("tracking error [m]")
    axs[0].legend(fontsize=8, ncol=4)
    if np.isfinite(st["est_err.horiz"]).any():
        axs[1].plot(t, st["est_err.horiz"], color="royalblue", lw=1.0,
                    label="in-loop estimate (horizontal)")
    for name, s in ests.items():
        axs[1].plot(s.t, s["err.horiz"], lw=0.8, label=name)
    axs[1].set_ylabel("estimation error [m]")
    axs[1].set_xlabel("sim time [s]")
    if axs[1].lines:
        axs[1].legend(fontsize=8, ncol=4)
    _grid(axs)
    return _save(fig, path, 110)


def _plot_controller(d: RunData, st: Series, path: Path) -> Path:
    """controller.png: the controller's signals per group, the motor commands, wind."""
    import matplotlib.pyplot as plt

    groups: dict[str, list[str]] = {}
    for k in st.fields:
        if k.startswith("ctrl."):
            rest = k[5:]
            g = rest.split(".")[0] if "." in rest else "ctrl"
            groups.setdefault(g, []).append(k)
    motors = sorted(k for k in st.fields if k == "motors")
    n = len(groups) + 2
    fig, axs = plt.subplots(n, 1, figsize=(10, 2.0 * n), sharex=True, squeeze=False)
    axs = axs[:, 0]
    for a, (g, keys) in zip(axs, groups.items(), strict=False):
        for k in keys:
            a.plot(st.t, st[k], lw=0.8, label=k[5:])
        a.set_ylabel(g)
        a.legend(fontsize=7, ncol=min(len(keys), 6), loc="upper right")
    a = axs[len(groups)]
    if motors:
        m = _motor_matrix(d)
        for j in range(m.shape[1]):
            a.plot(st.t, m[:, j], lw=0.8, label=f"motor {j}")
        a.legend(fontsize=7, ncol=4, loc="upper right")
    a.set_ylabel("motors")
    a = axs[-1]
    for k, c in (("wind.x", "tab:red"), ("wind.y", "tab:green"), ("wind.z", "tab:blue")):
        a.plot(st.t, st[k], color=c, lw=0.8, label=k)
    a.plot(st.t, st["spray"], color="k", lw=0.8, ls=":", label="spray on")
    a.set_ylabel("wind [m/s]")
    a.legend(fontsize=7, ncol=4, loc="upper right")
    a.set_xlabel("sim time [s]")
    _grid(axs)
    fig.suptitle("Controller internals, motor commands, wind")
    return _save(fig, path, 100)


#: what estimators.png compares (its caption)
GPS_CAPTION = ("GPS fix: the fix minus the true position of the point it measured (the antenna "
               "on the INS chain) at its measurement time (arrival less the latency)")
GPS_CAPTION_OLD = ("GPS fix: the fix minus the true body position at its arrival (a log "
                   "without /gps/error: the receiver's latency and the antenna offset count as "
                   "error)")
EST_CAPTION = "each filter: its estimate minus the true body position when it was logged"


def gps_fix_error(series: dict[str, Series]) -> tuple[np.ndarray, np.ndarray, str] | None:
    """(time, horizontal error, what is compared) of the run's GPS fixes, None without fixes:
    ``/gps/error`` (the fix against the truth of the point it measured at its measurement
    time, both logged with the fix), else, for an older log, ``/gps`` against ``/drone/state``
    at the fix's arrival, as :data:`GPS_CAPTION_OLD` says."""
    ge = series.get("/gps/error")
    if ge is not None and len(ge.t):
        return ge["t_meas"], ge["err.horiz"], GPS_CAPTION
    gps, st = series.get("/gps"), series.get("/drone/state")
    if gps is None or st is None or not len(gps.t):
        return None
    gx = gps["pose.position.x"] - np.interp(gps.t, st.t, st["pos.x"])
    gy = gps["pose.position.y"] - np.interp(gps.t, st.t, st["pos.y"])
    return gps.t, np.hypot(gx, gy), GPS_CAPTION_OLD


def _plot_estimators(fix: tuple[np.ndarray, np.ndarray, str] | None, ests: dict[str, Series],
                     path: Path) -> Path:
    """estimators.png: each estimator's (and the GPS fixes') horizontal error and RMSE; the
    caption says what each is compared with (:func:`gps_fix_error`)."""
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 2, figsize=(12, 4.5), gridspec_kw={"width_ratios": [3, 1]})
    names, rmse, caption = [], [], [EST_CAPTION]
    if fix is not None:
        t, gh, what = fix
        axs[0].plot(t, gh, color="orange", lw=0.6, alpha=0.7, label="GPS fix")
        names.append("GPS")
        rmse.append(float(np.sqrt(np.nanmean(gh ** 2))))
        caption.insert(0, what)
    for name, s in ests.items():
        axs[0].plot(s.t, s["err.horiz"], lw=0.9, label=name)
        names.append(name)
        rmse.append(float(np.sqrt(np.nanmean(s["err.horiz"] ** 2))))
    axs[0].set_xlabel("sim time [s]")
    axs[0].set_ylabel("horizontal position error [m]")
    axs[0].legend(fontsize=8)
    axs[0].grid(alpha=0.3)
    axs[1].bar(range(len(names)), rmse,
               color=["orange" if n == "GPS" else "tab:blue" for n in names])
    axs[1].set_xticks(range(len(names)), names, rotation=30)
    axs[1].set_ylabel("RMSE [m]")
    for i, v in enumerate(rmse):
        axs[1].text(i, v, f"{v:.2f}" if v >= 0.1 else f"{v:.3f}", ha="center",
                    va="bottom", fontsize=8)
    fig.suptitle("Estimator comparison (error against the true position)")
    fig.text(0.01, -0.02, "\n".join(caption), fontsize=8, va="top")
    return _save(fig, path, 110)


def _dose_of(d: RunData) -> tuple[np.ndarray, float, float, float] | None:
    """(L/ha (ny, nx), x0, y0, cell) of the run's dose map: ``dose.npz`` beside the log, else
    the last ``/dose`` grid of the log; None without one."""
    npz = d.path.parent / "dose.npz"
    if npz.is_file():
        try:
            with np.load(npz) as z:
                return (np.asarray(z["l_per_ha"], float), float(z["x0"]), float(z["y0"]),
                        float(z["cell"]))
        except (OSError, KeyError, ValueError):
            pass
    g = d.grids.get("/dose")
    if g is None or not g.column_count:
        return None
    a = np.frombuffer(g.data, dtype="<f4").astype(float)
    a = a.reshape(-1, g.column_count)
    return a, g.pose.position.x, g.pose.position.y, g.cell_size.x


def _plot_dose(dose: tuple[np.ndarray, float, float, float], field_scene: Any,
               summ: dict[str, Any], path: Path) -> Path:
    """The dose on the ground as a share of the target rate (0-200 %), the field's outline and
    holes over it, the dose metrics in the title."""
    import matplotlib.pyplot as plt

    a, x0, y0, cell = dose
    target = float(summ.get("config", {}).get("spray", {}).get("rate_l_per_ha", 0.0) or 0.0)
    if target <= 0:
        target = float(np.max(a)) / 2 or 1.0
    fig, ax = plt.subplots(figsize=(9, 7))
    ny, nx = a.shape
    cmap = plt.get_cmap("RdYlBu").with_extremes(bad="white")  # below 0.5 %: (next to) none
    im = ax.imshow(np.ma.masked_less(100.0 * a / target, 0.5), origin="lower", cmap=cmap,
                   vmin=0.0, vmax=200.0,
                   extent=(x0, x0 + nx * cell, y0, y0 + ny * cell), interpolation="nearest")
    fig.colorbar(im, ax=ax, shrink=0.8, label=f"dose [% of {target:g} L/ha]")
    if field_scene is not None:
        for pts, _col in _scene_lines(field_scene, "field"):
            ax.plot(pts[:, 0], pts[:, 1], color="k", lw=1.2)
    ax.set_aspect("equal")
    ax.set_xlabel("east x [m]")
    ax.set_ylabel("north y [m]")

    def pct(k: str) -> str:
        v = summ.get(k)
        return "–" if v is None else f"{100 * v:.1f} %"

    ax.set_title(f"Dose on the ground: CV {pct('dose_cv')}, under-dosed "
                 f"{pct('underdosed_fraction')}, over-dosed {pct('overdosed_fraction')}\n"
                 "off the field "
                 f"{pct('offtarget_deposit_fraction')} of sprayed, drift {pct('drift_fraction')}")
    return _save(fig, path, 110)


def _plot_off_target(ax: Any, field_scene: Any, sprayed_scene: Any,
                     summ: dict[str, Any]) -> None:
    """Shade the sprayed area beyond the field (and its buffer) or over holes, in red."""
    import shapely

    sprayed = shapely.union_all([shapely.Polygon(t) for t in
                                 _scene_triangles(sprayed_scene, "sprayed")]).buffer(0)
    field = shapely.union_all([shapely.Polygon(t) for t in
                               _scene_triangles(field_scene, "field")]).buffer(0)
    buf = float(summ.get("config", {}).get("spray", {}).get("offtarget_buffer_m", 0.0) or 0.0)
    rings = _scene_lines(field_scene, "field")
    outer = shapely.Polygon(rings[0][0][:, :2]) if rings else field
    off = sprayed.difference(outer.buffer(buf, join_style="mitre"))
    for pts, _c in rings[1:]:
        hole = shapely.Polygon(pts[:, :2]).buffer(-buf, join_style="mitre")
        off = off.union(sprayed.intersection(hole))
    geoms = getattr(off, "geoms", [off])
    first = True
    for g in geoms:
        if g.is_empty or g.geom_type != "Polygon":
            continue
        x, y = g.exterior.xy
        ax.fill(x, y, color="red", alpha=0.7, zorder=7, lw=0,
                label="off-target spray" if first else None)
        first = False


def _motor_matrix(d: RunData) -> np.ndarray:
    """Motor commands as (N, n_motors) (the flattened list column holds lists)."""
    st = d.series["/drone/state"]
    m = st.fields.get("motors")
    if m is None:
        return np.zeros((len(st.t), 0))
    return np.atleast_2d(np.asarray(m, dtype=float)).reshape(len(st.t), -1)
