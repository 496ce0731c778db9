"""Tests of the BB-BC, PSO and CMA-ES optimisers (controllers.optim)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from controllers.optim import BBBC, CMAES, PSO, bbbc_minimize, cmaes_minimize, pso_minimize


def sphere(x: np.ndarray) -> float:
    return float(np.sum(x * x))


def rosenbrock(x: np.ndarray) -> float:
    return float(100.0 * (x[1] - x[0] ** 2) ** 2 + (1.0 - x[0]) ** 2)


def quadratic(x: np.ndarray) -> float:
    # minimum at (-1.75, -3.25), f = -8.375 (negative costs exercise the mass-centre shift)
    return float(3 * x[0] ** 2 - 2 * x[0] * x[1] + x[1] ** 2 + 4 * x[0] + 3 * x[1])


MINIMISERS = {
    "bbbc-mass": lambda f, lo, hi, **kw: bbbc_minimize(f, lo, hi, centre="mass", **kw),
    "bbbc-best": lambda f, lo, hi, **kw: bbbc_minimize(f, lo, hi, centre="best", **kw),
    "pso": pso_minimize,
    "cmaes": cmaes_minimize,
}


@pytest.mark.parametrize("name", MINIMISERS)
def test_sphere_5d(name):
    res = MINIMISERS[name](sphere, [-5.0] * 5, [5.0] * 5, pop=30, iters=100, rng=1)
    assert res.fun < 1e-2
    assert np.max(np.abs(res.x)) < 0.1
    assert res.n_evals == 30 * 100
    assert res.iterations == 100
    assert len(res.history) == 100
    assert np.all(np.diff(res.history) <= 0.0)  # best-so-far never gets worse
    assert res.history[-1] == res.fun == sphere(res.x)


@pytest.mark.parametrize("name", MINIMISERS)
def test_rosenbrock_2d(name):
    res = MINIMISERS[name](rosenbrock, [-2.0, -1.0], [2.0, 3.0], pop=30, iters=100, rng=2)
    assert res.fun < 1e-3
    np.testing.assert_allclose(res.x, [1.0, 1.0], atol=0.06)


@pytest.mark.parametrize("name", MINIMISERS)
def test_quadratic_negative_minimum(name):
    res = MINIMISERS[name](quadratic, [-5.0, -5.0], [5.0, 5.0], pop=30, iters=100, rng=3)
    assert res.fun == pytest.approx(-8.375, abs=1e-3)
    np.testing.assert_allclose(res.x, [-1.75, -3.25], atol=0.02)


def test_map_fn_is_used_and_bounds_respected():
    calls = []

    def my_map(fun, xs):
        xs = list(xs)
        calls.append(len(xs))
        for x in xs:
            assert np.all(x >= -1.0) and np.all(x <= 2.0)
        return [fun(x) for x in xs]

    bbbc_minimize(sphere, [-1.0] * 3, [2.0] * 3, pop=7, iters=5, rng=0, map_fn=my_map)
    pso_minimize(sphere, [-1.0] * 3, [2.0] * 3, pop=7, iters=4, rng=0, map_fn=my_map)
    assert calls == [7] * 9


def test_elitism_keeps_best_in_population():
    opt = BBBC([-3.0] * 2, [3.0] * 2, pop=10, rng=4)
    for _ in range(5):
        X = opt.ask()
        opt.tell([sphere(x) for x in X])
        np.testing.assert_array_equal(opt.population[0], opt.best_x)


def test_nonfinite_costs_are_ignored():
    opt = BBBC([-1.0], [1.0], pop=6, rng=5)
    X = opt.ask()
    opt.tell([np.nan, np.inf, 0.5, 0.2, np.inf, 0.9])
    assert opt.best_f == 0.2
    np.testing.assert_array_equal(opt.best_x, X[3])
    assert np.all(np.isfinite(opt.population))
    opt2 = BBBC([-1.0], [1.0], pop=3, rng=5)
    opt2.tell([np.nan] * 3)  # nothing usable: centre falls back to the box middle
    np.testing.assert_array_equal(opt2.centre_x, [0.0])
    p = PSO([-1.0], [1.0], pop=3, rng=5)
    p.tell([np.inf, 1.0, np.nan])
    assert p.best_f == 1.0


def test_mass_centre_weights():
    opt = BBBC([-10.0], [10.0], pop=3, rng=0)
    opt.population = np.array([[1.0], [2.0], [4.0]])
    opt.tell([1.0, 2.0, 4.0])  # weights 1, 1/2, 1/4
    assert opt.centre_x[0] == pytest.approx((1 + 1 + 1) / (1 + 0.5 + 0.25))
    # non-positive costs: shifted by min and the median gap (here 1): f' = 1, 2, 3
    opt = BBBC([-10.0], [10.0], pop=3, rng=0)
    opt.population = np.array([[1.0], [2.0], [4.0]])
    opt.tell([-3.0, -2.0, -1.0])
    assert opt.centre_x[0] == pytest.approx((1 + 1 + 4 / 3) / (1 + 0.5 + 1 / 3))


def _run_with_checkpoint(cls, minimize, fun, split, total, **kw):
    saved = {}

    def cb(opt):
        if opt.iteration == split:
            saved["state"] = json.loads(json.dumps(opt.state_dict()))  # survive a JSON file
            return True
        return False

    minimize(fun, [-2.0, -1.0], [2.0, 3.0], iters=total, callback=cb, **kw)
    assert saved["state"]["iteration"] == split
    return minimize(fun, None, None, iters=total, state=saved["state"])


@pytest.mark.parametrize(
    "cls,minimize,kw",
    [
        (BBBC, bbbc_minimize, {"pop": 12, "spread": 0.4}),
        (BBBC, bbbc_minimize, {"pop": 9, "centre": "best", "elitism": False}),
        (PSO, pso_minimize, {"pop": 12}),
        (PSO, pso_minimize, {"pop": 8, "inertia": (0.9, 0.4), "v_max": 0.3}),
        (CMAES, cmaes_minimize, {"pop": 8}),
        (CMAES, cmaes_minimize, {"pop": 6, "sigma": 0.1}),
    ],
)
def test_resume_equals_uninterrupted(cls, minimize, kw):
    full = minimize(rosenbrock, [-2.0, -1.0], [2.0, 3.0], iters=15, rng=7, **kw)
    resumed = _run_with_checkpoint(cls, minimize, rosenbrock, 6, 15, rng=7, **kw)
    assert resumed.fun == full.fun
    np.testing.assert_array_equal(resumed.x, full.x)
    assert resumed.history == full.history
    assert resumed.n_evals == full.n_evals
    a, b = dict(resumed.state), dict(full.state)
    if "cma" in a:  # the pickle's bytes may differ (memo order); its contents may not
        ca, cb = (_cma_attrs(s.pop("cma")) for s in (a, b))
        assert ca.keys() == cb.keys()
        for k in ca:
            if isinstance(ca[k], np.ndarray):
                np.testing.assert_array_equal(ca[k], cb[k])
            elif isinstance(ca[k], int | float | tuple | str):
                assert ca[k] == cb[k], k
        assert str(ca["_rng"].get_state()) == str(cb["_rng"].get_state())
    assert a == b


def _cma_attrs(b64: str) -> dict:
    import base64
    import pickle

    return pickle.loads(base64.b64decode(b64))


def test_ask_tell_matches_minimize_and_seed_determinism():
    a = bbbc_minimize(quadratic, [-5, -5], [5, 5], pop=10, iters=8, rng=11)
    b = bbbc_minimize(quadratic, [-5, -5], [5, 5], pop=10, iters=8, rng=np.random.default_rng(11))
    opt = BBBC([-5, -5], [5, 5], pop=10, rng=11)
    for _ in range(8):
        opt.tell([quadratic(x) for x in opt.ask()])
    assert a.fun == b.fun == opt.best_f
    c = bbbc_minimize(quadratic, [-5, -5], [5, 5], pop=10, iters=8, rng=12)
    assert c.history != a.history


def test_from_state_rejects_wrong_kind():
    s = BBBC([0.0], [1.0], pop=3).state_dict()
    with pytest.raises(ValueError):
        PSO.from_state(s)


def test_invalid_arguments():
    with pytest.raises(ValueError):
        BBBC([0.0, 1.0], [1.0, 1.0])
    with pytest.raises(ValueError):
        BBBC([0.0], [1.0], centre="median")
    with pytest.raises(ValueError):
        PSO([0.0], [1.0], inertia=(0.9, 0.4))  # schedule without max_iter
    with pytest.raises(ValueError):
        BBBC([0.0], [1.0], pop=4).tell([1.0, 2.0])


def test_cmaes_bounds_and_few_dozen_iterations():
    lo, hi = np.array([-2.0, -1.0]), np.array([2.0, 3.0])
    opt = CMAES(lo, hi, pop=8, rng=3, sigma=0.5)  # wide σ: many samples fall outside the box
    for _ in range(40):
        X = opt.ask()
        assert X.shape == (8, 2)
        assert np.all(X >= lo) and np.all(X <= hi)
        opt.tell([rosenbrock(x) for x in X])
    assert opt.best_f < 1e-3
    np.testing.assert_allclose(opt.best_x, [1.0, 1.0], atol=0.06)
    q = cmaes_minimize(quadratic, [-5, -5], [5, 5], pop=8, iters=30, rng=4)
    assert q.fun == pytest.approx(-8.375, abs=1e-4)


def test_cmaes_seeds_nonfinite_and_injected_member():
    a = cmaes_minimize(sphere, [-1] * 3, [1] * 3, pop=6, iters=5, rng=1)
    b = cmaes_minimize(sphere, [-1] * 3, [1] * 3, pop=6, iters=5, rng=np.random.default_rng(1))
    c = cmaes_minimize(sphere, [-1] * 3, [1] * 3, pop=6, iters=5, rng=2)
    assert a.history == b.history != c.history
    opt = CMAES([-1.0], [1.0], pop=4, rng=5)
    opt.population[0] = [0.25]  # e.g. the default gains, as the tuner injects them
    opt.tell([0.1, np.nan, np.inf, 2.0])
    assert opt.best_f == 0.1 and opt.best_x[0] == 0.25
    assert np.all(np.isfinite(opt.ask()))
    with pytest.raises(ValueError):
        CMAES([0.0], [1.0], sigma=0.0)
    with pytest.raises(ValueError, match="pop >= 4"):
        CMAES([0.0], [1.0], pop=3)
    with pytest.raises(ValueError):
        CMAES.from_state(BBBC([0.0], [1.0], pop=3).state_dict())
