"""PSO-tuned measurement noise covariance R (Zhou et al. 2024, §4).

The paper tunes R with particle swarm optimisation on recorded data, minimising the *posterior*
residual (eq 35)::

    J_paper(R) = 1/N Σ_k ‖y_k − H x̂_{k|k}(R)‖²

That fitness is degenerate: as R → 0 the gain tends to a projection onto the measurements,
x̂_{k|k} reproduces y_k exactly in the measured components and J_paper → 0.  PSO therefore drives
R to the lower edge of its search box (the filter then trusts every fix completely, the opposite
of what tuning is for).  :func:`posterior_residual` implements it so that this can be shown.

The well-posed criterion used here is the innovation likelihood (the negative log-likelihood of
the innovations of a linear-Gaussian model, up to constants; Mehra 1970, Shumway & Stoffer)::

    J(R) = Σ_k ( ν_kᵀ S_k⁻¹ ν_k + log det S_k ),    ν_k = y_k − H x̄_k,  S_k = H P̄_k Hᵀ + R

It is minimised (in expectation) at the true R when F, H, Q are right: too small an R makes
the νᵀS⁻¹ν term blow up, too large an R the log det S term.

Parametrisation: R = diag(10^θ) with one parameter per *group* of measurement channels
(e.g. all position channels share one variance, all velocity channels another), θ searched in
a box of log10 variances by :func:`controllers.optim.pso_minimize`.  The swarm is evaluated in
one batched numpy run of the KF over all particles (:func:`kf_fitness_batch`), plugged in through
``pso_minimize``'s ``map_fn`` seam, so a 12-particle swarm costs about one filter run per
iteration.  (``controllers`` is a numpy-only library like this one.)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from controllers.optim import pso_minimize

__all__ = [
    "FITNESSES",
    "TuneROptions",
    "TunedR",
    "innovation_nll",
    "kf_fitness_batch",
    "posterior_residual",
    "r_from_params",
    "tune_r",
]

FITNESSES = ("nll", "paper")


def innovation_nll(filt, Z) -> float:
    """Σ(νᵀS⁻¹ν + log det S) of a bank filter run over fixes ``Z`` (predict, then update each).

    The filter is advanced in place; fixes with NaN are skipped (prediction only).
    """
    J = 0.0
    for z in Z:
        filt.predict()
        if filt.update(z):
            _, logdet = np.linalg.slogdet(filt.S)
            J += float(filt.nis) + float(logdet)
    return J


def posterior_residual(filt, Z) -> float:
    """The paper's eq 35: mean ‖y_k − H x̂_{k|k}‖² over the fixes (degenerate: R → 0 wins)."""
    J, n = 0.0, 0
    for z in Z:
        filt.predict()
        if filt.update(z):
            r = np.asarray(z, dtype=float) - filt.H @ filt.x
            J += float(r @ r)
            n += 1
    return J / max(n, 1)


def r_from_params(theta, groups: Sequence[Sequence[int]], m: int) -> np.ndarray:
    """R = diag(10^θ_g on the channels of group g); θ (G,) or (B, G) → (m, m) or (B, m, m)."""
    th = np.asarray(theta, dtype=float)
    single = th.ndim == 1
    th = np.atleast_2d(th)
    diag = np.empty((th.shape[0], m))
    covered = np.zeros(m, dtype=bool)
    for g, idx in enumerate(groups):
        diag[:, list(idx)] = 10.0 ** th[:, g : g + 1]
        covered[list(idx)] = True
    if not covered.all():
        raise ValueError("groups must cover every measurement channel")
    R = np.zeros((th.shape[0], m, m))
    ii = np.arange(m)
    R[:, ii, ii] = diag
    return R[0] if single else R


def kf_fitness_batch(F, H, Q, Rs, Z, x0, P0) -> dict[str, np.ndarray]:
    """Run B Kalman filters (one per R in ``Rs``, shape (B, m, m)) over the same fixes at once.

    Each step: predict, then update with ``Z[k]`` (rows with NaN are skipped),
    update in the short form P − K S Kᵀ (symmetrised; equal to the Joseph form of
    :class:`estimators.kf.KF` for the optimal gain, ~1e-12 apart).  A non-positive-definite S
    raises ``numpy.linalg.LinAlgError``.  Returns ``nll`` (B,) =
    Σ(νᵀS⁻¹ν + log det S), ``paper`` (B,) = eq 35's mean posterior residual, and the final
    ``x`` (B, n), ``P`` (B, n, n).
    """
    F = np.asarray(F, dtype=float)
    H = np.asarray(H, dtype=float)
    Q = np.asarray(Q, dtype=float)
    Rs = np.asarray(Rs, dtype=float)
    Z = np.asarray(Z, dtype=float)
    B, n = Rs.shape[0], F.shape[0]
    x = np.repeat(np.asarray(x0, dtype=float).reshape(1, n), B, axis=0)
    P = np.repeat(np.asarray(P0, dtype=float).reshape(1, n, n), B, axis=0)
    FT, HT = F.T, H.T
    nll = np.zeros(B)
    res = np.zeros(B)
    n_used = 0
    for z in Z:
        x = x @ FT
        P = F @ P @ FT + Q
        if not np.all(np.isfinite(z)):
            continue
        PHT = P @ HT
        S = H @ PHT + Rs
        L = np.linalg.cholesky(S)
        Li = np.linalg.inv(L)
        Si = Li.transpose(0, 2, 1) @ Li
        nu = z - x @ HT
        w = np.einsum("bij,bj->bi", Li, nu)
        nis = np.einsum("bi,bi->b", w, w)
        logdet = 2.0 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
        K = PHT @ Si
        x = x + np.einsum("bij,bj->bi", K, nu)
        # P − K S Kᵀ = P − K (P Hᵀ)ᵀ; equal to the Joseph form for the optimal gain
        P = P - K @ PHT.transpose(0, 2, 1)
        P = 0.5 * (P + P.transpose(0, 2, 1))
        r = z - x @ HT
        nll += nis + logdet
        res += np.einsum("bi,bi->b", r, r)
        n_used += 1
    bad = ~np.isfinite(nll)
    nll[bad] = np.inf
    return {"nll": nll, "paper": res / max(n_used, 1), "x": x, "P": P}


@dataclass
class TunedR:
    """Result of :func:`tune_r`."""

    R: np.ndarray
    theta: np.ndarray  # log10 variances per group
    fun: float
    fitness: str
    at_bound: bool  # some θ ended within 1 % of the box edge
    history: list[float] = field(default_factory=list)
    n_evals: int = 0


@dataclass(frozen=True)
class TuneROptions:
    """The search of :func:`tune_r`: ``fitness`` ``"nll"`` (innovation likelihood,
    recommended) or ``"paper"`` (eq 35's posterior residual, kept to demonstrate that it is
    minimised at the lower bound, R → 0); the PSO's ``pop`` and ``iters``; ``rng`` its seed or
    Generator (deterministic for a given seed)."""

    fitness: str = "nll"
    pop: int = 12
    iters: int = 15
    rng: np.random.Generator | int | None = None


def tune_r(F, H, Q, Z, x0, P0, groups: Sequence[Sequence[int]], lo, hi,
           **options) -> TunedR:
    """PSO over log10 variances of R (one per group) on recorded fixes ``Z``.

    ``lo``, ``hi``: bounds of θ (log10 m² / (m/s)² ...), one per group; ``options``: the fields
    of :class:`TuneROptions` by name (``fitness``, ``pop``, ``iters``, ``rng``).
    """
    o = TuneROptions(**options)
    fitness = o.fitness
    if fitness not in FITNESSES:
        raise ValueError(f"fitness must be one of {FITNESSES}, got {fitness!r}")
    H = np.asarray(H, dtype=float)
    m = H.shape[0]
    lo = np.broadcast_to(np.asarray(lo, dtype=float), (len(groups),)).copy()
    hi = np.broadcast_to(np.asarray(hi, dtype=float), (len(groups),)).copy()

    def batch_map(_fun, xs):
        Rs = r_from_params(np.asarray(xs), groups, m)
        out = kf_fitness_batch(F, H, Q, Rs, Z, x0, P0)[fitness]
        return [float(v) if math.isfinite(v) else math.inf for v in out]

    def single(theta):  # only used if someone calls fun directly
        return batch_map(None, [theta])[0]

    res = pso_minimize(single, lo, hi, pop=o.pop, iters=o.iters, rng=o.rng, map_fn=batch_map)
    span = hi - lo
    at_bound = bool(np.any((res.x - lo < 0.01 * span) | (hi - res.x < 0.01 * span)))
    return TunedR(R=r_from_params(res.x, groups, m), theta=res.x.copy(), fun=float(res.fun),
                  fitness=fitness, at_bound=at_bound, history=list(res.history),
                  n_evals=res.n_evals)
