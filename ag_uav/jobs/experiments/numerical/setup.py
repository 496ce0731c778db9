"""The numerical experiment's setup: its constants, the lawnmower truth, the GPS fixes of each
noise case, the filters by name and the library filter run step by step."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
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
    from ....vehicle.gps import GpsSensor

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


def library_states(name: str, setup: Setup, Z: np.ndarray, x0: np.ndarray, P0: np.ndarray
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
