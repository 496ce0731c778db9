"""``ag-uav experiment bearing-tracking``: Tables IV–V of Qin, Xu & Liu, "Path Planning for UAV
Target Tracking with Non-Gaussian Noise" — bearing-only (AOA) UAV self-localisation and target
tracking with EKF, UKF and MCC-EKF, each with and without PSO waypoint planning (MCC-EKF + PSO is
the paper's MCEP).

Setup (the paper's section IV where it gives a value, otherwise a documented choice of ours):

- state X = [ξ_u, ξ̇_u, η_u, η̇_u, ξ_t, ξ̇_t, η_t, η̇_t] (UAV and target, constant velocity, eqs 5-8),
  ψ = 1 s, T = 600 steps; anchors b₁ = (0, 925) m, b₂ = (200, 1050) m; measurements Z = [θ_ub1,
  θ_ub2, θ_ut] (eqs 1-3) with noise (1 − ϑ) N(0, 0.01) + ϑ N(0, 0.1) rad², ϑ = 0.1 (eq 4);
- X̂(0|0) = [−1000, 10, 1200, 5, 200, 0.3, 800, 0.3], P̂(0|0) = 10³ diag(1, .01, 1, .01, 1, .01,
  1, .01); the true target starts at (0, 600) m with velocity (0.3, 0.3) m/s (so its prior mean is
  283 m, 9 σ, off, as the paper gives it);
- *choice*: the true UAV starts at X̂(0|0)'s UAV part plus one draw of N(0, P̂₀) (the paper does
  not give it); process noise (not given) is continuous white acceleration, q = 1e-2 m²/s³ for the
  UAV and 1e-4 for the target, used both for the truth and the filters (``--q-uav``,
  ``--q-target``); the filters use R = 0.01 I (the mixture's nominal component; ``--filter-r``);
- *choice*: without planning the UAV keeps its own (noisy) constant-velocity motion, i.e. flies
  the fixed straight path from its start (the paper's EKF/UKF/MCCEKF rows);
- PSO planning (Tables II–III, eqs 26-38): after each update the filter predicts X̂(k+1|k),
  P̂(k+1|k); N = 70 particles λ = (λ_ξ, λ_η) displace the predicted UAV position (eqs 28-29); the
  cost is the trace of the covariance after an update with the Jacobian at the displaced
  prediction (eqs 30-31), in closed form for all particles at once
  (:func:`estimators.bearing.trace_after_update`); eq 32's "max over measurement noises" is the
  largest noise variance, R = 0.1 I (trace P⁺ grows with R; ``--plan-r``); ω = 0.5, c₁ = c₂ = 2;
  *choice*: λ ∈ [−20, 20]² m per step (``--step-max``), 5 PSO iterations per step
  (``--pso-iters``; 70 × 5 evaluations of a smooth 2-D cost), the library PSO's velocity clamp
  (0.2 of the box), and a 50 m standoff from the anchors and the estimated target
  (``--standoff``; the trace rewards proximity without bound — bearing information grows as
  1/d² — so without it the UAV parks on an anchor or on the target, where the bearing
  linearisation fails; ``--standoff 0`` is the paper's unconstrained cost). The best λ* is a
  known control: the true UAV and the filter's prediction both move by it (eq 38);
- MCC-EKF: kernel σ = 2 (whitened residuals; ``--sigma``), ε = 1e-6, ≤ 10 fixed-point
  iterations, the bank's lock-out recovery. UKF: scaled sigma points α = 1, β = 2, κ = 0. The
  UKF-PSO cost uses the same linearised closed form with the UKF's P̂(k+1|k).

ARMSE (eq 40): per run the RMSE over the T steps of each state component of X̂(k|k), averaged
over runs. All six methods of a run see the same target path, measurement-noise draws and UAV
process noise (common random numbers); every run is seeded from (``--seed``, run index) and does
not depend on the worker count.

Writes ``results.csv`` (one row per run and method), ``table.csv`` / ``table.md`` (ARMSE next
to the paper's) and ``bearing_tracking.png`` into ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from controllers.optim import PSO
from estimators.bearing import (
    BearingModel,
    angle_residual,
    cv_process_noise,
    cv_transition,
    mixture_noise,
    trace_cost,
    wrap_angle,
)
from estimators.ekf import EKF
from estimators.mccekf import MCCEKF
from estimators.ukf import UKF

NAME = "bearing-tracking"
HELP = ("Tables IV-V (Qin, Xu & Liu): bearing-only UAV self-localisation + target tracking, "
        "EKF / UKF / MCC-EKF with and without PSO waypoint planning (MCEP)")

METHODS = ("EKF", "UKF", "MCC-EKF", "EKF-PSO", "UKF-PSO", "MCEP")
#: state components in the paper's table order: target then UAV, (ξ, η, ξ̇, η̇)
TARGET_IDX = (4, 6, 5, 7)
UAV_IDX = (0, 2, 1, 3)
COMP_NAMES = ("xi", "eta", "vxi", "veta")
#: Table IV (target) and Table V (UAV): ξ (m), η (m), ξ̇ (m/s), η̇ (m/s)
PAPER_TARGET = {"EKF": (44.26, 44.36, 0.59, 1.11), "UKF": (13.34, 14.22, 0.43, 0.53),
                "MCC-EKF": (11.34, 11.55, 0.41, 0.58), "EKF-PSO": (3.44, 1.83, 0.10, 0.11),
                "UKF-PSO": (1.98, 0.87, 0.12, 0.07), "MCEP": (1.67, 0.75, 0.07, 0.06)}
PAPER_UAV = {"EKF": (118.99, 103.82, 4.13, 3.93), "UKF": (74.47, 68.43, 3.95, 3.36),
             "MCC-EKF": (69.31, 63.66, 2.32, 2.30), "EKF-PSO": (23.06, 23.23, 1.53, 1.23),
             "UKF-PSO": (31.09, 36.27, 0.28, 0.22), "MCEP": (17.87, 17.35, 0.20, 0.14)}


@dataclass(frozen=True)
class Setup:
    """Everything one Monte Carlo run depends on (see the module docstring)."""

    anchors: tuple[tuple[float, float], ...] = ((0.0, 925.0), (200.0, 1050.0))
    target0: tuple[float, float, float, float] = (0.0, 0.3, 600.0, 0.3)  # ξ, ξ̇, η, η̇
    x0_hat: tuple[float, ...] = (-1000.0, 10.0, 1200.0, 5.0, 200.0, 0.3, 800.0, 0.3)
    p0_diag: tuple[float, ...] = (1e3, 10.0, 1e3, 10.0, 1e3, 10.0, 1e3, 10.0)
    dt: float = 1.0
    steps: int = 600
    q_uav: float = 1e-2
    q_target: float = 1e-4
    var1: float = 0.01
    var2: float = 0.1
    weight: float = 0.1
    filter_r: float = 0.01
    plan_r: float = 0.1
    pop: int = 70
    pso_iters: int = 5
    inertia: float = 0.5
    c1: float = 2.0
    c2: float = 2.0
    v_max: float = 0.2
    step_max: float = 20.0
    standoff: float = 50.0
    sigma: float = 2.0
    mcc_eps: float = 1e-6
    mcc_max_iter: int = 10
    ukf_alpha: float = 1.0
    ukf_beta: float = 2.0
    ukf_kappa: float = 0.0
    seed: int = 0
    methods: tuple[str, ...] = METHODS

    def model(self) -> BearingModel:
        return BearingModel(8, observer=(0, 2), landmarks=self.anchors, targets=[(4, 6)])

    def F(self) -> np.ndarray:
        return cv_transition(4, self.dt)

    def Q(self) -> np.ndarray:
        return cv_process_noise([self.q_uav, self.q_uav, self.q_target, self.q_target], self.dt)


#: control matrix: a planned displacement λ moves the UAV position (rows ξ_u, η_u), eq 38
B_UAV = np.zeros((8, 2))
B_UAV[0, 0] = B_UAV[2, 1] = 1.0


def make_filter(kind: str, s: Setup, model: BearingModel | None = None):
    """EKF / UKF / MCC-EKF on the paper's model with the paper's initial state."""
    model = model or s.model()
    F, Q = s.F(), s.Q()
    R = s.filter_r * np.eye(model.m)
    x0, P0 = np.array(s.x0_hat), np.diag(s.p0_diag)
    if kind == "ekf":
        return EKF(F, None, model.h, model.jacobian, Q, R, x0, P0, residual=angle_residual,
                   B=B_UAV)
    if kind == "ukf":
        return UKF(F, model.h, Q, R, x0, P0, residual=angle_residual, alpha=s.ukf_alpha,
                   beta=s.ukf_beta, kappa=s.ukf_kappa, B=B_UAV, vectorized=True)
    if kind == "mcc":
        return MCCEKF(F, None, model.h, model.jacobian, Q, R, x0, P0, residual=angle_residual,
                      B=B_UAV, sigma=s.sigma, eps=s.mcc_eps, max_iter=s.mcc_max_iter)
    raise ValueError(f"unknown filter kind {kind!r}")


_KIND = {"EKF": "ekf", "UKF": "ukf", "MCC-EKF": "mcc", "EKF-PSO": "ekf", "UKF-PSO": "ukf",
         "MCEP": "mcc"}


def plan_cost(model: BearingModel, xb: np.ndarray, Pb: np.ndarray, R: np.ndarray,
              standoff: float = 0.0) -> Callable[[np.ndarray], np.ndarray]:
    """The paper's Table II cost as a function of displacements λ of the predicted UAV
    position: tr P⁺ after an update with the Jacobian at the displaced prediction.

    ``xb`` (n,) and ``Pb`` (n, n) give a function of λ (k, 2) → (k,); a batch ``xb`` (B, n),
    ``Pb`` (B, n, n) gives a function of λ (B, k, 2) → (B, k) (B priors planned at once).
    With ``standoff`` > 0 a candidate closer than that to an anchor or to the estimated target
    pays tr P̄ · (1 + 10 (standoff − d)/standoff) (above any feasible cost, and sloped so that
    the swarm is pushed out)."""
    tc = trace_cost(Pb, R, model.columns)
    u0 = xb[..., [0, 2]]
    trP = np.trace(Pb, axis1=-2, axis2=-1)
    if xb.ndim == 2:
        u0 = u0[:, None, :]
        trP = trP[:, None]

    def cost(lam: np.ndarray) -> np.ndarray:
        H, d2 = model.observer_jacobian(u0 + lam, xb)
        c = tc(H)
        if standoff > 0.0:
            dmin = np.sqrt(d2.min(axis=-1))
            bad = dmin < standoff
            if bad.any():
                c = np.where(bad, trP * (1.0 + 10.0 * (standoff - dmin) / standoff), c)
        return c

    return cost


def _new_pso(s: Setup, rng: np.random.Generator) -> PSO:
    lim = np.array([s.step_max, s.step_max])
    return PSO(-lim, lim, pop=s.pop, rng=rng, inertia=s.inertia, c1=s.c1, c2=s.c2,
               v_max=s.v_max)


def plan_waypoints(model: BearingModel, xb: np.ndarray, Pb: np.ndarray, R: np.ndarray,
                   s: Setup, rngs: list[np.random.Generator]) -> np.ndarray:
    """One PSO (Table III) per prior of the batch ``xb`` (B, n), ``Pb`` (B, n, n), each with its
    own Generator, over λ ∈ [−step_max, step_max]²; the B swarms are evaluated together.
    Returns λ* (B, 2) (0 for a swarm that found no finite cost)."""
    psos = [_new_pso(s, g) for g in rngs]
    cost = plan_cost(model, xb, Pb, R, s.standoff)
    for _ in range(s.pso_iters):
        C = cost(np.stack([p.ask() for p in psos]))
        for p, c in zip(psos, C, strict=True):
            p.tell(c)
    return np.array([np.zeros(2) if p.best_x is None else p.best_x for p in psos])


def plan_waypoint(model: BearingModel, xb: np.ndarray, Pb: np.ndarray, R: np.ndarray,
                  s: Setup, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """PSO (Table III) for one prior; returns (λ*, its cost)."""
    pso = _new_pso(s, rng)
    cost = plan_cost(model, xb, Pb, R, s.standoff)
    for _ in range(s.pso_iters):
        pso.tell(cost(pso.ask()))
    return pso.best_x.copy(), pso.best_f


def is_planned(method: str) -> bool:
    """EKF-PSO, UKF-PSO and MCEP plan the UAV's waypoints."""
    return method.endswith("PSO") or method == "MCEP"


def _simulate(s: Setup, model: BearingModel, target: np.ndarray, uav0: np.ndarray,
              w_uav: np.ndarray, v: np.ndarray,
              rngs: dict[str, np.random.Generator]) -> dict[str, dict[str, np.ndarray]]:
    """All methods of one run in lockstep (the planned ones share one batched cost per PSO
    iteration): true UAV path (planned or fixed), estimates, traces."""
    T = s.steps
    F = s.F()
    FT = F.T
    Fu = F[:4, :4]
    Q = s.Q()
    Rp = s.plan_r * np.eye(model.m)
    methods = list(s.methods)
    planned = [m for m in methods if is_planned(m)]
    filt = {m: make_filter(_KIND[m], s, model) for m in methods}
    xu = {m: uav0.copy() for m in methods}
    out = {m: {"truth": np.empty((T, 8)), "est": np.empty((T, 8)), "trace": np.empty(T)}
           for m in methods}
    zero = np.zeros(2)
    for k in range(T):
        lam = dict.fromkeys(methods, zero)
        if planned:
            xb = np.array([F @ filt[m].x for m in planned])
            Pb = np.array([F @ filt[m].P @ FT + Q for m in planned])
            ok = np.all(np.isfinite(Pb), axis=(1, 2)) & np.all(np.isfinite(xb), axis=1)
            sel = [m for m, good in zip(planned, ok, strict=True) if good]
            if sel:
                best = plan_waypoints(model, xb[ok], Pb[ok], Rp, s, [rngs[m] for m in sel])
                lam.update(zip(sel, best, strict=True))
        for m in methods:
            x = Fu @ xu[m] + w_uav[k]
            x[0] += lam[m][0]
            x[2] += lam[m][1]
            xu[m] = x
            x_true = np.concatenate([x, target[k]])
            f = filt[m]
            f.predict(u=lam[m] if m in planned else None)
            f.update(wrap_angle(model.h(x_true) + v[k]))
            o = out[m]
            o["truth"][k] = x_true
            o["est"][k] = f.x
            o["trace"][k] = np.trace(f.P)
    return out


def run_one(task: tuple[Setup, int, bool]) -> dict[str, Any]:
    """Monte Carlo run ``run`` of every method (common random numbers across methods)."""
    s, run, keep_paths = task
    t0 = time.perf_counter()
    ss = np.random.SeedSequence([int(s.seed), int(run)])
    g_meas, g_proc, g_init, *g_pso = (np.random.default_rng(c) for c in ss.spawn(3 + 3))
    T = s.steps
    model = s.model()
    Q = s.Q()
    Lu = np.linalg.cholesky(Q[:4, :4])
    Lt = np.linalg.cholesky(Q[4:, 4:])
    w_uav = g_proc.standard_normal((T, 4)) @ Lu.T
    w_tgt = g_proc.standard_normal((T, 4)) @ Lt.T
    v = mixture_noise(g_meas, (T, model.m), s.var1, s.var2, s.weight)
    uav0 = np.array(s.x0_hat[:4]) + np.sqrt(np.array(s.p0_diag[:4])) * g_init.standard_normal(4)
    Ft = s.F()[4:, 4:]
    target = np.empty((T, 4))
    xt = np.array(s.target0, dtype=float)
    for k in range(T):
        xt = Ft @ xt + w_tgt[k]
        target[k] = xt
    rngs = {"EKF-PSO": g_pso[0], "UKF-PSO": g_pso[1], "MCEP": g_pso[2]}
    with np.errstate(all="ignore"):
        sim = _simulate(s, model, target, uav0, w_uav, v, rngs)
    out: dict[str, Any] = {"run": run, "methods": {}, "wall_s": time.perf_counter() - t0}
    for m, r in sim.items():
        err = r["est"] - r["truth"]
        rec = {"rmse": np.sqrt(np.mean(err * err, axis=0)),
               "finite": bool(np.all(np.isfinite(err))),
               "err_target": np.hypot(err[:, 4], err[:, 6]),
               "err_uav": np.hypot(err[:, 0], err[:, 2]), "trace": r["trace"]}
        if keep_paths:
            rec["truth"] = r["truth"]
            rec["est"] = r["est"]
        out["methods"][m] = rec
    return out


# ------------------------------------------------------------------------------------- CLI
def add_arguments(p: argparse.ArgumentParser) -> None:
    d = Setup()
    p.add_argument("--runs", type=int, default=200, help="Monte Carlo runs (paper: 200)")
    p.add_argument("--steps", type=int, default=d.steps, help="time steps of 1 s (paper: 600)")
    p.add_argument("--seed", type=int, default=d.seed, help="base seed (run i uses (seed, i))")
    p.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods")
    p.add_argument("--pso-iters", type=int, default=d.pso_iters, help="PSO iterations per step")
    p.add_argument("--pop", type=int, default=d.pop, help="PSO particles (paper: 70)")
    p.add_argument("--step-max", type=float, default=d.step_max,
                   help="bound of the planned UAV displacement per axis and step (m)")
    p.add_argument("--standoff", type=float, default=d.standoff,
                   help="minimum planned distance to the anchors and the estimated target (m)")
    p.add_argument("--sigma", type=float, default=d.sigma, help="MCC-EKF kernel bandwidth")
    p.add_argument("--q-uav", type=float, default=d.q_uav, help="UAV process noise (m²/s³)")
    p.add_argument("--q-target", type=float, default=d.q_target,
                   help="target process noise (m²/s³)")
    p.add_argument("--filter-r", type=float, default=d.filter_r,
                   help="bearing variance the filters assume (rad²)")
    p.add_argument("--plan-r", type=float, default=d.plan_r,
                   help="bearing variance in the PSO cost (rad²; eq 32 worst case)")
    p.add_argument("--outlier-weight", type=float, default=d.weight,
                   help="ϑ, the weight of the N(0, 0.1) component")
    p.add_argument("--out", default="runs/experiment-bearing-tracking", metavar="DIR",
                   help="output folder")
    p.add_argument("--workers", "-j", type=int, default=None,
                   help="worker processes (default: CPU count; 1 = in this process)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def setup_from_args(args: argparse.Namespace) -> Setup:
    from ...config import ConfigError

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ConfigError(f"--methods: unknown {bad}; allowed: {', '.join(METHODS)}")
    if args.runs < 1 or args.steps < 1 or args.pso_iters < 1 or args.pop < 2:
        raise ConfigError("--runs, --steps, --pso-iters must be >= 1 and --pop >= 2")
    return replace(Setup(), steps=args.steps, seed=args.seed, methods=methods,
                   pso_iters=args.pso_iters, pop=args.pop, step_max=args.step_max,
                   standoff=args.standoff,
                   sigma=args.sigma, q_uav=args.q_uav, q_target=args.q_target,
                   filter_r=args.filter_r, plan_r=args.plan_r, weight=args.outlier_weight)


def aggregate(results: list[dict[str, Any]], methods: tuple[str, ...]) -> list[dict[str, Any]]:
    """ARMSE (eq 40: mean over runs of the per-run RMSE) per method and component."""
    recs = []
    for m in methods:
        R = np.array([r["methods"][m]["rmse"] for r in results])
        fin = np.all(np.isfinite(R), axis=1)
        Rf = R[fin]
        rec: dict[str, Any] = {"method": m, "runs": len(results), "finite": int(fin.sum())}
        for who, idx, paper in (("target", TARGET_IDX, PAPER_TARGET), ("uav", UAV_IDX,
                                                                        PAPER_UAV)):
            for c, i, pv in zip(COMP_NAMES, idx, paper[m], strict=True):
                rec[f"{who}_{c}"] = float(Rf[:, i].mean()) if len(Rf) else math.nan
                rec[f"{who}_{c}_median"] = float(np.median(Rf[:, i])) if len(Rf) else math.nan
                rec[f"{who}_{c}_paper"] = pv
        recs.append(rec)
    return recs


def _fmt(x: float) -> str:
    if not math.isfinite(x):
        return "–"
    return f"{x:.3g}" if abs(x) < 1 else f"{x:.2f}" if abs(x) < 1000 else f"{x:.3g}"


def tables(recs: list[dict[str, Any]]) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows) for Table IV (target) and Table V (UAV): ours (paper)."""
    out = []
    for who, title in (("target", "Table IV - ARMSE of the target"),
                       ("uav", "Table V - ARMSE of the UAV")):
        header = ["method", "ξ (m)", "η (m)", "ξ̇ (m/s)", "η̇ (m/s)", "finite runs"]
        rows = []
        for r in recs:
            cells = [f"{_fmt(r[f'{who}_{c}'])} ({_fmt(r[f'{who}_{c}_paper'])})"
                     for c in COMP_NAMES]
            rows.append([r["method"], *cells, f"{r['finite']}/{r['runs']}"])
        out.append((title + " - ours (paper)", header, rows))
    return out


def _markdown(title: str, header: list[str], rows: list[list[str]]) -> str:
    lines = [f"**{title}**", "", "| " + " | ".join(header) + " |",
             "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def plot(results: list[dict[str, Any]], s: Setup, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(2, 2, figsize=(12, 9))
    first = results[0]["methods"]
    ax = axs[0, 0]
    tgt_drawn = False
    for m, rec in first.items():
        if "truth" not in rec:
            continue
        tr, es = rec["truth"], rec["est"]
        if not tgt_drawn:
            ax.plot(tr[:, 4], tr[:, 6], "k-", lw=2, label="target (truth)")
            tgt_drawn = True
        if m in ("EKF", "EKF-PSO", "UKF-PSO", "MCEP"):
            lbl = "fixed path" if m == "EKF" else m
            ln = ax.plot(tr[:, 0], tr[:, 2], "-", lw=1, label=f"UAV truth, {lbl}")[0]
            ax.plot(es[:, 0], es[:, 2], ":", color=ln.get_color(), lw=1)
    an = np.array(s.anchors)
    ax.plot(an[:, 0], an[:, 1], "r^", ms=9, label="anchors")
    ax.set_title("run 0: UAV truth (solid) and estimate (dotted)", fontsize=9)
    ax.set_xlabel("ξ (m)")
    ax.set_ylabel("η (m)")
    ax.legend(fontsize=7)
    ax.axis("equal")
    t = np.arange(1, s.steps + 1) * s.dt
    for ax, key, label in ((axs[0, 1], "err_target", "target position error (m)"),
                           (axs[1, 0], "err_uav", "UAV position error (m)"),
                           (axs[1, 1], "trace", "tr P (cost function, cf. Fig. 4)")):
        for m in s.methods:
            arr = np.array([r["methods"][m][key] for r in results])
            arr = arr[np.all(np.isfinite(arr), axis=1)]
            if len(arr):
                ax.semilogy(t, np.median(arr, axis=0), lw=1, label=m)
        ax.set_xlabel("time (s)")
        ax.set_ylabel(label + ", median over runs")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"Bearing-only tracking (Qin, Xu & Liu), {len(results)} runs", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(args: argparse.Namespace) -> int:
    from ..executor import make_executor

    s = setup_from_args(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tasks = [(s, i, i == 0) for i in range(args.runs)]
    t0 = time.perf_counter()
    results: list[dict[str, Any] | None] = [None] * len(tasks)
    bar = None
    if not args.quiet:
        from ..._progress import progress_bar

        bar = progress_bar(total=len(tasks), desc="bearing-tracking", unit="run")
    workers = args.workers
    if workers == 1 or len(tasks) == 1:
        it = ((i, run_one(t)) for i, t in enumerate(tasks))
        for i, r in it:
            results[i] = r
            if bar is not None:
                bar.update(1)
    else:
        with make_executor(workers) as ex:
            for i, r in ex.map_unordered(run_one, tasks):
                results[i] = r
                if bar is not None:
                    bar.update(1)
    if bar is not None:
        bar.close()
    wall = time.perf_counter() - t0
    res = [r for r in results if r is not None]

    with open(out / "results.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        labels = ["xi_u", "vxi_u", "eta_u", "veta_u", "xi_t", "vxi_t", "eta_t", "veta_t"]
        w.writerow(["run", "method", "finite", "run_wall_s"] + [f"rmse_{c}" for c in labels])
        for r in res:
            for m, rec in r["methods"].items():
                w.writerow([r["run"], m, int(rec["finite"]), f"{r['wall_s']:.3f}"]
                           + [f"{x:.6g}" for x in rec["rmse"]])
    recs = aggregate(res, s.methods)
    with open(out / "table.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(recs[0].keys()))
        w.writeheader()
        w.writerows(recs)
    tabs = tables(recs)
    md = [f"Bearing-only tracking, {len(res)} runs x {s.steps} steps, seed {s.seed}, "
          f"{wall:.0f} s wall\n"]
    from rich.console import Console
    from rich.table import Table

    con = Console(width=max(Console().width, 120))
    for title, header, rows in tabs:
        tb = Table(title=title)
        for h in header:
            tb.add_column(h)
        for row in rows:
            tb.add_row(*row)
        con.print(tb)
        md.append(_markdown(title, header, rows))
    setup_txt = ", ".join(f"{k}={v}" for k, v in asdict(s).items() if k != "methods")
    md.append(f"\nSetup: {setup_txt}\n")
    (out / "table.md").write_text("\n".join(md))
    plot(res, s, out / "bearing_tracking.png")
    print(f"{len(res)} runs in {wall:.1f} s; wrote {out}/results.csv, table.csv, table.md, "
          "bearing_tracking.png")
    print("Paper's Tables IV-V are not expected to reproduce exactly: the paper gives neither "
          "Q, the true UAV start, the UAV's path without planning, the PSO bounds nor its "
          "iteration count (see docs/bearing_tracking.md).")
    return 0
