"""``ag-uav experiment numerical``: the paper's numerical experiment (Candan & Li, §IV.A, Table II).

Setup (eqs 8-11): 2-D constant-velocity model, Ts = 0.05 s, F, Q, H, R of
:func:`estimators.models.paper_numerical_model` (R = diag(10, 100) m²).  The truth is a
lawnmower (coverage-path-planning) reference like the paper's Fig. 3, flown at constant speed:
by default 4 legs of 100 m along ±x, 10 m apart (a spray swath), joined by semicircular turns
of radius 5 m, at 5 m/s — 447 m, 89.4 s, 1789 fixes (``--legs``, ``--leg-length``,
``--spacing``, ``--speed``).  Every fix is the truth plus one GPS error draw; four noise cases,
all with the same per-axis variance (R):

==================== ======================== ===============================================
case                 GPS preset (ag_uav.vehicle.gps)   error per axis (× √10 m in x, × 10 m in y)
==================== ======================== ===============================================
white                ``paper-numerical``       N(0, 1)
coloured             ``coloured``              Gaussian AR(1), τ = 1 s (ρ = 0.951 per fix)
impulsive            ``mixture``               0.9 N(0, σ₁²) + 0.1 N(0, 10 σ₁²), unit variance
coloured-impulsive   ``coloured-impulsive``    AR(1) (var 0.36) + 4 % spikes of ±4 (var 0.64)
==================== ======================== ===============================================

Run ``r`` uses seed ``r`` for the GPS sensor, and every estimator of a case sees the SAME fixes
(common random numbers), so comparisons between estimators are paired.  Every filter starts from
the true initial state with P0 = diag(R_x, 1, R_y, 1) (position as uncertain as one fix,
velocity std 1 m/s); at fix k > 0 it runs ``predict(); update(z_k)``; at k = 0 only
``update(z_0)``.  RMSE per run = √(mean over all fixes of the squared 2-D position error);
the table gives the mean over runs with a 95 % Student-t interval, and the paired difference to
the KF with its own 95 % Student-t interval.

Estimators (``estimators.make``): ``kf``, ``mckf`` (σ = 2, library defaults otherwise:
ε = 1e-6, ≤ 10 iterations, KF recovery after 10 rejected fixes: a rule of ours, not Chen et
al. 2017's), ``mckf-norec`` and ``pca-mckf-norec`` (the same without that recovery rule, as
published), ``pca-kf``, ``pca-mckf``
(PCA block defaults: hankel reading, window 20, L = 10, r = 2), and two coloured-noise
baselines configured for the ``coloured`` preset in EVERY case (they are told τ = 1 s, which
the other filters are not): ``kf-bias`` (Gauss-Markov bias states, τ = 1 s, bias variance
0.95 R, white 0.05 R) and ``kf-diff`` (Bryson-Henrikson differencing, τ = 1 s).  ``gps`` is the
RMSE of the raw fixes.

Speed (``--engine fast``, the default).  The library filters cost ~20-180 µs per step in
Python, ~400 µs for all six: 100 runs × 4 cases × 1789 fixes would take ~5 minutes on one core.
The fast engine computes the same numbers with numpy batched over runs:

- KF, PCA-KF, kf-bias, kf-diff have data-independent gain sequences (fixed F, H, Q, R, no
  missing fixes).  The gains are RECORDED from the library filter itself (run once on dummy
  fixes) and applied to all runs at once; only the linear state recursion is vectorised.
- The PCA block depends on the fixes only, and MCKF / PCA-MCKF are data dependent: the runs of
  a chunk are the rows of the library's batched filters (:mod:`estimators.batched`, which
  loop over the rows calling the same row functions as the scalar filters: one implementation
  of each law), :func:`pca_batch` and :func:`mckf_batch`.
- The update time in the table is measured with the LIBRARY filter, step by step
  (``predict()`` + ``update()``, loop included), on the first ``--timing-runs`` runs of every
  case; the same runs serve as a self-check: the fast path must agree with the library filter
  to 1e-6 m there (it agrees to ~1e-12 m), else the command fails.
- Work is split into fixed chunks of ``--chunk`` runs (default 50; independent of
  ``--workers``) and run on a process pool (``--workers``, default = CPU cores), so results are
  identical for any number of workers.  The batched loops cost mostly per time step, not per
  run (a chunk of 25 runs takes about as long as one of 10), hence the large default chunk.
  Measured: 100 runs, all four cases, six estimators in 43-68 s wall on the shared 2-core
  machine (~45-90 s of CPU, of which ~7 s are the library timing runs).

``--engine library`` runs every library filter step by step on every run instead (the slow
reference; same numbers to ~1e-12 m).  ``recovery="inflate"`` is not exposed here.

Kernel sweep: the MCKF names take ``@SIGMA`` (``mckf@1`` … ``mckf@inf``; σ = ∞ gives weights
of exactly 1, i.e. the KF's estimates) and a kernel variant suffix, ``-adaptive`` (the adaptive
bandwidth of :class:`estimators.MCKF`, run by the library filter on every run: the batched MCKF
has no adaptive rows) or ``-multi`` (σ on the measurement rows, ∞ on the state rows), e.g.
``--estimators kf,mckf@1,mckf@2,mckf@4,mckf@inf,mckf-adaptive,mckf-multi``.

The paper's Table II (Matlab column: MCKF 6880 s / 0.137 m, KF 2415 s / 0.328 m, PCA-MCKF
7530 s / 0.068 m, PCA-KF 2865 s / 0.343 m) is printed next to every case; the paper does not
say what its "time" is (nor which noise case the row is), and its RMSEs are far below what
R = diag(10, 100) m² allows (the optimal KF's steady-state RMSE on this model is ~2.1 m).
Nothing here is tuned toward those numbers.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from .fast import (
    fast_tracks,
    gain_sequence,
    kf_diff_fixed_gain,
    kf_fixed_gain,
    mckf_batch,
    pca_batch,
)
from .report import (
    HEADER,
    plot_rmse,
    plot_tracks,
    summarise,
    t_interval,
    table_lines,
    write_csv,
)
from .setup import (
    CASES,
    COLOURS,
    ESTIMATORS,
    HELP,
    KERNELS,
    NAME,
    NOREC,
    PAPER_MATLAB,
    SELF_CHECK_TOL,
    Setup,
    filter_params,
    fixes,
    initial,
    lawnmower,
    make_filter,
    model,
    parse_estimator,
    run_library,
    truth,
)

__all__ = ["NAME", "HELP", "CASES", "COLOURS", "ESTIMATORS", "KERNELS", "NOREC", "PAPER_MATLAB",
           "SELF_CHECK_TOL", "HEADER", "Setup", "lawnmower", "truth", "fixes", "model", "initial",
           "parse_estimator", "filter_params", "make_filter", "run_library", "gain_sequence",
           "kf_fixed_gain", "kf_diff_fixed_gain", "pca_batch", "mckf_batch", "fast_tracks",
           "chunk_task", "make_jobs", "run_experiment", "t_interval", "summarise", "table_lines",
           "plot_tracks", "plot_rmse", "write_csv", "add_arguments", "main"]


# ------------------------------------------------------------------------------------ tasks
def _rmse(track: np.ndarray, pos: np.ndarray) -> tuple[float, float, float]:
    e = track - pos
    ex, ey = float(np.mean(e[:, 0] ** 2)), float(np.mean(e[:, 1] ** 2))
    return math.sqrt(ex + ey), math.sqrt(ex), math.sqrt(ey)



def chunk_task(job: dict[str, Any]) -> dict[str, Any]:
    """One work unit: a noise case × a fixed chunk of runs.  Returns the per-run RMSEs, the
    library timings and self-check differences (timing runs), and the tracks of ``keep``."""
    setup: Setup = job["setup"]
    case, runs, ests = job["case"], job["runs"], job["estimators"]
    pos, vel = truth(setup)
    x0, P0 = initial(setup, pos, vel)
    timing = set(job["timing_runs"]) if job["engine"] == "fast" else set(runs)
    if job["engine"] == "fast":
        Z, tracks = fast_tracks(setup, case, runs, ests, job["gains"])
    else:
        Z = np.stack([fixes(case, r, pos, setup.dt) for r in runs])
        tracks = {e: np.empty_like(Z) for e in ests}
    rows: list[dict[str, Any]] = []
    check: dict[str, float] = {}
    kept: dict[int, dict[str, np.ndarray]] = {}
    for i, r in enumerate(runs):
        upd: dict[str, float] = {}
        if r in timing:
            for e in ests:
                lib, sec = run_library(e, setup, Z[i], x0, P0)
                upd[e] = sec * 1e6
                if job["engine"] == "fast":
                    check[e] = max(check.get(e, 0.0), float(np.max(np.abs(lib - tracks[e][i]))))
                else:
                    tracks[e][i] = lib
        g = _rmse(Z[i], pos)
        rows.append({"case": case, "preset": CASES[case], "run": r, "seed": r,
                     "estimator": "gps", "rmse_m": g[0], "rmse_x_m": g[1], "rmse_y_m": g[2],
                     "update_us": math.nan})
        for e in ests:
            v = _rmse(tracks[e][i], pos)
            rows.append({"case": case, "preset": CASES[case], "run": r, "seed": r,
                         "estimator": e, "rmse_m": v[0], "rmse_x_m": v[1], "rmse_y_m": v[2],
                         "update_us": upd.get(e, math.nan)})
        if r in job["keep"]:
            kept[r] = {"fixes": Z[i].copy(), **{e: tracks[e][i].copy() for e in ests}}
    return {"case": case, "runs": runs, "rows": rows, "check": check, "kept": kept}


def make_jobs(setup: Setup, cases: list[str], ests: list[str], n_runs: int, chunk: int,
              engine: str, timing_runs: int, keep: tuple[int, ...] = (0,)
              ) -> list[dict[str, Any]]:
    """Fixed work units (chunks do not depend on the number of workers)."""
    gains: dict[str, np.ndarray] = {}
    if engine == "fast":
        pos, vel = truth(setup)
        x0, P0 = initial(setup, pos, vel)
        for e in ("kf", "kf-bias", "kf-diff"):
            if e in ests or (e == "kf" and "pca-kf" in ests):
                gains[e] = gain_sequence(e, setup, len(pos), x0, P0)
    jobs = []
    for case in cases:
        for start in range(0, n_runs, chunk):
            runs = list(range(start, min(start + chunk, n_runs)))
            jobs.append({"setup": setup, "case": case, "runs": runs, "estimators": ests,
                         "engine": engine, "gains": gains,
                         "timing_runs": [r for r in runs if r < timing_runs],
                         "keep": [r for r in runs if r in keep]})
    return jobs


def run_experiment(setup: Setup, cases: list[str], ests: list[str], n_runs: int, *,
                   workers: int | None = 1, chunk: int = 50, engine: str = "fast",
                   timing_runs: int = 2, keep: tuple[int, ...] = (0,),
                   progress: bool = False) -> dict[str, Any]:
    """Run everything; returns ``rows`` (one per case × run × estimator, plus "gps"),
    ``check`` (max |fast − library| per case and estimator, fast engine), ``kept`` tracks."""
    from ...executor import make_executor

    jobs = make_jobs(setup, cases, ests, n_runs, chunk, engine, timing_runs, keep)
    results: list[Any] = [None] * len(jobs)
    bar = None
    if progress:
        from ...._progress import progress_bar

        bar = progress_bar(total=n_runs * len(cases), unit="run", desc="numerical")
    with make_executor(workers) as ex:
        for i, res in ex.map_unordered(chunk_task, jobs):
            results[i] = res
            if bar is not None:
                bar.update(len(res["runs"]))
    if bar is not None:
        bar.close()
    rows = [row for res in results for row in res["rows"]]
    check: dict[tuple[str, str], float] = {}
    kept: dict[tuple[str, int], dict[str, np.ndarray]] = {}
    for res in results:
        for e, v in res["check"].items():
            check[(res["case"], e)] = max(check.get((res["case"], e), 0.0), v)
        for r, tr in res["kept"].items():
            kept[(res["case"], r)] = tr
    return {"rows": rows, "check": check, "kept": kept}



# -------------------------------------------------------------------------------------- CLI
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, default=100, help="Monte Carlo runs (run r: seed r)")
    p.add_argument("--out", default="runs/experiment-numerical", metavar="DIR",
                   help="output folder")
    p.add_argument("--cases", default=",".join(CASES),
                   help=f"comma-separated noise cases ({', '.join(CASES)})")
    p.add_argument("--estimators", default=",".join(ESTIMATORS),
                   help=f"comma-separated estimators ({', '.join(ESTIMATORS)}); the MCKF ones "
                        "also as NAME[-adaptive|-multi][@SIGMA], e.g. mckf@4, mckf@inf, "
                        "mckf-adaptive, pca-mckf-multi@1 (a σ sweep: docs/ins.md)")
    p.add_argument("--workers", "-j", type=int, default=None,
                   help="worker processes (default: CPU cores; 1 = serial)")
    p.add_argument("--chunk", type=int, default=50,
                   help="runs per work unit (batched together; the cost is mostly per time "
                        "step, so larger is faster)")
    p.add_argument("--engine", choices=("fast", "library"), default="fast",
                   help="fast: vectorised/batched, checked against the library on the timing "
                        "runs; library: every filter step by step on every run (slow)")
    p.add_argument("--timing-runs", type=int, default=2,
                   help="runs per case timed with the library filters (and self-checked)")
    p.add_argument("--legs", type=int, default=4, help="lawnmower legs")
    p.add_argument("--leg-length", type=float, default=100.0, help="leg length (m)")
    p.add_argument("--spacing", type=float, default=10.0, help="leg spacing = 2 × turn "
                   "radius (m)")
    p.add_argument("--speed", type=float, default=5.0, help="constant speed (m/s)")
    p.add_argument("--steps", type=int, default=None,
                   help="truncate the trajectory to this many fixes")
    p.add_argument("--sigma", type=float, default=2.0, help="MCKF kernel bandwidth")
    p.add_argument("--window", type=int, default=20, help="PCA window (fixes)")
    p.add_argument("--pca-mode", choices=("hankel", "channels"), default="hankel",
                   help="PCA reading (see estimators.pca)")
    p.add_argument("--plot-run", type=int, default=0, help="run shown in tracks.png")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def _setup_from(args: argparse.Namespace) -> Setup:
    return Setup(n_legs=args.legs, leg_m=args.leg_length, spacing_m=args.spacing,
                 speed=args.speed, sigma=args.sigma, window=args.window,
                 pca_mode=args.pca_mode, max_steps=args.steps)


def main(args: argparse.Namespace) -> int:
    from ....config import ConfigError
    from ...batch import markdown_table, print_table

    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    ests = [e.strip() for e in args.estimators.split(",") if e.strip()]
    bad = [c for c in cases if c not in CASES]
    if bad:
        raise ConfigError(f"--cases {bad[0]!r}: allowed {', '.join(CASES)}")
    for e in ests:
        try:
            parse_estimator(e)
        except ValueError as err:
            raise ConfigError(f"--estimators {err}") from None
    if args.runs < 1 or args.chunk < 1:
        raise ConfigError("--runs and --chunk must be >= 1")
    if not 0 <= args.plot_run < args.runs:
        raise ConfigError(f"--plot-run = {args.plot_run}: must be in [0, {args.runs - 1}]")
    setup = _setup_from(args)
    pos, _ = truth(setup)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    res = run_experiment(setup, cases, ests, args.runs, workers=args.workers, chunk=args.chunk,
                         engine=args.engine, timing_runs=args.timing_runs,
                         keep=(args.plot_run,), progress=not args.quiet)
    wall = time.perf_counter() - t0
    bad_check = {k: v for k, v in res["check"].items() if not v <= SELF_CHECK_TOL}
    rows = sorted(res["rows"], key=lambda r: (cases.index(r["case"]), r["run"],
                                              (["gps", *ests]).index(r["estimator"])))
    recs = summarise(rows, cases, ests)
    write_csv(out / "results.csv", rows)
    write_csv(out / "summary.csv", recs)
    plot_tracks(res["kept"], pos, cases, ests, args.plot_run, out / "tracks.png")
    plot_rmse(rows, cases, ests, out / "rmse.png")

    T = len(pos)
    desc = (f"{args.runs} runs (seeds 0..{args.runs - 1}, same fixes for every estimator), "
            f"lawnmower {setup.n_legs} × {setup.leg_m:g} m legs, {setup.spacing_m:g} m apart, "
            f"{setup.speed:g} m/s, {T} fixes ({T * setup.dt:.1f} s) at Ts = {setup.dt:g} s")
    md = ["# Numerical experiment (Candan & Li §IV.A, eqs 8-11, Table II)", "", f"- {desc}",
          f"- engine `{args.engine}`; wall time {wall:.1f} s"
          f" ({args.workers or 'all'} workers)",
          "- RMSE: 2-D position, all fixes; mean over runs ± 95 % Student-t half-width; "
          "Δ vs KF: paired per run (common random numbers), Student-t",
          f"- update: library filter, predict()+update() per step, mean over "
          f"{'all' if args.engine == 'library' else args.timing_runs} run(s) per case",
          "- paper columns: Table II, Matlab; its \"time\" is not defined in the paper", ""]
    for case in cases:
        lines = table_lines(recs, case)
        title = f"{case} ({CASES[case]})"
        print_table(HEADER, lines, f"Numerical experiment — {title}")
        md += [f"## {title}", "", markdown_table(HEADER, lines)]
    if args.engine == "fast" and res["check"]:
        worst = max(res["check"].values())
        msg = (f"self-check, fast path vs library filters on {args.timing_runs} run(s) per "
               f"case: max |Δ position| = {worst:.2e} m")
        print(msg)
        md += [f"- {msg}"]
    md += ["", "![tracks](tracks.png)", "", "![rmse](rmse.png)", ""]
    (out / "numerical.md").write_text("\n".join(md))
    (out / "setup.txt").write_text(repr(asdict(setup)) + "\n")
    print(f"{desc}; wall time {wall:.1f} s")
    print(f"wrote {out / 'results.csv'}, {out / 'summary.csv'}, {out / 'numerical.md'}, "
          f"{out / 'tracks.png'}, {out / 'rmse.png'}")
    if bad_check:
        (case, e), v = max(bad_check.items(), key=lambda kv: kv[1])
        print(f"error: fast path differs from the library {e} on case {case} by {v:.3g} m "
              f"(> {SELF_CHECK_TOL:g}); rerun with --engine library")
        return 1
    return 0
