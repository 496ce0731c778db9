"""Figures of a controller config's fuzzy cores (``ag-uav plot --controller CONFIG``).

- ``fou_<axis>.png``: the N / Z / P input sets of each axis group, upper and lower membership
  functions (scikit-fuzzy ``trimf``, :mod:`controllers.fuzzy_sets`) and the footprint of
  uncertainty between them;
- ``surfaces_<axis>.png``: the control surfaces Φ(E, dE) on [-1, 1]² of the IT2 core with each
  type reducer (KM, NT, BMM, zeta), the type-1 core and the linear "PID" core, and their
  differences. The PID core is the plane Φ = G·(E + dE) with G the small-signal slope of the
  configured core: a fuzzy PID with a linear core *is* a PID
  (Kp = G(K0 Ke + K1 Kd), Ki = G K1 Ke, Kd = G K0 Kd), so "configured − PID" shows what the
  fuzzy nonlinearity adds; "T1 − plane" is the type-1 core against its own plane c_m(E + dE).

Every core uses the axis group's own α, c_m and ζ from the config. :func:`surface_stats`
returns the maximum differences on an 81 × 81 grid (printed by the command).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from controllers.fuzzy import REDUCERS, IT2FuzzyPD, T1FuzzyPD

N_GRID = 81


def cores(g: Any) -> dict[str, Any]:
    """IT2 cores (every reducer), the T1 core and the slope of the configured core."""
    out: dict[str, Any] = {f"IT2-{r.upper() if r != 'zeta' else 'zeta'}":
                           IT2FuzzyPD(alpha=g.alpha, cm=g.cm, reducer=r, zeta=g.zeta)
                           for r in REDUCERS}
    out["T1"] = T1FuzzyPD(cm=g.cm)
    return out


def surfaces(g: Any, reducer: str, ctype: str, n: int = N_GRID
             ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], float]:
    """(E, dE, {name: Φ grid}, G) on an n × n grid; "PID" is the plane G (E + dE) where G is
    the small-signal slope of the configured core (``ctype``/``reducer``)."""
    x = np.linspace(-1.0, 1.0, n)
    E, D = np.meshgrid(x, x, indexing="xy")
    cs = cores(g)
    out = {k: c.phi_grid(E, D) for k, c in cs.items()}
    if ctype == "t1-fpid" or ctype == "pid":
        G = float(g.cm)
    else:
        G = float(IT2FuzzyPD(alpha=g.alpha, cm=g.cm, reducer=reducer,
                             zeta=g.zeta).small_signal_gain())
    out["PID"] = G * (E + D)
    return E, D, out, G


def surface_stats(g: Any, reducer: str = "km", ctype: str = "it2-fpid") -> dict[str, float]:
    """Max |difference| on the grid: each IT2 reducer vs T1, T1 vs its linear plane."""
    _, _, s, _ = surfaces(g, reducer, ctype)
    st = {f"max|{k} - T1|": float(np.max(np.abs(v - s["T1"])))
          for k, v in s.items() if k.startswith("IT2")}
    E, D = np.meshgrid(np.linspace(-1, 1, N_GRID), np.linspace(-1, 1, N_GRID))
    st["max|T1 - c_m(E+dE)|"] = float(np.max(np.abs(s["T1"] - g.cm * (E + D))))
    return st


def _quantize(path: Path, colors: int = 96) -> None:
    """Palette PNG (small files for the docs); the figure is unchanged to the eye."""
    from PIL import Image

    with Image.open(path) as im:
        q = im.convert("RGB").quantize(colors=colors)
    q.save(path, optimize=True)


def _save_png(fig: Any, path: Path, **kw: Any) -> Path:
    """Save ``fig`` as a palette PNG at ``path``, atomically (ag_uav.record.atomic); close it."""
    import matplotlib.pyplot as plt

    from ..record.atomic import atomic_path

    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", **kw)
            _quantize(tmp)
    finally:
        plt.close(fig)
    return Path(path)


def plot_fou(g: Any, title: str, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from controllers.fuzzy_sets import SET_NAMES, lower_memberships, upper_memberships

    x = np.linspace(-1.0, 1.0, 401)
    up, lo = upper_memberships(x), lower_memberships(x, alpha=g.alpha)
    fig, ax = plt.subplots(figsize=(6.0, 2.9))
    for k, s in enumerate(SET_NAMES):
        ax.fill_between(x, lo[s], up[s], color=f"C{k}", alpha=0.25)
        ax.plot(x, up[s], color=f"C{k}", lw=1.4, label=f"{s} upper")
        ax.plot(x, lo[s], color=f"C{k}", lw=1.0, ls="--", label=f"{s} lower")
    ax.set_xlabel("E or dE (normalised)")
    ax.set_ylabel("membership")
    ax.set_title(f"{title}: footprint of uncertainty\nα = {g.alpha:.3g}: "
                 f"h_Z = {g.alpha:.3g}, h_N = h_P = {1 - g.alpha:.3g}", fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    return _save_png(fig, path, dpi=80)


def plot_surfaces(g: Any, reducer: str, ctype: str, title: str, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    E, D, s, G = surfaces(g, reducer, ctype)
    names = [k for k in s if k.startswith("IT2")] + ["T1", "PID"]
    diffs = [(f"{k} − T1", s[k] - s["T1"]) for k in names if k.startswith("IT2")]
    diffs += [("T1 − plane c_m(E+dE)", s["T1"] - g.cm * (E + D)),
              (f"IT2-{reducer.upper() if reducer != 'zeta' else 'zeta'} − PID",
               s[f"IT2-{reducer.upper() if reducer != 'zeta' else 'zeta'}"] - s["PID"])]
    fig, axs = plt.subplots(2, len(names), figsize=(2.3 * len(names), 4.8))
    ext = (-1, 1, -1, 1)
    vmax = 1.0  # |Φ| <= 1 for the fuzzy cores; the PID plane saturates the colour scale
    for ax, k in zip(axs[0], names, strict=True):
        im = ax.imshow(s[k], origin="lower", extent=ext, cmap="RdBu_r", vmin=-vmax, vmax=vmax)
        ax.contour(E, D, s[k], levels=9, colors="k", linewidths=0.4)
        lab = k if k != "PID" else f"PID plane (G = {G:.3g})"
        ax.set_title(lab, fontsize=7)
        ax.tick_params(labelsize=6)
    fig.colorbar(im, ax=axs[0].tolist(), shrink=0.8).ax.tick_params(labelsize=6)
    for ax, (lab, d) in zip(axs[1], diffs, strict=True):
        dmax = max(1e-9, float(np.max(np.abs(d))))  # each panel on its own scale
        ax.imshow(d, origin="lower", extent=ext, cmap="PuOr", vmin=-dmax, vmax=dmax)
        ax.set_title(f"{lab}\nmax |·| {np.max(np.abs(d)):.3g} (own scale)", fontsize=6)
        ax.tick_params(labelsize=6)
    for ax in axs[:, 0]:
        ax.set_ylabel("dE", fontsize=7)
    for ax in axs[1]:
        ax.set_xlabel("E", fontsize=7)
    fig.suptitle(f"{title}: Φ(E, dE), α = {g.alpha:.3g}, c_m = {g.cm:.3g}, ζ = {g.zeta:.3g}",
                 fontsize=8)
    return _save_png(fig, path, dpi=72, bbox_inches="tight")


def plot_controller(config_path: str | None, out: str | Path,
                    overrides: dict[str, Any] | None = None) -> tuple[list[Path], dict[str, Any]]:
    """Write the FOU and surface figures of a controller config; returns (paths, stats)."""
    from ..config import load_config

    cfg = load_config(config_path, overrides)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ctype = cfg.controller.type
    paths: list[Path] = []
    stats: dict[str, Any] = {}
    for axis in ("xy", "z"):
        g = getattr(cfg.controller, axis)
        title = f"{ctype} [{axis}]"
        paths.append(plot_fou(g, title, out / f"fou_{axis}.png"))
        paths.append(plot_surfaces(g, g.reducer, ctype, title, out / f"surfaces_{axis}.png"))
        stats[axis] = surface_stats(g, g.reducer, ctype)
    return paths, stats
