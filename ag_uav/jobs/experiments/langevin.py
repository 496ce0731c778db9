"""``ag-uav experiment langevin``: the kfuea paper's tracking experiment (its §3, Figs. 4-8).

Setup (eqs 42-45, with what the paper leaves open filled in and stated):

- State θ = (θ¹, θ²), two independent double-well Langevin equations, Euler–Maruyama with
  Δt = 0.01 (the paper writes Δθ = drift + √2 u without Δt; dθ = drift dt + √2 dW is the
  standard reading)::

      θⁱ_{n+1} = θⁱ_n + Δt [−½ (θⁱ_n − cᵢ)³ + (θⁱ_n − cᵢ)] + √(2Δt) uⁱ_n,   c = (1, 6)

  (wells at cᵢ ± √2, barrier 0.5), θ_0 ~ N(c, I), 1000 steps per trajectory.
- Measurement (eqs 44-45): azimuth φ = atan2(θ¹, θ²) and range r = ‖θ‖ (the paper prints
  √(θ¹² + θ¹²), a typo), each plus white Gaussian noise.  SNR (undefined in the paper) is taken
  per channel as var(clean channel over the trajectory) / noise variance, so σ²_ch =
  var(ζ_ch) / SNR; swept over ``--snr`` (the paper names 1, 0.67 and 0.18).
- Score (the paper's nRMSE, undefined): per channel RMSE of the clean-measurement estimate ẑ
  against ζ = h(θ), divided by the standard deviation of ζ over the trajectory; mean ± sd over
  ``--runs`` trajectories (paper: 50).  "Meas" (the raw measurement) is the paper's upper bound.

Filters (all told the true model, Δt, diffusion and noise variances; prior N(c, 2.5 I)):

- ``EKF``: drift and range/azimuth linearised at the estimate (Jacobians below), azimuth
  innovation wrapped to (−π, π].  Written here (small step), not a library dependency.
- ``IF-EKF``: the same linearisation with :class:`estimators.information.InformationKF`'s
  update (the kfuea eqs 10-14).  It must equal the EKF (printed: max difference).
- ``SDN-EKF``: :class:`estimators.information.StateDependentNoiseKF`'s eq 25 noise on the EKF:
  Q_eff = 2Δt I + δ̄ (P + x̃ x̃ᵀ) δ̄ᵀ, x̃ = θ̂ − c the distance from the potential's centre (the
  paper's linearisation point), δ̄ = β √Δt I, β = ``--beta`` (0.5, set a priori): the drift is
  cubic in x̃, so the model is trusted less far from the centre.
- ``PF``: bootstrap particle filter (:mod:`estimators.particle`), ``--particles`` (500),
  systematic resampling at ESS < N/2; ẑ = Σ wᵢ h(θᵢ).

The paper's KFUEA (eqs 31-41) and DMK (diffusion-maps KF) are not implemented: KFUEA's
operators are undefined (see docs/langevin.md), DMK is a different paper's method.  The paper
reports nRMSE only as plots (Figs. 4, 6) with no numbers; its claim is the ordering
KFUEA < PF < DMK-noisy at every SNR.

Writes ``results.csv`` (one row per run, SNR and filter), ``summary.csv`` and ``langevin.png``
to ``--out``.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from estimators.information import InformationKF, StateDependentNoiseKF
from estimators.particle import ParticleFilter

from . import write_csv

NAME = "langevin"
HELP = ("kfuea paper §3: double-well Langevin target seen as range + azimuth, nRMSE vs SNR for "
        "EKF, information-form EKF, state-dependent-noise EKF and a particle filter")

FILTERS = ("EKF", "IF-EKF", "SDN-EKF", "PF", "Meas")
CHANNELS = ("phi", "r")
CENTRE = np.array([1.0, 6.0])
#: what the paper shows (Figs. 4 and 6): curves only, no numbers
PAPER_CLAIM = "KFUEA < PF < DMK (noisy) at every SNR; values only as plots"


@dataclass(frozen=True)
class Setup:
    dt: float = 0.01
    steps: int = 1000
    particles: int = 500
    beta: float = 0.5
    p0: float = 2.5


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def drift(th: np.ndarray) -> np.ndarray:
    e = th - CENTRE
    return -0.5 * e**3 + e


def step_mean(th: np.ndarray, dt: float) -> np.ndarray:
    return th + dt * drift(th)


def jac_step(th: np.ndarray, dt: float) -> np.ndarray:
    e = th - CENTRE
    return np.eye(2) + dt * np.diag(1.0 - 1.5 * e**2)


def h(th: np.ndarray) -> np.ndarray:
    """(φ, r) = (atan2(θ¹, θ²), ‖θ‖) for (2,) or (N, 2) input."""
    th = np.asarray(th, dtype=float)
    return np.stack([np.arctan2(th[..., 0], th[..., 1]), np.hypot(th[..., 0], th[..., 1])],
                    axis=-1)


def jac_h(th: np.ndarray) -> np.ndarray:
    a, b = float(th[0]), float(th[1])
    r2 = a * a + b * b
    r = math.sqrt(r2)
    return np.array([[b / r2, -a / r2], [a / r, b / r]])


def simulate(s: Setup, rng: np.random.Generator) -> np.ndarray:
    th = np.empty((s.steps, 2))
    x = CENTRE + rng.standard_normal(2)
    sq = math.sqrt(2.0 * s.dt)
    for k in range(s.steps):
        th[k] = x
        x = step_mean(x, s.dt) + sq * rng.standard_normal(2)
    return th


# ----------------------------------------------------------------------------------- filters
def ekf_predict(x, P, s: Setup, Qx=None):
    J = jac_step(x, s.dt)
    Q = 2.0 * s.dt * np.eye(2) if Qx is None else Qx
    return step_mean(x, s.dt), J @ P @ J.T + Q


def ekf_update(x, P, z, R):
    """EKF update with innovation z − h(x̄), azimuth wrapped; Joseph form."""
    Hj = jac_h(x)
    nu = z - h(x)
    nu[0] = _wrap(nu[0])
    S = Hj @ P @ Hj.T + R
    K = P @ Hj.T @ np.linalg.inv(S)
    IKH = np.eye(2) - K @ Hj
    return x + K @ nu, IKH @ P @ IKH.T + K @ R @ K.T


def run_ekf(Z, R, s: Setup) -> np.ndarray:
    x, P = CENTRE.copy(), s.p0 * np.eye(2)
    out = np.empty_like(Z)
    for k, z in enumerate(Z):
        if k:
            x, P = ekf_predict(x, P, s)
        x, P = ekf_update(x, P, z, R)
        out[k] = x
    return out


def run_if_ekf(Z, R, s: Setup) -> np.ndarray:
    """EKF with the information-form update of InformationKF on the linearised measurement."""
    f = InformationKF(np.eye(2), np.eye(2), 2.0 * s.dt * np.eye(2), R, x0=CENTRE,
                      P0=s.p0 * np.eye(2))
    out = np.empty_like(Z)
    for k, z in enumerate(Z):
        if k:
            f.x, f.P = ekf_predict(f.x, f.P, s)
        Hj = jac_h(f.x)
        nu = z - h(f.x)
        nu[0] = _wrap(nu[0])
        f.H = Hj
        f.update(Hj @ f.x + nu)  # innovation z_lin − H x̄ = z − h(x̄)
        out[k] = f.x
    return out


def run_sdn_ekf(Z, R, s: Setup) -> np.ndarray:
    """EKF whose process noise is eq 25's state-dependent Q_eff (δ̄ = β√Δt I about c)."""
    db = s.beta * math.sqrt(s.dt) * np.eye(2)
    f = StateDependentNoiseKF(np.eye(2), np.eye(2), 2.0 * s.dt * np.eye(2), R, Dbar=[db],
                              x0=CENTRE, P0=s.p0 * np.eye(2))
    out = np.empty_like(Z)
    x, P = CENTRE.copy(), s.p0 * np.eye(2)
    for k, z in enumerate(Z):
        if k:
            Qe = f.process_noise(x - CENTRE, P)
            x, P = ekf_predict(x, P, s, Qx=Qe)
        x, P = ekf_update(x, P, z, R)
        out[k] = x
    return out


def run_pf(Z, R, s: Setup, rng: np.random.Generator) -> np.ndarray:
    """Bootstrap PF; returns the MMSE estimate of the clean measurement Σ wᵢ h(θᵢ)."""
    sq = math.sqrt(2.0 * s.dt)
    Ri = np.diag(1.0 / np.diag(R))

    def trans(X, g):
        return X + s.dt * drift(X) + sq * g.standard_normal(X.shape)

    def loglik(z, X):
        e = z - h(X)
        e[:, 0] = _wrap(e[:, 0])
        return -0.5 * (e[:, 0] ** 2 * Ri[0, 0] + e[:, 1] ** 2 * Ri[1, 1])

    pf = ParticleFilter(trans, loglik, x0=CENTRE, P0=s.p0 * np.eye(2),
                        n_particles=s.particles, rng=rng)
    out = np.empty_like(Z)
    for k, z in enumerate(Z):
        if k:
            pf.predict()
        pf.update(z)
        zh = pf.expect(h)
        out[k] = zh
    return out


def nrmse(est: np.ndarray, clean: np.ndarray) -> np.ndarray:
    """Per channel RMSE(est − clean) / std(clean) (azimuth differences wrapped)."""
    e = est - clean
    e[:, 0] = _wrap(e[:, 0])
    return np.sqrt(np.mean(e**2, axis=0)) / np.std(clean, axis=0)


def one_run(s: Setup, snr: float, seed: int) -> dict[str, Any]:
    rng = np.random.default_rng([seed, int(round(snr * 1e6))])
    th = simulate(s, rng)
    clean = h(th)
    var = np.var(clean, axis=0) / snr
    R = np.diag(var)
    Z = clean + rng.standard_normal(clean.shape) * np.sqrt(var)
    ekf = run_ekf(Z, R, s)
    ifk = run_if_ekf(Z, R, s)
    est = {
        "EKF": h(ekf),
        "IF-EKF": h(ifk),
        "SDN-EKF": h(run_sdn_ekf(Z, R, s)),
        "PF": run_pf(Z, R, s, rng),
        "Meas": Z,
    }
    return {"seed": seed, "snr": snr, "if_diff": float(np.max(np.abs(ekf - ifk))),
            "nrmse": {k: nrmse(v, clean) for k, v in est.items()},
            "clean": clean if seed == 0 else None, "est": est if seed == 0 else None}


# ------------------------------------------------------------------------------------ output


def summarise(results: list[dict[str, Any]], snrs: list[float]) -> list[dict[str, Any]]:
    recs = []
    for snr in snrs:
        rs = [r for r in results if r["snr"] == snr]
        for name in FILTERS:
            v = np.array([r["nrmse"][name] for r in rs])
            rec: dict[str, Any] = {"snr": snr, "filter": name, "runs": len(rs)}
            for j, ch in enumerate(CHANNELS):
                rec[f"nrmse_{ch}"] = float(v[:, j].mean())
                rec[f"sd_{ch}"] = float(v[:, j].std(ddof=1)) if len(v) > 1 else math.nan
            recs.append(rec)
    return recs


def plot(recs, results, snrs, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    for j, ch in enumerate(CHANNELS):
        ax = axes[j]
        for name in FILTERS:
            m = [next(r for r in recs if r["snr"] == s and r["filter"] == name)[f"nrmse_{ch}"]
                 for s in snrs]
            sd = [next(r for r in recs if r["snr"] == s and r["filter"] == name)[f"sd_{ch}"]
                  for s in snrs]
            ax.errorbar(snrs, m, yerr=sd, marker="o", capsize=3, label=name)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("SNR")
        ax.set_ylabel(f"nRMSE of {'azimuth φ' if ch == 'phi' else 'range r'}")
        ax.grid(alpha=0.3, which="both")
        ax.legend()
    ax = axes[2]
    r0 = next((r for r in results if r["clean"] is not None and r["snr"] == 1.0), None)
    r0 = r0 or next(r for r in results if r["clean"] is not None)
    t = np.arange(len(r0["clean"])) * 0.01
    ax.plot(t, r0["est"]["Meas"][:, 1], "x", color="0.7", ms=2, label="noisy")
    ax.plot(t, r0["clean"][:, 1], "k--", lw=1, label="clean")
    for name in ("EKF", "SDN-EKF", "PF"):
        ax.plot(t, r0["est"][name][:, 1], lw=1, label=name)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("range r")
    ax.set_title(f"run 0, SNR {r0['snr']:g}")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, default=10, help="trajectories per SNR (paper: 50)")
    p.add_argument("--snr", default="0.18,0.67,1,3,10", help="comma-separated SNR levels")
    p.add_argument("--particles", type=int, default=Setup.particles, help="PF particles")
    p.add_argument("--beta", type=float, default=Setup.beta,
                   help="state-dependent noise gain of SDN-EKF (δ̄ = β √Δt I)")
    p.add_argument("--out", default="runs/experiment-langevin", metavar="DIR", help="output folder")


def main(args: argparse.Namespace) -> int:
    from ...config import ConfigError
    from ..batch import markdown_table, print_table

    try:
        snrs = [float(v) for v in args.snr.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"--snr {args.snr!r}: expected comma-separated numbers") from None
    if args.runs < 1 or not snrs or any(not v > 0 for v in snrs) or args.particles < 2:
        raise ConfigError("--runs >= 1, --particles >= 2 and positive --snr values needed")
    s = Setup(particles=args.particles, beta=args.beta)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    results = [one_run(s, snr, seed) for snr in snrs for seed in range(args.runs)]
    wall = time.perf_counter() - t0
    recs = summarise(results, snrs)
    rows = [{"snr": r["snr"], "seed": r["seed"], "filter": n,
             **{f"nrmse_{ch}": float(r["nrmse"][n][j]) for j, ch in enumerate(CHANNELS)}}
            for r in results for n in FILTERS]
    write_csv(out / "results.csv", rows)
    write_csv(out / "summary.csv", recs)
    plot(recs, results, snrs, out / "langevin.png")
    header = ["SNR", *FILTERS]
    md = [f"# Langevin tracking (kfuea §3): nRMSE mean ± sd over {args.runs} runs", ""]
    for ch in CHANNELS:
        lines = []
        for snr in snrs:
            row = [f"{snr:g}"]
            for name in FILTERS:
                rec = next(r for r in recs if r["snr"] == snr and r["filter"] == name)
                row.append(f"{rec[f'nrmse_{ch}']:.3f} ± {rec[f'sd_{ch}']:.3f}"
                           if args.runs > 1 else f"{rec[f'nrmse_{ch}']:.3f}")
            lines.append(row)
        label = "azimuth φ" if ch == "phi" else "range r"
        print_table(header, lines, f"nRMSE of {label} (mean ± sd over {args.runs} runs); "
                                   f"paper: {PAPER_CLAIM}")
        md += [f"## {label}", "", markdown_table(header, lines)]
    diff = max(r["if_diff"] for r in results)
    notes = [f"information-form EKF vs covariance-form EKF: max |Δθ| = {diff:.1e}",
             f"paper (Figs. 4, 6): {PAPER_CLAIM}; KFUEA and DMK not implemented "
             "(see docs/langevin.md)",
             f"SDN-EKF: δ̄ = {s.beta:g}·√Δt·I about c = (1, 6); PF: {s.particles} particles"]
    for n in notes:
        print("- " + n)
    print(f"wall time {wall:.1f} s; wrote {out / 'results.csv'}, {out / 'summary.csv'}, "
          f"{out / 'langevin.png'}")
    md += [*("- " + n for n in notes), "", "![langevin](langevin.png)", ""]
    (out / "langevin.md").write_text("\n".join(md))
    return 0
