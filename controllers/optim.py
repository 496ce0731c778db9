"""Derivative-free box-constrained optimisers for controller tuning: BB-BC, PSO and CMA-ES.

All three are ask/tell objects with a JSON-serialisable :meth:`state_dict` so that a long tuning
run can be checkpointed after any iteration and resumed with results identical to an
uninterrupted run (the numpy Generator's ``bit_generator.state`` is part of the state).
``bbbc_minimize`` / ``pso_minimize`` are thin loops over them; every population is
evaluated through ``map_fn(fun, list_of_x)`` so that a parallel executor's ``map`` can be
plugged in.

Big Bang–Big Crunch (O. K. Erol & I. Eksin, "A new optimization method: Big Bang–Big
Crunch", Advances in Engineering Software 37(2):106–111, 2006)::

    x_i ~ U(lo, hi), i = 1..N
    for k = 1..K:
        f_i = J(x_i); keep best-so-far (x*, f*)
        x_c = Σ(x_i/f_i) / Σ(1/f_i)          centre of mass (needs f_i > 0), or x_c = argmin f
        x_i = clip(x_c + s (hi - lo) N(0, I) / k, lo, hi)
        x_0 = x*                             (elitism)

Costs <= 0 are shifted before the centre of mass: f' = f - min f + δ with δ the median of
(f - min f) (1 if that is 0), so the weights stay finite and scale-free. Non-finite costs
(NaN, inf) get zero weight and never become the best.

Particle swarm (J. Kennedy & R. Eberhart 1995; constriction-equivalent constants of
M. Clerc & J. Kennedy, IEEE TEC 6(1), 2002)::

    v_i = ω v_i + c1 r1 ⊙ (p_i - x_i) + c2 r2 ⊙ (g - x_i),  |v| <= v_max (hi - lo)
    x_i = clip(x_i + v_i, lo, hi)  (velocity components that hit a bound are zeroed)

CMA-ES (N. Hansen & A. Ostermeier, "Completely derandomized self-adaptation in evolution
strategies", Evolutionary Computation 9(2):159–195, 2001; N. Hansen, "The CMA evolution
strategy: a tutorial", arXiv:1604.00772), through the PyPI library ``cmaes`` (its ``CMA``
class), run in the unit cube u = (x - lo) / (hi - lo) so one step size σ fits every axis::

    u_i ~ N(m, σ² C), i = 1..λ           (resampled, then clipped, to stay in [0, 1]^d)
    m ← m + c_m σ Σ_{i≤μ} w_i y_(i)       y = (u - m)/σ, ranked by cost
    p_σ, p_c, C, σ updated by cumulative step-size adaptation and rank-one + rank-μ updates

with m₀ = centre of the box and σ₀ = ``sigma`` (a fraction of the box width). Only the ranks
of the costs matter; non-finite costs rank last.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["BBBC", "CMAES", "PSO", "OptimResult", "bbbc_minimize", "cmaes_minimize",
           "pso_minimize"]

Objective = Callable[[np.ndarray], float]
MapFn = Callable[[Objective, list[np.ndarray]], Iterable[float]]


@dataclass
class OptimResult:
    """Outcome of a minimisation."""

    x: np.ndarray
    fun: float
    history: list[float] = field(default_factory=list)  # best-so-far cost after each iteration
    n_evals: int = 0
    iterations: int = 0
    state: dict[str, Any] = field(default_factory=dict)  # final optimiser state


def _make_rng(rng: np.random.Generator | int | None) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(0 if rng is None else rng)


def _rng_from_state(state: dict[str, Any]) -> np.random.Generator:
    bg = getattr(np.random, state["bit_generator"])()
    bg.state = state
    return np.random.Generator(bg)


def _clean_costs(costs: Iterable[float], n: int) -> np.ndarray:
    f = np.array([float(c) for c in costs], dtype=float)
    if f.shape != (n,):
        raise ValueError(f"expected {n} costs, got {f.shape[0]}")
    f[np.isnan(f)] = np.inf
    return f


class _PopulationOptimizer:
    """Book-keeping shared by BB-BC and PSO (bounds, RNG, best-so-far, history)."""

    kind = ""

    def __init__(self, lo: Any, hi: Any, pop: int, rng: np.random.Generator | int | None):
        self.lo = np.asarray(lo, dtype=float).reshape(-1)
        self.hi = np.asarray(hi, dtype=float).reshape(-1)
        if self.lo.shape != self.hi.shape or not np.all(self.hi > self.lo):
            raise ValueError("need lo < hi elementwise with equal shapes")
        if int(pop) < 2:
            raise ValueError("pop must be >= 2")
        self.pop = int(pop)
        self.dim = self.lo.size
        self.rng = _make_rng(rng)
        self.iteration = 0
        self.n_evals = 0
        self.best_x: np.ndarray | None = None
        self.best_f = np.inf
        self.history: list[float] = []

    def _uniform(self) -> np.ndarray:
        return self.lo + (self.hi - self.lo) * self.rng.random((self.pop, self.dim))

    def _record(self, X: np.ndarray, f: np.ndarray) -> None:
        self.n_evals += f.size
        i = int(np.argmin(f))
        if f[i] < self.best_f:
            self.best_f = float(f[i])
            self.best_x = X[i].copy()
        self.iteration += 1
        self.history.append(self.best_f)

    def _common_state(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "lo": self.lo.tolist(),
            "hi": self.hi.tolist(),
            "pop": self.pop,
            "iteration": self.iteration,
            "n_evals": self.n_evals,
            "best_x": None if self.best_x is None else self.best_x.tolist(),
            "best_f": self.best_f,
            "history": list(self.history),
            "rng": self.rng.bit_generator.state,
        }

    def _load_common(self, s: dict[str, Any]) -> None:
        self.rng = _rng_from_state(s["rng"])
        self.iteration = int(s["iteration"])
        self.n_evals = int(s["n_evals"])
        self.best_x = None if s["best_x"] is None else np.array(s["best_x"], dtype=float)
        self.best_f = float(s["best_f"])
        self.history = [float(v) for v in s["history"]]

    def result(self) -> OptimResult:
        """Current best as an :class:`OptimResult`."""
        x = np.full(self.dim, np.nan) if self.best_x is None else self.best_x.copy()
        return OptimResult(
            x=x,
            fun=self.best_f,
            history=list(self.history),
            n_evals=self.n_evals,
            iterations=self.iteration,
            state=self.state_dict(),
        )

    def state_dict(self) -> dict[str, Any]:  # pragma: no cover - overridden
        raise NotImplementedError


class BBBC(_PopulationOptimizer):
    """Big Bang–Big Crunch optimiser (ask/tell). See the module docstring for the update.

    Parameters
    ----------
    lo, hi : box bounds (1-D arrays of equal length).
    pop : population size N.
    rng : numpy Generator or integer seed (None: seed 0).
    spread : s, the Big-Bang standard deviation as a fraction of (hi - lo) at k = 1.
    centre : "mass" (1/f-weighted centre of mass) or "best" (best member of the generation).
    elitism : put the best-so-far point back into each new population (as member 0).
    """

    kind = "bbbc"

    def __init__(
        self,
        lo: Any,
        hi: Any,
        pop: int = 20,
        rng: np.random.Generator | int | None = None,
        spread: float = 0.5,
        centre: str = "mass",
        elitism: bool = True,
    ) -> None:
        super().__init__(lo, hi, pop, rng)
        if centre not in ("mass", "best"):
            raise ValueError(f'centre must be "mass" or "best", got {centre!r}')
        if not spread > 0.0:
            raise ValueError("spread must be > 0")
        self.spread = float(spread)
        self.centre = centre
        self.elitism = bool(elitism)
        self.centre_x: np.ndarray | None = None
        self.population = self._uniform()

    def ask(self) -> np.ndarray:
        """The population to evaluate next, shape (pop, dim) (a copy)."""
        return self.population.copy()

    def _centre(self, X: np.ndarray, f: np.ndarray) -> np.ndarray:
        ok = np.isfinite(f)
        if not ok.any():
            if self.best_x is not None:
                return self.best_x.copy()
            return 0.5 * (self.lo + self.hi)
        if self.centre == "best":
            return X[int(np.argmin(f))].copy()
        Xf, ff = X[ok], f[ok]
        fmin = ff.min()
        if fmin <= 0.0:
            gap = ff - fmin
            delta = float(np.median(gap))
            ff = gap + (delta if delta > 0.0 else 1.0)
        w = 1.0 / ff
        return (w[:, None] * Xf).sum(0) / w.sum()

    def tell(self, costs: Iterable[float]) -> None:
        """Give the costs of the last :meth:`ask`; performs one Big Crunch + Big Bang."""
        X = self.population
        f = _clean_costs(costs, self.pop)
        self._record(X, f)
        xc = self._centre(X, f)
        self.centre_x = xc
        k = self.iteration
        noise = self.rng.standard_normal((self.pop, self.dim))
        new = xc + self.spread * (self.hi - self.lo) * noise / k
        np.clip(new, self.lo, self.hi, out=new)
        if self.elitism and self.best_x is not None:
            new[0] = self.best_x
        self.population = new

    def state_dict(self) -> dict[str, Any]:
        """JSON-serialisable snapshot; :meth:`from_state` continues identically."""
        s = self._common_state()
        s.update(
            spread=self.spread,
            centre=self.centre,
            elitism=self.elitism,
            population=self.population.tolist(),
            centre_x=None if self.centre_x is None else self.centre_x.tolist(),
        )
        return s

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> BBBC:
        """Rebuild an optimiser from :meth:`state_dict` output."""
        if state.get("kind") != cls.kind:
            raise ValueError(f"not a {cls.kind} state: kind={state.get('kind')!r}")
        obj = cls(
            state["lo"],
            state["hi"],
            pop=state["pop"],
            rng=0,
            spread=state["spread"],
            centre=state["centre"],
            elitism=state["elitism"],
        )
        obj._load_common(state)
        obj.population = np.array(state["population"], dtype=float)
        cx = state.get("centre_x")
        obj.centre_x = None if cx is None else np.array(cx, dtype=float)
        return obj


class PSO(_PopulationOptimizer):
    """Global-best particle swarm optimiser (ask/tell).

    Parameters
    ----------
    lo, hi, pop, rng : as :class:`BBBC`.
    inertia : ω, or (ω_start, ω_end) for a linear decrease over ``max_iter`` iterations.
    c1, c2 : cognitive and social acceleration coefficients.
    v_max : velocity clamp as a fraction of (hi - lo).
    max_iter : iterations over which a scheduled inertia decreases (needed for a tuple).
    """

    kind = "pso"

    def __init__(
        self,
        lo: Any,
        hi: Any,
        pop: int = 20,
        rng: np.random.Generator | int | None = None,
        inertia: float | tuple[float, float] = 0.7298,
        c1: float = 1.49618,
        c2: float = 1.49618,
        v_max: float = 0.2,
        max_iter: int | None = None,
    ) -> None:
        super().__init__(lo, hi, pop, rng)
        if isinstance(inertia, tuple | list):
            if max_iter is None or max_iter < 1:
                raise ValueError("a scheduled inertia needs max_iter >= 1")
            self.inertia: tuple[float, float] = (float(inertia[0]), float(inertia[1]))
        else:
            self.inertia = (float(inertia), float(inertia))
        if not v_max > 0.0:
            raise ValueError("v_max must be > 0")
        self.c1 = float(c1)
        self.c2 = float(c2)
        self.v_max = float(v_max)
        self.max_iter = None if max_iter is None else int(max_iter)
        self.x = self._uniform()
        vmax = self.v_max * (self.hi - self.lo)
        self.v = vmax * (2.0 * self.rng.random((self.pop, self.dim)) - 1.0)
        self.pbest_x = self.x.copy()
        self.pbest_f = np.full(self.pop, np.inf)

    def _omega(self) -> float:
        w0, w1 = self.inertia
        if w0 == w1 or self.max_iter is None:
            return w0
        t = min(1.0, self.iteration / self.max_iter)
        return w0 + (w1 - w0) * t

    def ask(self) -> np.ndarray:
        """Particle positions to evaluate next, shape (pop, dim) (a copy)."""
        return self.x.copy()

    def tell(self, costs: Iterable[float]) -> None:
        """Give the costs of the last :meth:`ask`; moves the swarm one step."""
        f = _clean_costs(costs, self.pop)
        x = self.x
        better = f < self.pbest_f
        self.pbest_f[better] = f[better]
        self.pbest_x[better] = x[better]
        self._record(x, f)
        w = self._omega()
        r = self.rng.random((2, self.pop, self.dim))
        g = self.best_x if self.best_x is not None else self.pbest_x[0]
        v = w * self.v + self.c1 * r[0] * (self.pbest_x - x) + self.c2 * r[1] * (g - x)
        vmax = self.v_max * (self.hi - self.lo)
        np.clip(v, -vmax, vmax, out=v)
        xn = x + v
        out = (xn < self.lo) | (xn > self.hi)
        np.clip(xn, self.lo, self.hi, out=xn)
        v[out] = 0.0
        self.x = xn
        self.v = v

    def state_dict(self) -> dict[str, Any]:
        """JSON-serialisable snapshot; :meth:`from_state` continues identically."""
        s = self._common_state()
        s.update(
            inertia=list(self.inertia),
            c1=self.c1,
            c2=self.c2,
            v_max=self.v_max,
            max_iter=self.max_iter,
            x=self.x.tolist(),
            v=self.v.tolist(),
            pbest_x=self.pbest_x.tolist(),
            pbest_f=self.pbest_f.tolist(),
        )
        return s

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> PSO:
        """Rebuild an optimiser from :meth:`state_dict` output."""
        if state.get("kind") != cls.kind:
            raise ValueError(f"not a {cls.kind} state: kind={state.get('kind')!r}")
        w0, w1 = state["inertia"]
        obj = cls(
            state["lo"],
            state["hi"],
            pop=state["pop"],
            rng=0,
            inertia=(w0, w1),
            c1=state["c1"],
            c2=state["c2"],
            v_max=state["v_max"],
            max_iter=state["max_iter"] if state["max_iter"] is not None else 1,
        )
        obj.max_iter = state["max_iter"]
        obj._load_common(state)
        obj.x = np.array(state["x"], dtype=float)
        obj.v = np.array(state["v"], dtype=float)
        obj.pbest_x = np.array(state["pbest_x"], dtype=float)
        obj.pbest_f = np.array(state["pbest_f"], dtype=float)
        return obj


class CMAES(_PopulationOptimizer):
    """CMA-ES (ask/tell) over the box, delegating the update to ``cmaes.CMA``.

    Parameters
    ----------
    lo, hi, pop, rng : as :class:`BBBC`; ``pop`` is the CMA-ES population size λ. The
        library's own RandomState is seeded from ``rng``'s first draw.
    sigma : σ₀ as a fraction of (hi - lo) (the search runs in the unit cube).

    :attr:`population` holds the points the next :meth:`tell` ranks (member 0 may be replaced
    before evaluation, e.g. by the default gains: the update uses the points as told).
    """

    kind = "cmaes"

    def __init__(
        self,
        lo: Any,
        hi: Any,
        pop: int = 20,
        rng: np.random.Generator | int | None = None,
        sigma: float = 0.3,
    ) -> None:
        from cmaes import CMA

        if int(pop) < 4:
            raise ValueError("CMA-ES needs pop >= 4 (at least 2 parents for the rank-mu update)")
        super().__init__(lo, hi, pop, rng)
        if not 0.0 < float(sigma):
            raise ValueError("sigma must be > 0")
        self.sigma = float(sigma)
        bounds = np.tile([0.0, 1.0], (self.dim, 1))
        seed = int(self.rng.integers(2**31 - 1))
        self.cma = CMA(mean=np.full(self.dim, 0.5), sigma=self.sigma, bounds=bounds,
                       seed=seed, population_size=self.pop)
        self.population = self._sample()

    def _sample(self) -> np.ndarray:
        U = np.array([self.cma.ask() for _ in range(self.pop)])
        return self.lo + (self.hi - self.lo) * U

    def ask(self) -> np.ndarray:
        """The population to evaluate next, shape (pop, dim) (a copy)."""
        return self.population.copy()

    def tell(self, costs: Iterable[float]) -> None:
        """Give the costs of the last :meth:`ask`; one CMA-ES generation update."""
        X = self.population
        f = _clean_costs(costs, self.pop)
        self._record(X, f)
        fin = np.isfinite(f)
        top = float(np.max(f[fin])) if fin.any() else 0.0
        ranked = np.where(fin, f, top + abs(top) + 1.0)  # non-finite: worst, rank-preserving
        U = np.clip((X - self.lo) / (self.hi - self.lo), 0.0, 1.0)
        self.cma.tell([(U[i], float(ranked[i])) for i in range(self.pop)])
        self.population = self._sample()

    def state_dict(self) -> dict[str, Any]:
        """JSON-serialisable snapshot (the ``CMA`` object's attributes as a base64 pickle,
        its RandomState and full covariance included, which the library's own pickling drops
        or compresses); :meth:`from_state` continues identically."""
        import base64
        import pickle

        s = self._common_state()
        s.update(sigma=self.sigma, population=self.population.tolist(),
                 cma=base64.b64encode(pickle.dumps(dict(vars(self.cma)))).decode("ascii"))
        return s

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> CMAES:
        """Rebuild an optimiser from :meth:`state_dict` output."""
        import base64
        import pickle

        if state.get("kind") != cls.kind:
            raise ValueError(f"not a {cls.kind} state: kind={state.get('kind')!r}")
        obj = cls(state["lo"], state["hi"], pop=state["pop"], rng=0, sigma=state["sigma"])
        obj._load_common(state)
        obj.cma = type(obj.cma).__new__(type(obj.cma))
        obj.cma.__dict__.update(pickle.loads(base64.b64decode(state["cma"])))  # noqa: S301
        obj.population = np.array(state["population"], dtype=float)
        return obj


def _run(
    opt: BBBC | PSO | CMAES,
    fun: Objective,
    iters: int,
    map_fn: MapFn,
    callback: Callable[[Any], Any] | None,
) -> OptimResult:
    while opt.iteration < iters:
        X = opt.ask()
        costs = list(map_fn(fun, [row for row in X]))
        opt.tell(costs)
        if callback is not None and callback(opt):
            break
    return opt.result()


def bbbc_minimize(
    fun: Objective,
    lo: Any,
    hi: Any,
    pop: int = 20,
    iters: int = 20,
    rng: np.random.Generator | int | None = None,
    map_fn: MapFn = map,
    callback: Callable[[BBBC], Any] | None = None,
    state: dict[str, Any] | None = None,
    **settings: Any,
) -> OptimResult:
    """Minimise ``fun`` over the box [lo, hi] with BB-BC (see :class:`BBBC`).

    ``map_fn(fun, xs)`` evaluates a population (plug in an executor's ``map``).
    ``callback(opt)`` runs after every iteration (checkpoint with ``opt.state_dict()``);
    returning a truthy value stops early. ``state`` resumes from a checkpoint, in which case
    the other optimiser settings are taken from it and the run continues until ``iters``
    iterations have been done in total. ``settings``: :class:`BBBC`'s own (``spread``,
    ``centre``, ``elitism``; its defaults otherwise).
    """
    if state is not None:
        opt = BBBC.from_state(state)
    else:
        opt = BBBC(lo, hi, pop=pop, rng=rng, **settings)
    return _run(opt, fun, iters, map_fn, callback)


def pso_minimize(
    fun: Objective,
    lo: Any,
    hi: Any,
    pop: int = 20,
    iters: int = 20,
    rng: np.random.Generator | int | None = None,
    map_fn: MapFn = map,
    callback: Callable[[PSO], Any] | None = None,
    state: dict[str, Any] | None = None,
    **settings: Any,
) -> OptimResult:
    """Minimise ``fun`` over the box [lo, hi] with PSO (see :class:`PSO`).

    Same calling conventions as :func:`bbbc_minimize`; ``settings``: :class:`PSO`'s own
    (``inertia``, ``c1``, ``c2``, ``v_max``; its defaults otherwise). A tuple ``inertia``
    decreases linearly over ``iters`` iterations.
    """
    if state is not None:
        opt = PSO.from_state(state)
    else:
        linear = isinstance(settings.get("inertia"), tuple | list)
        opt = PSO(lo, hi, pop=pop, rng=rng, max_iter=iters if linear else None, **settings)
    return _run(opt, fun, iters, map_fn, callback)


def cmaes_minimize(
    fun: Objective,
    lo: Any,
    hi: Any,
    pop: int = 20,
    iters: int = 20,
    rng: np.random.Generator | int | None = None,
    sigma: float = 0.3,
    map_fn: MapFn = map,
    callback: Callable[[CMAES], Any] | None = None,
    state: dict[str, Any] | None = None,
) -> OptimResult:
    """Minimise ``fun`` over the box [lo, hi] with CMA-ES (see :class:`CMAES`).

    Same calling conventions as :func:`bbbc_minimize`.
    """
    opt = CMAES.from_state(state) if state is not None else CMAES(lo, hi, pop, rng, sigma)
    return _run(opt, fun, iters, map_fn, callback)
