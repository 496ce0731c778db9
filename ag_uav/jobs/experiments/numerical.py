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
import csv
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

NAME = "numerical"
HELP = ("the paper's numerical experiment (eqs 8-11, Fig. 3, Table II): KF, MCKF, PCA-KF, "
        "PCA-MCKF (+ coloured-noise baselines) on a lawnmower, 4 noise cases, N runs")

ESTIMATORS = ("kf", "mckf", "pca-kf", "pca-mckf", "kf-bias", "kf-diff", "mckf-norec",
              "pca-mckf-norec")
#: suffix of the MCKF rows without the lock-out recovery rule (``recovery=None``): Chen et al.
#: 2017's MCKF as published; the plain names carry the library default ``recovery="kf"``
NOREC = "-norec"
#: noise case -> GPS preset of :mod:`ag_uav.vehicle.gps`
CASES = {"white": "paper-numerical", "coloured": "coloured", "impulsive": "mixture",
         "coloured-impulsive": "coloured-impulsive"}
#: Candan & Li, Table II, "Computer (Matlab)" column: (time [s, undefined], RMSE [m])
PAPER_MATLAB = {"mckf": (6880.0, 0.137), "kf": (2415.0, 0.328), "pca-mckf": (7530.0, 0.068),
                "pca-kf": (2865.0, 0.343)}
COLOURS = {"mckf-norec": "tab:olive", "pca-mckf-norec": "tab:pink",
           "kf": "tab:blue", "mckf": "tab:orange", "pca-kf": "tab:green",
           "pca-mckf": "tab:red", "kf-bias": "tab:purple", "kf-diff": "tab:brown"}
#: the fast path must match the library filter to this (m) on the timing runs
SELF_CHECK_TOL = 1e-6
#: MCKF kernel variants, as suffixes of the MCKF names (see :func:`parse_estimator`)
KERNELS = ("adaptive", "multi")


@dataclass(frozen=True)
class Setup:
    """Everything that defines one experiment (picklable; sent to the workers)."""

    n_legs: int = 4
    leg_m: float = 100.0
    spacing_m: float = 10.0
    speed: float = 5.0
    dt: float = 0.05
    sigma: float = 2.0
    window: int = 20
    pca_mode: str = "hankel"
    tau_s: float = 1.0
    bias_fraction: float = 0.95
    max_steps: int | None = None  # truncate the trajectory (tests)


# ------------------------------------------------------------------------------ truth and data
def lawnmower(n_legs: int = 4, leg_m: float = 100.0, spacing_m: float = 10.0,
              speed: float = 5.0, dt: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Constant-speed lawnmower sampled every ``dt``: legs along +x, −x, +x, … at y = 0,
    spacing, 2·spacing, …, joined by semicircles of radius spacing/2.  Returns positions and
    velocities, each (T, 2), T = ⌊length / (speed·dt)⌋ + 1."""
    r = 0.5 * spacing_m
    s_turn = math.pi * r
    total = n_legs * leg_m + (n_legs - 1) * s_turn
    ds = speed * dt
    T = int(math.floor(total / ds + 1e-9)) + 1
    pos = np.empty((T, 2))
    vel = np.empty((T, 2))
    for k in range(T):
        s = k * ds
        i = min(int(s // (leg_m + s_turn)), n_legs - 1)
        rem = s - i * (leg_m + s_turn)
        sign = 1.0 if i % 2 == 0 else -1.0
        x0 = 0.0 if i % 2 == 0 else leg_m
        y0 = i * spacing_m
        if rem <= leg_m or i == n_legs - 1:
            pos[k] = (x0 + sign * rem, y0)
            vel[k] = (sign * speed, 0.0)
        else:
            a = (rem - leg_m) / r  # 0..π around the turn centre
            cx = leg_m if i % 2 == 0 else 0.0
            pos[k] = (cx + sign * r * math.sin(a), y0 + r - r * math.cos(a))
            vel[k] = (sign * speed * math.cos(a), speed * math.sin(a))
    return pos, vel


def truth(setup: Setup) -> tuple[np.ndarray, np.ndarray]:
    pos, vel = lawnmower(setup.n_legs, setup.leg_m, setup.spacing_m, setup.speed, setup.dt)
    if setup.max_steps is not None:
        pos, vel = pos[: setup.max_steps], vel[: setup.max_steps]
    return pos, vel


def fixes(case: str, run: int, pos: np.ndarray, dt: float) -> np.ndarray:
    """GPS fixes (T, 2) of run ``run`` (seed = run) for noise ``case``."""
    from ...vehicle.gps import GpsSensor

    sensor = GpsSensor.from_preset(CASES[case], seed=int(run), rate_hz=1.0 / dt)
    err = sensor.generate_errors(len(pos))[:, :2]
    return pos + err


# ---------------------------------------------------------------------------------- filters
def model():
    from estimators.models import paper_numerical_model

    return paper_numerical_model()


def initial(setup: Setup, pos: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Prior: the true initial state, P0 = diag(R_x, 1, R_y, 1)."""
    m = model()
    x0 = np.array([pos[0, 0], vel[0, 0], pos[0, 1], vel[0, 1]])
    P0 = np.diag([m.R[0, 0], 1.0, m.R[1, 1], 1.0])
    return x0, P0


def parse_estimator(name: str) -> tuple[str, str, float | None]:
    """``BASE[-adaptive|-multi][@SIGMA]`` → (BASE, kernel, σ or None): the MCKF names (``mckf``,
    ``pca-mckf`` and their ``-norec`` forms) take a kernel bandwidth (``mckf@4``, ``mckf@inf``:
    the KF's weights) and a kernel variant: ``-adaptive`` (σ_k = σ max(1, √ŝ_k), the
    ``adaptive_sigma`` rule of :class:`estimators.MCKF`) or ``-multi`` (σ on the 2 measurement
    rows, ∞ on the 4 state rows); "fixed" when neither.  ValueError for anything else."""
    base, at, sig = name.partition("@")
    sigma = None
    if at:
        try:
            sigma = float(sig)
        except ValueError:
            raise ValueError(f"{name!r}: expected NAME@SIGMA with a number (or inf)") from None
        if not sigma > 0:
            raise ValueError(f"{name!r}: sigma must be > 0")
    kernel = "fixed"
    for k in KERNELS:
        if base.endswith("-" + k):
            base, kernel = base[: -len(k) - 1], k
    if base not in ESTIMATORS or ((at or kernel != "fixed") and "mckf" not in base):
        raise ValueError(f"{name!r}: allowed {', '.join(ESTIMATORS)}; the MCKF ones also as "
                         "NAME[-adaptive|-multi][@SIGMA]")
    return base, kernel, sigma


def filter_params(name: str, setup: Setup) -> dict[str, Any]:
    """Keyword arguments of ``estimators.make(name, F=..., ...)`` besides the matrices."""
    m = model()
    base, kernel, sig = parse_estimator(name)
    if base != name:
        p = filter_params(base, setup)
        s = setup.sigma if sig is None else sig
        p["sigma"] = np.r_[[np.inf] * 4, [s] * 2] if kernel == "multi" else s
        if kernel == "adaptive":
            p["adaptive_sigma"] = True
        return p
    if name.endswith(NOREC):
        return {**filter_params(name[: -len(NOREC)], setup), "recovery": None}
    if name in ("mckf", "pca-mckf"):
        p: dict[str, Any] = {"sigma": setup.sigma}
    else:
        p = {}
    if name.startswith("pca-"):
        p.update(window=setup.window, mode=setup.pca_mode)
    if name == "kf-bias":
        p.update(tau=setup.tau_s, sigma_b=np.sqrt(setup.bias_fraction * np.diag(m.R)),
                 dt=setup.dt, R=(1.0 - setup.bias_fraction) * m.R)
    if name == "kf-diff":
        p.update(tau=setup.tau_s, dt=setup.dt)
    return p


def make_filter(name: str, setup: Setup, x0: np.ndarray, P0: np.ndarray):
    import estimators

    m = model()
    kw = {"F": m.F, "H": m.H, "Q": m.Q, "R": m.R, "x0": x0, "P0": P0}
    kw.update(filter_params(name, setup))
    return estimators.make(parse_estimator(name)[0].removesuffix(NOREC), **kw)


def run_library(name: str, setup: Setup, Z: np.ndarray, x0: np.ndarray, P0: np.ndarray
                ) -> tuple[np.ndarray, float]:
    """The library filter step by step on fixes Z (T, 2): position track (T, 2) and the mean
    wall time of ``predict() + update()`` per step (s)."""
    f = make_filter(name, setup, x0, P0)
    T = len(Z)
    out = np.empty((T, 2))
    rows = list(Z)
    clock = time.perf_counter
    t0 = clock()
    for k in range(T):
        if k:
            f.predict()
        f.update(rows[k])
        x = f.x
        out[k, 0] = x[0]
        out[k, 1] = x[2]
    return out, (clock() - t0) / T


def _library_states(name: str, setup: Setup, Z: np.ndarray, x0: np.ndarray, P0: np.ndarray
                    ) -> np.ndarray:
    """The library filter's full state (T, n) on fixes Z (the PCA filters run their own
    block)."""
    f = make_filter(name, setup, x0, P0)
    out = np.empty((len(Z), x0.size))
    for k in range(len(Z)):
        if k:
            f.predict()
        f.update(Z[k])
        out[k] = f.x
    return out


# --------------------------------------------------------------------------- fast: linear KFs
def gain_sequence(name: str, setup: Setup, T: int, x0: np.ndarray, P0: np.ndarray
                  ) -> np.ndarray:
    """Gains K_k (T, n, m) of a fixed-gain filter, recorded from the library filter run on
    dummy (zero) fixes; with fixed F, H, Q, R and no missing fix they do not depend on data."""
    f = make_filter(name, setup, x0, P0)
    z = np.zeros(2)
    Ks = []
    for k in range(T):
        if k:
            f.predict()
        f.update(z)
        Ks.append(np.array(f.K))
    return np.array(Ks)


def kf_fixed_gain(F: np.ndarray, H: np.ndarray, Ks: np.ndarray, x0: np.ndarray,
                  Z: np.ndarray) -> np.ndarray:
    """KF state recursion with precomputed gains for a batch of runs: Z (B, T, m) → x̂ (B, T, n).
    x̄ = F x̂, x̂ = x̄ + K_k (z_k − H x̄) (no predict at k = 0)."""
    B, T, _ = Z.shape
    FT, HT = F.T, H.T
    x = np.broadcast_to(x0, (B, x0.size)).copy()
    out = np.empty((B, T, x0.size))
    for k in range(T):
        if k:
            x = x @ FT
        x = x + (Z[:, k] - x @ HT) @ Ks[k].T
        out[:, k] = x
    return out


def kf_diff_fixed_gain(F: np.ndarray, H: np.ndarray, gamma: np.ndarray, Ks: np.ndarray,
                       x0: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Bryson-Henrikson recursion of :class:`estimators.DifferencingKF` (one predict per fix)
    with precomputed gains: k = 0 plain KF update; then with H̄ = H F − Γ H,
    x̂_k = F x̂_{k−1} + K_k (z_k − Γ z_{k−1} − H̄ x̂_{k−1})."""
    B, T, _ = Z.shape
    Hb = np.dot(H, F) - np.dot(gamma, H)
    x = np.broadcast_to(x0, (B, x0.size)).copy()
    out = np.empty((B, T, x0.size))
    x = x + (Z[:, 0] - x @ H.T) @ Ks[0].T
    out[:, 0] = x
    for k in range(1, T):
        y = Z[:, k] - Z[:, k - 1] @ gamma.T - x @ Hb.T
        x = x @ F.T + y @ Ks[k].T
        out[:, k] = x
    return out


# ------------------------------------------------------------------------------ fast: PCA
def pca_batch(Z: np.ndarray, setup: Setup) -> np.ndarray:
    """Output of :class:`estimators.PCABlock` (2 channels, the filters' window/mode defaults)
    for every fix of every run: Z (B, T, 2) → (B, T, 2), the runs as the rows of the batched
    block (:func:`estimators.batched.pca_batch`, the library's ``pca_row``).  The first N − 1
    fixes pass through unchanged."""
    from estimators import PCABlock
    from estimators.batched import pca_batch as run_rows
    from estimators.pca import PCA_MODE

    blk = PCABlock(2, setup.window, None, setup.pca_mode)
    B, T, c = Z.shape
    Zt = np.ascontiguousarray(np.asarray(Z, dtype=float).transpose(1, 0, 2))  # T × B × c
    buf = np.zeros((B, c, 2 * blk.N))
    pcs = np.zeros((B, 2), dtype=np.int64)
    zf = np.empty((B, c))
    rows = np.ones(B, dtype=bool)
    out = np.empty((B, T, c))
    for k in range(T):
        run_rows(buf, pcs, zf, Zt[k], rows, blk.N, blk.L, blk.n_components,
                 PCA_MODE[blk.mode])
        out[:, k] = zf
    return out


# ------------------------------------------------------------------------------ fast: MCKF
def mckf_batch(F: np.ndarray, H: np.ndarray, Q: np.ndarray, R: np.ndarray, x0: np.ndarray,
               P0: np.ndarray, Z: np.ndarray, sigma: float = 2.0, eps: float = 1e-6,
               max_iter: int = 10, kernel_floor: float = 1e-12, recovery: str | None = "kf",
               lockout_n: int = 10, reject_weight: float = 0.05) -> np.ndarray:
    """:class:`estimators.MCKF` on a batch of runs: Z (B, T, m) → x̂ (B, T, n), the runs as the
    rows of :class:`estimators.batched.BatchMCKF` (the library's ``mckf_update_row``; no
    predict at k = 0)."""
    from estimators import MCKF
    from estimators.batched import BatchMCKF

    B, T, m = Z.shape
    n = F.shape[0]
    f = MCKF(F, H, Q, R, x0, P0, sigma=sigma, eps=eps, max_iter=max_iter,
             kernel_floor=kernel_floor, recovery=recovery, lockout_n=lockout_n,
             reject_weight=reject_weight)
    bf = BatchMCKF(F, H, Q, np.broadcast_to(f.R, (B, m, m)), np.broadcast_to(f.x, (B, n)),
                   np.broadcast_to(f.P, (B, n, n)), [], [], 1.0)
    bf._from([f] * B)
    Zt = np.ascontiguousarray(np.asarray(Z, dtype=float).transpose(1, 0, 2))  # T × B × m
    out = np.empty((B, T, n))
    for k in range(T):
        if k:
            bf.predict()
        bf.update(Zt[k])
        out[:, k] = bf.x
    return out


# ------------------------------------------------------------------------------------ tasks
def _rmse(track: np.ndarray, pos: np.ndarray) -> tuple[float, float, float]:
    e = track - pos
    ex, ey = float(np.mean(e[:, 0] ** 2)), float(np.mean(e[:, 1] ** 2))
    return math.sqrt(ex + ey), math.sqrt(ex), math.sqrt(ey)


def fast_tracks(setup: Setup, case: str, runs: list[int], ests: list[str],
                gains: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Fixes (B, T, 2) and every estimator's position track (B, T, 2) for ``runs``, fast path."""
    pos, vel = truth(setup)
    x0, P0 = initial(setup, pos, vel)
    m = model()
    Z = np.stack([fixes(case, r, pos, setup.dt) for r in runs])
    Zp = pca_batch(Z, setup) if any(e.startswith("pca-") for e in ests) else None
    tracks: dict[str, np.ndarray] = {}
    for e in ests:
        data = Zp if e.startswith("pca-") else Z
        base, kernel, _ = parse_estimator(e)
        if e in ("kf", "pca-kf"):
            xs = kf_fixed_gain(m.F, m.H, gains["kf"], x0, data)
        elif kernel == "adaptive":  # BatchMCKF has no adaptive rows: the library, run by run
            xs = np.stack([_library_states(e, setup, Z[i], x0, P0) for i in range(len(Z))])
        elif "mckf" in base:
            xs = mckf_batch(m.F, m.H, m.Q, m.R, x0, P0, data,
                            sigma=filter_params(e, setup)["sigma"],
                            recovery=None if base.endswith(NOREC) else "kf")
        elif e == "kf-bias":
            f = make_filter(e, setup, x0, P0)
            xs = kf_fixed_gain(f.kf.F, f.kf.H, gains[e], f.x_aug, data)
        elif e == "kf-diff":
            # Γ over one predict, as DifferencingKF computes it: exp(−n_pred·dt/τ), n_pred = 1
            gamma = np.diag(np.exp(-1 * setup.dt / np.full(2, setup.tau_s)))
            xs = kf_diff_fixed_gain(m.F, m.H, gamma, gains[e], x0, data)
        else:
            raise ValueError(f"unknown estimator {e!r}")
        tracks[e] = xs[:, :, [0, 2]]
    return Z, tracks


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
    from ..executor import make_executor

    jobs = make_jobs(setup, cases, ests, n_runs, chunk, engine, timing_runs, keep)
    results: list[Any] = [None] * len(jobs)
    bar = None
    if progress:
        from ..._progress import progress_bar

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


# ---------------------------------------------------------------------------------- report
def t_interval(values: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """Mean and the half-width of its Student-t interval (nan for fewer than 2 values)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan
    if v.size == 1:
        return float(v[0]), math.nan
    from scipy import stats

    h = float(stats.t.ppf(0.5 + level / 2, v.size - 1)) * float(np.std(v, ddof=1))
    return float(np.mean(v)), h / math.sqrt(v.size)


def summarise(rows: list[dict[str, Any]], cases: list[str], ests: list[str]
              ) -> list[dict[str, Any]]:
    """One record per case × estimator (mean RMSE, 95 % t-interval, paired Δ vs KF, µs)."""
    recs = []
    for case in cases:
        by = {e: sorted((r for r in rows if r["case"] == case and r["estimator"] == e),
                        key=lambda r: r["run"]) for e in ["gps", *ests]}
        kf = np.array([r["rmse_m"] for r in by.get("kf", [])])
        for e in ["gps", *ests]:
            v = np.array([r["rmse_m"] for r in by[e]])
            m, h = t_interval(v)
            if kf.size == v.size and kf.size and e != "kf":
                dm, dh = t_interval(v - kf)
            else:
                dm, dh = math.nan, math.nan
            us = np.array([r["update_us"] for r in by[e]], dtype=float)
            us = us[np.isfinite(us)]
            pt, pr = PAPER_MATLAB.get(e, (math.nan, math.nan))
            recs.append({"case": case, "preset": CASES[case], "estimator": e, "runs": v.size,
                         "rmse_m": m, "rmse_ci95_m": h,
                         "rmse_x_m": float(np.mean([r["rmse_x_m"] for r in by[e]])),
                         "rmse_y_m": float(np.mean([r["rmse_y_m"] for r in by[e]])),
                         "delta_vs_kf_m": dm, "delta_ci95_m": dh,
                         "update_us": float(np.mean(us)) if us.size else math.nan,
                         "timed_runs": int(us.size),
                         "paper_matlab_time_s": pt, "paper_matlab_rmse_m": pr})
    return recs


def _f(v: float, fmt: str) -> str:
    return "–" if v is None or not math.isfinite(v) else fmt.format(v)


def _pm(m: float, h: float, fmt: str, signed: bool = False) -> str:
    if not math.isfinite(m):
        return "–"
    s = ("{:+" + fmt[2:]).format(m) if signed else fmt.format(m)
    return s if not math.isfinite(h) else f"{s} ± {fmt.format(h)}"


HEADER = ["estimator", "RMSE (m), mean ± 95 % t", "x / y RMSE (m)", "Δ vs KF (m), paired",
          "update (µs/step)", "paper time (s)", "paper RMSE (m)"]


def table_lines(recs: list[dict[str, Any]], case: str) -> list[list[str]]:
    out = []
    for r in recs:
        if r["case"] != case:
            continue
        out.append([r["estimator"] if r["estimator"] != "gps" else "gps (raw fixes)",
                    _pm(r["rmse_m"], r["rmse_ci95_m"], "{:.3f}"),
                    f"{r['rmse_x_m']:.2f} / {r['rmse_y_m']:.2f}",
                    _pm(r["delta_vs_kf_m"], r["delta_ci95_m"], "{:.3f}", signed=True),
                    _f(r["update_us"], "{:.0f}"), _f(r["paper_matlab_time_s"], "{:.0f}"),
                    _f(r["paper_matlab_rmse_m"], "{:.3f}")])
    return out


def plot_tracks(kept: dict[tuple[str, int], dict[str, np.ndarray]], pos: np.ndarray,
                cases: list[str], ests: list[str], run: int, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(cases)
    cols = 2 if n > 1 else 1
    rows_ = math.ceil(n / cols)
    fig, axs = plt.subplots(rows_, cols, figsize=(7 * cols, 4.2 * rows_), squeeze=False)
    for ax, case in zip(axs.flat, cases, strict=False):
        tr = kept.get((case, run))
        if tr is None:
            continue
        ax.plot(tr["fixes"][:, 0], tr["fixes"][:, 1], ".", color="0.7", ms=2,
                label="GPS fixes")
        ax.plot(pos[:, 0], pos[:, 1], "k-", lw=2, label="reference")
        # the coloured-noise baselines are jagged on white noise: draw them first, faint
        for e in sorted(ests, key=lambda e: e in PAPER_MATLAB):
            main_ = e in PAPER_MATLAB
            ax.plot(tr[e][:, 0], tr[e][:, 1], "-", lw=1.0 if main_ else 0.6,
                    alpha=1.0 if main_ else 0.45, color=COLOURS.get(e), label=e)
        span = np.ptp(pos[:, 1])
        ax.set_ylim(pos[:, 1].min() - 0.6 * span - 5, pos[:, 1].max() + 0.6 * span + 5)
        ax.set_title(f"{case} ({CASES[case]}), run {run}", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.grid(alpha=0.3)
    for ax in list(axs.flat)[n:]:
        ax.axis("off")
    axs.flat[0].legend(fontsize=7, ncol=2, loc="upper right")
    fig.suptitle("Numerical experiment (Candan & Li eqs 8-11, Fig. 3 style): "
                 "R = diag(10, 100) m², Ts = 0.05 s", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_rmse(rows: list[dict[str, Any]], cases: list[str], ests: list[str], path: Path
              ) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, len(cases), figsize=(3.6 * len(cases) + 1, 4), squeeze=False)
    for ax, case in zip(axs[0], cases, strict=True):
        data = [[r["rmse_m"] for r in rows if r["case"] == case and r["estimator"] == e]
                for e in ests]
        ax.boxplot(data, showmeans=True)
        ax.set_xticks(range(1, len(ests) + 1), ests, rotation=45, fontsize=8)
        paper = [PAPER_MATLAB.get(e, (0, math.nan))[1] for e in ests]
        ax.plot(range(1, len(ests) + 1), paper, "r*", ms=9, label="paper Table II (Matlab)")
        ax.set_title(case, fontsize=9)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    axs[0, 0].set_ylabel("position RMSE per run (m)")
    axs[0, 0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_csv(path: Path, recs: list[dict[str, Any]]) -> None:
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(recs[0]))
        w.writeheader()
        for r in recs:
            w.writerow({k: ("" if isinstance(v, float) and math.isnan(v) else
                            (f"{v:.12g}" if isinstance(v, float) else v))
                        for k, v in r.items()})


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
    from ...config import ConfigError
    from ..batch import markdown_table, print_table

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
