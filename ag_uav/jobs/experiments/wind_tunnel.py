"""``ag-uav experiment wind-tunnel``: the deposition law against a measured UAV wind-tunnel trial.

The trial (Grant, Perine, Abi-Akar, Lane, Kent, Mohler, Scott & Ritter 2022, "A Wind-Tunnel
Assessment of Parameters That May Impact Spray Drift during UAV Pesticide Application",
*Drones* 6(8):204, doi 10.3390/drones6080204; data published by the authors "as-is"): a spraying
UAV hovers freely in a wind tunnel; glass slides on the tunnel floor at 14 positions from 3 m
upwind to 20 m downwind catch the deposit (``Dep_flux``, ng/cm²); tunnel wind 1.5 / 3 / 4.5 m/s;
nozzles XR11001 (fine), TT11001 (medium) and Lechler IDK 11001 (coarse); initial payload 2 or
10 L; three replicates. The product ships the 2 L rows in the authors' column layout
(``ag_uav/data/grant2022_deposition_slides_2L.csv``); ``--measured FILE`` reads any CSV in that
layout (another payload's rows, say).

The model: the vehicle hovers at the trial's height in the tunnel's uniform wind (tilted into it
so thrust balances weight and drag: :func:`ag_uav.world.pattern.pass_states` at zero ground
speed), each nozzle sprays the measured rotor-on spectrum of its nozzle and payload
(:data:`SPECTRA_ON`), and every droplet class's landing law is the loop's
(:func:`ag_uav.world.deposition.footprints`, the same compiled function). The deposit at a slide
is evaluated analytically, as the drift trial does (:mod:`.drift`): per (nozzle, class) the
wake part a Gaussian, the escaped part the inverse-Gaussian first passage along the wind blurred
by the wake's edge ring, Gaussian across it; the tunnel's side walls reflect what reaches them
(images at ±``--tunnel-width``). The tunnel's uniform flow is the log-law with a smooth floor
(z₀ = ``--floor-roughness``): the mean over the layer is ~0.9 of the wind at the vehicle and u*
is small. Both measured and model deposits are normalised by the condition's total over the 14
positions (the slide's area and the sprayed volume drop out).

**Assumed (not in the published files; the paper's method section could not be read with the
search tools):** the vehicle (an octocopter of the DJI Agras MG-1P class, the 10 L payload's
class: 8 rotors of 0.533 m, 1.5 m wheelbase, 13.8 kg with its battery and an empty tank, four
nozzles under four rotors 0.35 m below the rotor plane; DJI's MG-1P figures as recalled, not
verified), the nozzle height above the slides
(``--height``, 2 m; the anemometers at 1.2 and 1.8 m have no reading at the vehicle's station),
the tunnel width (``--tunnel-width``, 4.2 m: the anemometers stand 0.99, 2.1 and 3.3 m across)
and the vehicle's drag. ``--height`` and ``--tunnel-width`` show their effect.

``--law hover`` runs the hover law (:data:`ag_uav.world.deposition_config.HOVER_LAW`: the merged
jet, the impaction cut, the outwash as a radial wall jet, the impinging jet's stagnation zone,
and the escape share ε₀ = 0.6 from one calibration on the 2 L rows); the default law is the
product's.

Writes into ``--out`` (``runs/experiment-wind-tunnel``): ``wind_tunnel.csv`` (one row per
condition and position: wind m/s, nozzle, payload L, distance m, measured and model deposit, both
normalised), ``wind_tunnel.png`` (the profiles: model line, measured replicates as points) and
``wind_tunnel.md`` (per condition: the downwind fraction, the share of the total at ≥ 2 m,
measured and modelled, their ratio, the in-swath peak position, and the median
|log10(model / measured)| of the normalised deposit over 2–20 m).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
from importlib import resources
from pathlib import Path

import numpy as np

from ...world.deposition import DepositionConfig, footprints, pack_input
from ...world.deposition_config import LAWS
from ...world.pattern import pass_states
from . import name_axis, number_axis, toml_overrides

NAME = "wind-tunnel"
HELP = ("the deposition law against a measured UAV wind-tunnel trial (Grant et al. 2022, "
        "Drones 6(8):204): deposits at 14 slides from -3 to 20 m, three nozzles, three winds")

#: the trial's slide positions (m from the vehicle, + downwind)
POSITIONS = (-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 12.0, 16.0, 20.0)
#: rotor-on droplet spectra (Dv10, Dv50, Dv90 µm), means of the three replicates measured under
#: the hovering UAV (Grant et al. 2022, ``droplet_spectra.csv`` "On, 2L" / "On, 10L")
SPECTRA_ON = {
    ("fine", 2.0): (82.9, 148.0, 229.3), ("fine", 10.0): (88.1, 154.2, 239.8),
    ("medium", 2.0): (182.5, 334.5, 526.9), ("medium", 10.0): (181.6, 336.6, 526.7),
    ("coarse", 2.0): (239.8, 482.4, 766.1), ("coarse", 10.0): (242.6, 470.8, 749.1),
}
NOZZLES = ("fine", "medium", "coarse")
DEFAULT_MEASURED = "grant2022_deposition_slides_2L.csv"
DX = 0.02               # m, the grid the escaped part's along-wind density is evaluated on


@dataclasses.dataclass(frozen=True)
class Trial:
    """The hovering vehicle and the tunnel (assumptions in the module docstring)."""

    height_m: float = 2.0              # nozzles above the slides
    empty_kg: float = 13.8             # vehicle with battery, tank empty
    n_rotors: int = 8
    rotor_d_m: float = 0.533
    arm_m: float = 0.75                # rotor hub radius from the centre (1.5 m wheelbase)
    nozzle_z_m: float = -0.35          # nozzles below the body origin
    tunnel_width_m: float = 4.2        # side walls at ± half of it (0: open air)
    floor_roughness_m: float = 1e-4    # the smooth tunnel floor's z₀
    drag_lin: float = 0.25
    drag_quad: float = 0.18

    def nozzles(self) -> tuple:
        """Four nozzles under the rotors at ±45° and ±135° (body frame, x into the wind's
        direction of travel)."""
        r = self.arm_m / math.sqrt(2.0)
        return tuple((sx * r, sy * r, self.nozzle_z_m)
                     for sx, sy in ((1, -1), (1, 1), (-1, 1), (-1, -1)))


def nozzle_class(label: str) -> str:
    """``"fine"``, ``"medium"`` or ``"coarse"`` from the published nozzle label."""
    for n in NOZZLES:
        if f"({n})" in label.lower() or label.strip().lower() == n:
            return n
    raise ValueError(f"nozzle {label!r}: expected a label naming (fine), (medium) or (coarse)")


def read_measured(path: str | None) -> dict:
    """Measured deposits by condition (wind, nozzle, payload) -> {distance: [replicates]} from
    a CSV in the published layout (columns Distance, Nozzle_DSD, Volume, WS.m_s, Dep_flux)."""
    if path is None:
        text = resources.files("ag_uav.data").joinpath(DEFAULT_MEASURED).read_text()
    else:
        text = Path(path).read_text()
    out: dict = {}
    rows = list(csv.DictReader(text.splitlines()))
    need = ("Distance", "Nozzle_DSD", "Volume", "WS.m_s", "Dep_flux")
    if not rows or any(k not in rows[0] for k in need):
        raise ValueError(f"--measured {path}: need the columns {', '.join(need)}")
    for r in rows:
        key = (float(r["WS.m_s"]), nozzle_class(r["Nozzle_DSD"]), float(r["Volume"]))
        out.setdefault(key, {}).setdefault(float(r["Distance"]), []).append(float(r["Dep_flux"]))
    return out


def ig_pdf(t: np.ndarray, mu: float, lam: float) -> np.ndarray:
    """Density of the inverse Gaussian IG(μ, λ) (the first-passage time of the escaped part,
    as the drift trial evaluates it; ``scipy.stats.invgauss``), 0 for t ≤ 0."""
    from scipy.stats import invgauss

    out = np.zeros_like(t)
    pos = t > 0
    out[pos] = invgauss.pdf(t[pos], mu / lam, scale=lam)
    return out


def _wall_gauss(yc: float, var: float, width: float) -> float:
    """Density at y = 0 of a Gaussian across the tunnel (mean yc, variance var), reflected by
    walls at ±width/2 (method of images; width 0: no walls)."""
    s = math.sqrt(var)
    c = 1.0 / (s * math.sqrt(2.0 * math.pi))
    if width <= 0.0:
        return c * math.exp(-0.5 * (yc / s) ** 2)
    tot = 0.0
    for j in range(-6, 7):
        for y in (yc + 2 * j * width, (2 * j + 1) * width - yc):
            tot += math.exp(-0.5 * (y / s) ** 2)
    return c * tot


def model_profile(cfg: DepositionConfig, trial: Trial, wind: float, payload_l: float,
                  x: np.ndarray) -> tuple[np.ndarray, dict]:
    """Deposit density (share of the sprayed tracer per m², on the tunnel's centre line) at the
    positions ``x`` (m downwind of the vehicle), and the footprints the loop's law gave."""
    mass = trial.empty_kg + payload_l * cfg.liquid_density / 1000.0
    R, thrust = pass_states(0.0, trial.height_m, 0.0, mass, trial.drag_lin, trial.drag_quad,
                            wind_x=wind)
    Rm = R.reshape(3, 3)
    noz = np.asarray(cfg.nozzle_xyz_m, float).reshape(-1, 3)
    pz = trial.height_m - float(np.mean(noz @ Rm[2]))
    inp = pack_input([0.0, 0.0, pz], [0.0, 0.0, 0.0], R, thrust, [wind, 0.0, 0.0], 1)
    fp = footprints(cfg, inp)
    xy = noz @ Rm[:2].T                               # nozzle offsets in the world frame
    share = np.asarray(cfg.nozzle_share, float)
    grid = np.arange(-10.0, max(x.max(), 0.0) + 60.0, DX)
    edge2 = np.max(np.hypot(noz[:, 0], noz[:, 1])) + 0.5 * cfg.rotor_diameter_m
    w = trial.tunnel_width_m
    dens = np.zeros(len(x))
    for k in range(len(fp["frac"])):
        f = fp["frac"][k]
        # the escaped part's release spread: the sheet, a rotary atomiser's throw, the edge ring
        s_e = math.sqrt(cfg.release_sigma_m ** 2 + fp["throw"][k] + 0.5 * edge2 ** 2)
        kx = np.arange(-5 * s_e, 5 * s_e + DX, DX)
        kern = np.exp(-0.5 * (kx / s_e) ** 2)
        kern /= kern.sum()
        esc_x = None
        ux = fp["ux"][k]
        land = fp["esc"][k] * (1.0 - fp["pair"][k])
        if land > 0.0 and ux > 1e-9:
            x0 = fp["ex"][k] - ux * fp["mut"][k]       # where the escaped part starts to settle
            esc_x = np.convolve(ig_pdf((grid - x0) / ux, fp["mut"][k], fp["lamt"][k]) / ux,
                                kern, mode="same")
        for m in range(len(share)):
            xm, ym = xy[m]
            wv = fp["wvar"][k]
            gx = np.exp(-0.5 * (x - xm - fp["wx"][k]) ** 2 / wv) / math.sqrt(2 * math.pi * wv)
            dens += share[m] * f * fp["wake"][k] * gx * _wall_gauss(ym + fp["wy"][k], wv, w)
            if fp["vort"][k] > 0.0:                    # the trailing vortex pair's part
                vv = fp["vvx"][k]
                gv = np.exp(-0.5 * (x - xm - fp["vx"][k]) ** 2 / vv) / math.sqrt(2 * math.pi * vv)
                dens += (share[m] * f * fp["vort"][k] * gv
                         * _wall_gauss(ym + fp["vy"][k], fp["vvy"][k], w))
            if esc_x is not None:
                ex = np.interp(x - xm, grid, esc_x, left=0.0, right=0.0)
                dens += share[m] * f * land * ex * _wall_gauss(ym + fp["ey"][k], fp["evy"][k], w)
    return dens, fp


def config_for(base: DepositionConfig, trial: Trial, nozzle: str, payload_l: float
               ) -> DepositionConfig:
    """The deposition config of one condition: the trial's rotors and nozzles, the measured
    rotor-on spectrum of the nozzle at the payload (the nearest payload measured)."""
    pay = min((p for (n, p) in SPECTRA_ON if n == nozzle), key=lambda p: abs(p - payload_l))
    dv = SPECTRA_ON[(nozzle, pay)]
    return dataclasses.replace(base, dv10_um=dv[0], dv50_um=dv[1], dv90_um=dv[2],
                               n_rotors=trial.n_rotors, rotor_diameter_m=trial.rotor_d_m,
                               rotor_arm_m=trial.arm_m,
                               nozzle_xyz_m=trial.nozzles(), nozzle_share=(0.25,) * 4,
                               roughness_m=trial.floor_roughness_m)


def compare(base: DepositionConfig, trial: Trial, measured: dict, winds: list[float] | None,
            nozzles: list[str] | None, payloads: list[float] | None
            ) -> tuple[list[dict], list[dict]]:
    """Every selected condition of ``measured``: rows per position (normalised deposits) and
    one summary per condition (downwind fraction, peak position, log error over 2-20 m)."""
    rows, summ = [], []
    for key in sorted(measured, key=lambda k: (k[0], NOZZLES.index(k[1]), k[2])):
        wind, noz, pay = key
        if ((winds and not any(abs(wind - w) < 1e-6 for w in winds))
                or (nozzles and noz not in nozzles)
                or (payloads and not any(abs(pay - p) < 1e-6 for p in payloads))):
            continue
        reps = measured[key]
        pos = np.asarray([d for d in POSITIONS if d in reps])
        meas_mean = np.asarray([np.mean(reps[d]) for d in pos])
        total = meas_mean.sum()
        dens, _ = model_profile(config_for(base, trial, noz, pay), trial, wind, pay, pos)
        model = dens / dens.sum()
        meas = meas_mean / total
        for i, d in enumerate(pos):
            rows.append({"wind_mps": wind, "nozzle": noz, "payload_l": pay, "distance_m": d,
                         "measured_norm": float(meas[i]), "model_norm": float(model[i]),
                         "measured_reps_norm": ";".join(f"{v / total:.6g}" for v in reps[d])})
        summ.append(summary(wind, noz, pay, pos, meas, model) | replicate_range(reps, pos))
    return rows, summ


def replicate_range(reps: dict, pos: np.ndarray) -> dict:
    """The data's own spread: the downwind fraction (share at ≥ 2 m) of each replicate on its
    own total, lowest and highest."""
    n = min(len(reps[d]) for d in pos)
    fr = [sum(reps[d][r] for d in pos if d >= 2.0) / sum(reps[d][r] for d in pos)
          for r in range(n)]
    return {"downwind_reps_lo": float(min(fr)), "downwind_reps_hi": float(max(fr))}


def summary(wind: float, noz: str, pay: float, pos: np.ndarray, meas: np.ndarray,
            model: np.ndarray) -> dict:
    """Downwind fraction (share at ≥ 2 m), in-swath peak position (the largest deposit), and
    the median |log10(model / measured)| over 2-20 m (positions where both are > 0)."""
    dw = pos >= 2.0
    far = dw & (meas > 0) & (model > 0)
    err = (float(np.median(np.abs(np.log10(model[far] / meas[far])))) if far.any()
           else math.nan)
    fm, fmod = float(meas[dw].sum()), float(model[dw].sum())
    return {"wind_mps": wind, "nozzle": noz, "payload_l": pay, "downwind_measured": fm,
            "downwind_model": fmod, "ratio": fmod / fm if fm > 0 else math.inf,
            "peak_measured_m": float(pos[int(np.argmax(meas))]),
            "peak_model_m": float(pos[int(np.argmax(model))]), "median_abs_log10_2_20m": err}


def checks(rows: list[dict], summ: list[dict]) -> list[list[str]]:
    """The comparison's checks, each a row (check, result): the downwind fraction within a
    factor 2, its rise with wind per nozzle and its fall from fine to coarse at each wind
    (where the measured means do), the medium nozzle's peak moving downwind and within 1 m of
    the measured, and per wind the median |log10(model / measured)| over 2-20 m (all nozzles'
    positions pooled)."""
    out = []
    ok2 = [s for s in summ if 0.5 <= s["ratio"] <= 2.0]
    out.append(["downwind fraction within a factor 2", f"{len(ok2)} of {len(summ)}"])
    by = {(s["wind_mps"], s["nozzle"], s["payload_l"]): s for s in summ}
    winds = sorted({k[0] for k in by})
    for noz in NOZZLES:
        for pay in sorted({k[2] for k in by}):
            seq = [by[(w, noz, pay)] for w in winds if (w, noz, pay) in by]
            if len(seq) < 2:
                continue
            mrise = all(b["downwind_measured"] > a["downwind_measured"]
                        for a, b in zip(seq, seq[1:], strict=False))
            rise = all(b["downwind_model"] > a["downwind_model"]
                       for a, b in zip(seq, seq[1:], strict=False))
            out.append([f"rises with wind, {noz} {pay:g} L",
                        f"model {'yes' if rise else 'no'}, measured {'yes' if mrise else 'no'}"])
    for w in winds:
        seq = [by[k] for n in NOZZLES for k in by if k[0] == w and k[1] == n]
        if len(seq) == 3:
            mfall = all(b["downwind_measured"] < a["downwind_measured"]
                        for a, b in zip(seq, seq[1:], strict=False))
            fall = all(b["downwind_model"] < a["downwind_model"]
                       for a, b in zip(seq, seq[1:], strict=False))
            out.append([f"falls fine -> coarse at {w:g} m/s",
                        f"model {'yes' if fall else 'no'}, measured {'yes' if mfall else 'no'}"])
        med = [by[k] for k in by if k[0] == w and k[1] == "medium"]
        if med:
            m = med[0]
            out.append([f"medium peak at {w:g} m/s (model, measured)",
                        f"{m['peak_model_m']:+g} m, {m['peak_measured_m']:+g} m"])
        err = [abs(math.log10(r["model_norm"] / r["measured_norm"])) for r in rows
               if r["wind_mps"] == w and 2.0 <= r["distance_m"] <= 20.0
               and r["model_norm"] > 0 and r["measured_norm"] > 0]
        if err:
            out.append([f"median |log10(model / measured)| 2-20 m at {w:g} m/s",
                        f"{float(np.median(err)):.2f}"])
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    t = Trial()
    p.add_argument("--measured", default=None, metavar="FILE",
                   help="measured deposits, a CSV in the published column layout (default: the "
                        "2 L rows of Grant et al. 2022 shipped with the product)")
    p.add_argument("--payloads", default=None,
                   help="initial payloads (L) to compare (default: all)")
    p.add_argument("--winds", default=None, help="tunnel winds (m/s) to compare (default: all)")
    p.add_argument("--nozzles", default=None, help="fine, medium, coarse (default: all)")
    p.add_argument("--height", type=float, default=t.height_m,
                   help="nozzle height above the slides (m; assumed)")
    p.add_argument("--tunnel-width", type=float, default=t.tunnel_width_m,
                   help="tunnel width (m; assumed); 0: no side walls")
    p.add_argument("--law", default="default", choices=sorted(LAWS),
                   help="the deposition law: default (the outwash layer calibrated on the T40), "
                        "hover (the wall jet and the impinging jet; ε₀ from these rows) or wake "
                        "(hover and the forward-flight vortex pair)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a DepositionConfig field (e.g. wake_escape=0.6)")
    p.add_argument("--out", default="runs/experiment-wind-tunnel", metavar="DIR",
                   help="output folder")


def _plot(path: Path, rows: list[dict], summ: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(summ)
    cols = min(3, n)
    nr = (n + cols - 1) // cols
    fig, axes = plt.subplots(nr, cols, figsize=(4.2 * cols, 3.2 * nr), squeeze=False)
    for ax, s in zip(axes.ravel(), summ, strict=False):
        rr = [r for r in rows if (r["wind_mps"], r["nozzle"], r["payload_l"])
              == (s["wind_mps"], s["nozzle"], s["payload_l"])]
        x = [r["distance_m"] for r in rr]
        ax.plot(x, [max(r["model_norm"], 1e-6) for r in rr], "-", color="C0", label="model")
        for r in rr:
            reps = [float(v) for v in r["measured_reps_norm"].split(";")]
            ax.plot([r["distance_m"]] * len(reps), np.maximum(reps, 1e-6), "o", ms=3,
                    color="C3", alpha=0.7)
        ax.plot([], [], "o", ms=3, color="C3", label="measured (replicates)")
        ax.set_yscale("log")
        ax.set_ylim(1e-5, 1.0)
        ax.set_title(f"{s['wind_mps']:g} m/s, {s['nozzle']}, {s['payload_l']:g} L", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7)
    fig.supxlabel("distance downwind of the hovering UAV (m)")
    fig.supylabel("deposit / condition's total over the 14 slides")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def table(summ: list[dict]) -> tuple[list[str], list[list[str]]]:
    header = ["wind (m/s)", "nozzle", "payload (L)", "downwind measured",
              "its replicates (lo-hi)", "downwind model", "model / measured",
              "peak measured (m)", "peak model (m)", "median |log10| 2-20 m"]
    return header, [[f"{s['wind_mps']:g}", s["nozzle"], f"{s['payload_l']:g}",
                     f"{s['downwind_measured']:.3f}",
                     f"{s['downwind_reps_lo']:.3f}-{s['downwind_reps_hi']:.3f}",
                     f"{s['downwind_model']:.3f}",
                     f"{s['ratio']:.2f}", f"{s['peak_measured_m']:+g}",
                     f"{s['peak_model_m']:+g}", f"{s['median_abs_log10_2_20m']:.2f}"]
                    for s in summ]


def main(args: argparse.Namespace) -> int:
    from ..batch import markdown_table, print_table
    from . import write_csv

    try:
        over = toml_overrides(args.set)
        bad_keys = [k for k in over if k not in DepositionConfig.__dataclass_fields__]
        if bad_keys:
            raise ValueError(f"--set {bad_keys[0]}: not a DepositionConfig field")
        base = DepositionConfig(**{**LAWS[args.law], **over})
        nozzles = None if args.nozzles is None else name_axis("--nozzles", args.nozzles, NOZZLES)
        if not 0.3 <= args.height <= 10.0:
            raise ValueError(f"--height {args.height:g}: must be within [0.3, 10] m")
        if args.tunnel_width < 0.0:
            raise ValueError(f"--tunnel-width {args.tunnel_width:g}: must be >= 0 (0: no walls)")
        trial = Trial(height_m=args.height, tunnel_width_m=args.tunnel_width)
        measured = read_measured(args.measured)
        winds = (None if args.winds is None
                 else number_axis("--winds", args.winds, lo=0.0, lo_open=True))
        pays = (None if args.payloads is None
                else number_axis("--payloads", args.payloads, lo=0.0, lo_open=True))
    except (ValueError, TypeError, OSError, KeyError) as e:
        print(f"error: {e}")
        return 2
    rows, summ = compare(base, trial, measured, winds, nozzles, pays)
    if not summ:
        print("error: no measured condition matches --winds/--nozzles/--payloads")
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "wind_tunnel.csv", rows)
    _plot(out / "wind_tunnel.png", rows, summ)
    header, tab = table(summ)
    src = args.measured or f"ag_uav/data/{DEFAULT_MEASURED} (Grant et al. 2022, Drones 6(8):204)"
    print_table(header, tab, f"Wind tunnel: model against {src}")
    ck = checks(rows, summ)
    print_table(["check", "result"], ck, "Checks")
    (out / "wind_tunnel.md").write_text(
        f"Measured: {src}. Downwind = share of the condition's total at >= 2 m; peak = the "
        "position of the largest deposit.\n\n" + markdown_table(header, tab) + "\n"
        + markdown_table(["check", "result"], ck))
    print(f"wrote {out / 'wind_tunnel.csv'}, {out / 'wind_tunnel.png'}, {out / 'wind_tunnel.md'}")
    return 0
