"""Overlapping Allan variance of a sampled series and the analytic Allan variance of the noise
terms a GNSS error model is built from (white, first-order Gauss–Markov, random walk).

The series ``y_k`` (k = 0 … N−1, one sample every ``τ0``; here a position error in metres) is
read as the "rate" of the Allan-variance literature, so that white noise has the slope −1/2 in
a log–log plot of the deviation and a random walk +1/2 (IEEE Std 952-1997, Annex C; El-Sheimy,
Hou & Niu 2008, "Analysis and modeling of inertial sensors using Allan variance", IEEE Trans.
Instrum. Meas. 57(1), Table 1).

Overlapping estimator (Riley 2008, NIST SP 1065, eq. 14), with the phase
``x_j = τ0 Σ_{i<j} y_i`` (j = 0 … N) and ``τ = m τ0``::

    σ²(τ) = 1 / (2 τ² (N + 1 − 2m)) · Σ_{j=0}^{N−2m} (x_{j+2m} − 2 x_{j+m} + x_j)²

Analytic Allan variance of each term (the discrete forms are exact for the sampled processes the
product's generator draws, :mod:`ag_uav.vehicle.gps.noise`; each tends to the continuous form of
IEEE 952 / El-Sheimy et al. as τ0 → 0):

* white, std σ_w per sample: ``σ²(mτ0) = σ_w² / m`` (continuous: ``N²/τ`` with ``N² = σ_w² τ0``).
* first-order Gauss–Markov, stationary std σ, correlation time T (``ρ = e^{−τ0/T}``): with the
  block means ``ȳ`` of m samples, ``σ² = Var(ȳ) − Cov(ȳ_A, ȳ_B)`` for adjacent blocks, and
  ``Var(ȳ) = σ²/m² [m + 2 Σ_{k=1}^{m−1} (m − k) ρ^k]``, ``Cov = σ² ρ S² / m²``,
  ``S = (1 − ρ^m)/(1 − ρ)``.  Continuous form (IEEE 952 Annex C, "exponentially correlated
  (Markov) noise"; El-Sheimy et al. 2008, correlated noise), with ``q_c² = 2σ²/T``::

      σ²(τ) = (q_c T)²/τ · [1 − T/(2τ) (3 − 4 e^{−τ/T} + e^{−2τ/T})]

  which reads ``2σ²τ/(3T)`` (slope +1/2) for τ ≪ T and ``2σ²T/τ`` (slope −1/2) for τ ≫ T.
* random walk, step std q per sample: ``σ²(mτ0) = q² (2m² + 1)/(6m)`` (continuous:
  ``K² τ/3`` with ``K² = q²/τ0``).

Expected variance about the mean of N samples (what a log's "scatter" estimates):
``E[s²] = R(0) − Var(ȳ_N)`` for a stationary term of autocovariance R (white:
``σ_w²(1 − 1/N)``; Gauss–Markov: ``σ²[1 − (N + 2 ρ(N(1−ρ) − (1−ρ^N))/(1−ρ)²)/N²]``), and
``q²(N² − 1)/(6N)`` for a random walk.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["overlapping_avar", "octave_m", "avar_white", "avar_gm", "avar_gm_continuous",
           "avar_rw", "scatter_white", "scatter_gm", "scatter_rw", "loglog_slope"]


def octave_m(n: int, max_frac: float = 0.25) -> np.ndarray:
    """Octave-spaced cluster sizes 1, 2, 4, … up to ``max_frac · n`` (at least one)."""
    top = max(1, int(max_frac * n))
    return 2 ** np.arange(int(math.log2(top)) + 1)


def overlapping_avar(y: np.ndarray, m: np.ndarray, segments: list[tuple[int, int]] | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan variance of ``y`` at cluster sizes ``m`` (τ = m τ0; the result is in
    y's units squared and does not depend on τ0, which cancels between ``x = τ0 Σ y`` and τ),
    and the number of second differences behind each value.  ``segments``: (start, stop)
    index ranges of contiguous data (a log with gaps); the squared second differences of all
    segments are pooled, a segment shorter than ``2m + 1`` samples adds none.  NaN where no
    segment is long enough."""
    y = np.asarray(y, dtype=float)
    segs = segments if segments is not None else [(0, y.size)]
    avar = np.full(len(m), np.nan)
    count = np.zeros(len(m), dtype=int)
    for i, mi in enumerate(np.asarray(m, dtype=int)):
        tot, cnt = 0.0, 0
        for a, b in segs:
            n = b - a
            if n < 2 * mi:
                continue
            x = np.concatenate(([0.0], np.cumsum(y[a:b])))
            d = x[2 * mi:] - 2.0 * x[mi:-mi] + x[: x.size - 2 * mi]
            tot += float(np.dot(d, d))
            cnt += d.size
        if cnt:
            avar[i] = tot / (2.0 * mi * mi * cnt)
            count[i] = cnt
    return avar, count


def avar_white(sigma: float, m: np.ndarray) -> np.ndarray:
    """White noise of std ``sigma`` per sample: ``σ²/m``."""
    return sigma**2 / np.asarray(m, dtype=float)


def avar_gm(sigma: float, tau_s: float, m: np.ndarray, dt: float) -> np.ndarray:
    """First-order Gauss–Markov (std ``sigma``, correlation time ``tau_s``) sampled every
    ``dt``: the exact discrete Allan variance (module docstring)."""
    mm = np.asarray(m, dtype=float)
    rho = math.exp(-dt / tau_s)
    om = 1.0 - rho
    rm = rho**mm
    s = (1.0 - rm) / om
    # Σ_{k=1}^{m-1} (m-k) ρ^k = ρ (m(1-ρ) - (1-ρ^m)) / (1-ρ)^2
    acc = rho * (mm * om - (1.0 - rm)) / om**2
    var_mean = (mm + 2.0 * acc) / mm**2
    cov = rho * s * s / mm**2
    return sigma**2 * np.maximum(var_mean - cov, 0.0)


def avar_gm_continuous(sigma: float, tau_s: float, tau: np.ndarray) -> np.ndarray:
    """IEEE 952 Annex C / El-Sheimy et al. 2008 (module docstring), ``q_c² = 2σ²/T``."""
    t = np.asarray(tau, dtype=float)
    r = t / tau_s
    return (2.0 * sigma**2 * tau_s / t) * (1.0 - (3.0 - 4.0 * np.exp(-r) + np.exp(-2.0 * r))
                                           / (2.0 * r))


def avar_rw(q: float, m: np.ndarray) -> np.ndarray:
    """Random walk with step std ``q`` per sample: ``q² (2m² + 1)/(6m)``."""
    mm = np.asarray(m, dtype=float)
    return q**2 * (2.0 * mm * mm + 1.0) / (6.0 * mm)


def scatter_white(sigma: float, n: int) -> float:
    """Expected variance about the mean of ``n`` white samples."""
    return sigma**2 * (1.0 - 1.0 / n)


def scatter_gm(sigma: float, tau_s: float, n: int, dt: float) -> float:
    """Expected variance about the mean of ``n`` consecutive Gauss–Markov samples."""
    rho = math.exp(-dt / tau_s)
    om = 1.0 - rho
    acc = rho * (n * om - (1.0 - rho**n)) / om**2
    return sigma**2 * (1.0 - (n + 2.0 * acc) / (n * n))


def scatter_rw(q: float, n: int) -> float:
    """Expected variance about the mean of ``n`` samples of a random walk."""
    return q**2 * (n * n - 1.0) / (6.0 * n)


def loglog_slope(tau: np.ndarray, adev: np.ndarray) -> float:
    """Least-squares slope of ``log adev`` against ``log tau`` (finite points)."""
    ok = np.isfinite(adev) & (adev > 0)
    return float(np.polyfit(np.log(np.asarray(tau)[ok]), np.log(np.asarray(adev)[ok]), 1)[0])
