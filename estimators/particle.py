"""Bootstrap (SIR) particle filter (Gordon, Salmond, Smith 1993), the kfuea paper's PF baseline.

Particles x⁽ⁱ⁾ (N × n) with normalised weights w⁽ⁱ⁾:

- ``predict()``: x⁽ⁱ⁾ ← f(x⁽ⁱ⁾, rng), the user's transition *sampler* (the proposal is the
  transition prior: bootstrap filter);
- ``update(z)``: log w⁽ⁱ⁾ ← log w⁽ⁱ⁾ + log p(z | x⁽ⁱ⁾) (user's log-likelihood), normalised in
  the log domain (max subtracted, so tiny likelihoods do not underflow to 0/0); if every
  log-likelihood is −inf or NaN the update is skipped and ``False`` returned;
- resampling: when the effective sample size ESS = 1 / Σ w⁽ⁱ⁾² drops below
  ``resample_frac · N`` (default N/2), **systematic resampling** (Kitagawa 1996): one
  u ~ U[0, 1/N), points u + j/N, j = 0..N−1, each takes the particle whose cumulative weight
  interval contains it; weights reset to 1/N.

Estimates: ``x`` = Σ w⁽ⁱ⁾ x⁽ⁱ⁾ and ``P`` = Σ w⁽ⁱ⁾ (x⁽ⁱ⁾ − x)(x⁽ⁱ⁾ − x)ᵀ (properties), and
:meth:`expect` for E[g(x)] (e.g. the MMSE estimate of a clean measurement h(x)).

Every random draw comes from the numpy Generator given (or built from a seed) at construction,
so a run is reproducible.  :meth:`ParticleFilter.linear_gaussian` builds the filter for
x' = F x + w, z = H x + v (w ~ N(0, Q), v ~ N(0, R)), used in tests against the KF.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["ParticleFilter", "effective_sample_size", "systematic_resample"]

Transition = Callable[[np.ndarray, np.random.Generator], np.ndarray]
LogLikelihood = Callable[[np.ndarray, np.ndarray], np.ndarray]


def effective_sample_size(w: np.ndarray) -> float:
    """ESS = 1 / Σ wᵢ² for normalised weights."""
    return float(1.0 / np.sum(np.square(w)))


def systematic_resample(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices of a systematic resample of normalised weights ``w`` (one uniform draw).

    Particle i is copied either ⌊N wᵢ⌋ or ⌈N wᵢ⌉ times.
    """
    N = w.size
    pts = (rng.random() + np.arange(N)) / N
    c = np.cumsum(w)
    c[-1] = 1.0  # guard against round-off
    return np.minimum(np.searchsorted(c, pts, side="right"), N - 1)


class ParticleFilter:
    """Bootstrap particle filter with systematic resampling when ESS < ``resample_frac``·N.

    Parameters
    ----------
    transition : f(particles (N, n), rng) -> new particles (N, n), sampling the process noise.
    log_likelihood : g(z, particles) -> (N,) log p(z | x⁽ⁱ⁾) (up to a constant).
    particles : initial particles (N, n), or use ``x0``, ``P0`` and ``n_particles`` to draw them
        from N(x0, P0).
    rng : numpy Generator or integer seed.
    """

    def __init__(self, transition: Transition, log_likelihood: LogLikelihood, *,
                 particles: np.ndarray | None = None, x0=None, P0=None,
                 n_particles: int = 1000, rng: np.random.Generator | int | None = 0,
                 resample_frac: float = 0.5) -> None:
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        if particles is None:
            if x0 is None or P0 is None:
                raise ValueError("give particles or x0 and P0")
            x0 = np.asarray(x0, dtype=float).reshape(-1)
            particles = self.rng.multivariate_normal(x0, np.asarray(P0, dtype=float),
                                                     size=int(n_particles), method="cholesky")
        self.particles = np.array(particles, dtype=float, ndmin=2)
        self.N, self.n = self.particles.shape
        if self.N < 2:
            raise ValueError("need at least 2 particles")
        if not 0.0 < resample_frac <= 1.0:
            raise ValueError("resample_frac must be in (0, 1]")
        self.transition = transition
        self.log_likelihood = log_likelihood
        self.resample_frac = float(resample_frac)
        self.logw = np.full(self.N, -np.log(self.N))
        self.ess = float(self.N)
        self.n_resamples = 0
        self.resampled = False

    @classmethod
    def linear_gaussian(cls, F, H, Q, R, x0, P0, **kw) -> ParticleFilter:
        """PF for x' = F x + w, z = H x + v with Gaussian w ~ N(0, Q), v ~ N(0, R)."""
        F = np.asarray(F, dtype=float)
        H = np.asarray(H, dtype=float)
        Lq = np.linalg.cholesky(np.asarray(Q, dtype=float))
        Ri = np.linalg.inv(np.asarray(R, dtype=float))

        def f(X, rng):
            return X @ F.T + rng.standard_normal(X.shape) @ Lq.T

        def g(z, X):
            e = z - X @ H.T
            return -0.5 * np.einsum("ij,jk,ik->i", e, Ri, e)

        return cls(f, g, x0=x0, P0=P0, **kw)

    # -------------------------------------------------------------------------- estimates
    @property
    def weights(self) -> np.ndarray:
        return np.exp(self.logw)

    @property
    def x(self) -> np.ndarray:
        return self.weights @ self.particles

    @property
    def P(self) -> np.ndarray:
        w = self.weights
        d = self.particles - w @ self.particles
        return (d * w[:, None]).T @ d

    def expect(self, g: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """Σ w⁽ⁱ⁾ g(x⁽ⁱ⁾) for a vectorised g: (N, n) -> (N, ...)."""
        return np.tensordot(self.weights, g(self.particles), axes=1)

    # -------------------------------------------------------------------------------- steps
    def predict(self) -> None:
        self.particles = np.asarray(self.transition(self.particles, self.rng), dtype=float)

    def update(self, z) -> bool:
        """Reweight by p(z | x); resample if ESS < resample_frac·N.  False if no fix/all −inf."""
        self.resampled = False
        if z is None:
            return False
        z = np.asarray(z, dtype=float)
        if not np.all(np.isfinite(z)):
            return False
        ll = np.asarray(self.log_likelihood(z, self.particles), dtype=float).reshape(self.N)
        ll = np.where(np.isnan(ll), -np.inf, ll)
        lw = self.logw + ll
        mx = float(np.max(lw))
        if not np.isfinite(mx):
            return False
        w = np.exp(lw - mx)
        w /= w.sum()
        self.ess = effective_sample_size(w)
        if self.ess < self.resample_frac * self.N:
            idx = systematic_resample(w, self.rng)
            self.particles = self.particles[idx]
            self.logw = np.full(self.N, -np.log(self.N))
            self.n_resamples += 1
            self.resampled = True
        else:
            with np.errstate(divide="ignore"):
                self.logw = np.log(w)
        return True
