"""Tests of the IT2 / type-1 fuzzy PD cores (controllers.fuzzy) against the spec's facts."""

from __future__ import annotations

import numpy as np
import pytest
from oracles.controllers_ref import km_reduce

from controllers.fuzzy import (
    REDUCERS,
    IT2FuzzyPD,
    T1FuzzyPD,
    heights_from_alpha,
    small_signal_gain,
)


def make(reducer: str, **kw) -> IT2FuzzyPD | T1FuzzyPD:
    if reducer == "t1":
        return T1FuzzyPD(cm=kw.get("cm", 0.7))
    return IT2FuzzyPD(reducer=reducer, **kw)


def random_points(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1.0, 1.0, size=(n, 2))
    # include points exactly on set boundaries and corners
    extra = np.array([[0, 0], [1, 1], [-1, -1], [1, -1], [0, 0.5], [-0.3, 0], [1, 0], [0, -1]])
    return np.vstack([pts, extra])


@pytest.mark.parametrize("reducer", ["t1", *REDUCERS])
def test_origin_is_zero(reducer):
    assert make(reducer)(0.0, 0.0) == 0.0


@pytest.mark.parametrize("reducer", ["t1", "km", "nt", "bmm"])
@pytest.mark.parametrize("alpha", [0.25, 0.6, 0.9])
def test_corners_are_plus_minus_one(reducer, alpha):
    f = make(reducer, alpha=alpha) if reducer != "t1" else make("t1")
    assert f(1.0, 1.0) == pytest.approx(1.0, abs=1e-15)
    assert f(-1.0, -1.0) == pytest.approx(-1.0, abs=1e-15)
    # inputs outside [-1, 1] are clipped
    assert f(3.0, 1.5) == f(1.0, 1.0)
    assert f(-7.0, -1.2) == f(-1.0, -1.0)


@pytest.mark.parametrize("zeta", [0.0, 0.3, 0.5, 1.0])
def test_zeta_corner_value(zeta):
    h = 0.75  # h_P with alpha = 0.25
    f = IT2FuzzyPD(alpha=0.25, reducer="zeta", zeta=zeta)
    expected = (zeta * h * h + 1.0 - zeta) / (h * h + 1.0)
    assert f(1.0, 1.0) == pytest.approx(expected, abs=1e-15)
    if zeta == 0.5:
        assert f(1.0, 1.0) == pytest.approx(0.5, abs=1e-15)


@pytest.mark.parametrize("reducer", ["t1", *REDUCERS])
@pytest.mark.parametrize("alpha,cm", [(0.25, 0.7), (0.4, 0.5), (0.8, 0.9)])
def test_odd_and_input_symmetry(reducer, alpha, cm):
    f = make(reducer, alpha=alpha, cm=cm) if reducer != "t1" else T1FuzzyPD(cm=cm)
    for e, d in random_points(200):
        v = f(e, d)
        assert f(-e, -d) == pytest.approx(-v, abs=1e-14)
        assert f(d, e) == pytest.approx(v, abs=1e-14)
        assert f(e, -e) == pytest.approx(0.0, abs=1e-14)
        assert abs(v) <= 1.0 + 1e-15


@pytest.mark.parametrize("alpha,cm", [(0.25, 0.7), (0.1, 0.5), (0.5, 0.8), (0.9, 0.3)])
def test_km_is_monotone(alpha, cm):
    f = IT2FuzzyPD(alpha=alpha, cm=cm, reducer="km")
    g = np.linspace(-1.0, 1.0, 161)
    Z = f.phi_grid(g[:, None], g[None, :])
    assert np.all(np.diff(Z, axis=0) >= -1e-12)
    assert np.all(np.diff(Z, axis=1) >= -1e-12)
    # scalar path too, along lines through the origin region
    for d in (-0.7, -0.01, 0.0, 0.02, 0.5):
        vals = [f(e, d) for e in g]
        assert np.all(np.diff(vals) >= -1e-12)


@pytest.mark.parametrize("reducer", ["t1", "km", "nt", "bmm"])
def test_unit_heights_and_half_cm_give_linear_core(reducer):
    f = make(reducer, heights=(1.0, 1.0, 1.0), cm=0.5) if reducer != "t1" else T1FuzzyPD(0.5)
    for e, d in random_points(300, seed=3):
        assert f(e, d) == pytest.approx(0.5 * (e + d), abs=1e-14)


@pytest.mark.parametrize("zeta", [0.2, 0.5, 0.9])
def test_unit_heights_zeta_is_half_nt(zeta):
    # With f = f̄ the spec's zeta formula gives Σ f y / (2 Σ f): NT / 2 = (E + dE)/4.
    f = IT2FuzzyPD(heights=(1.0, 1.0, 1.0), cm=0.5, reducer="zeta", zeta=zeta)
    for e, d in random_points(100, seed=4):
        assert f(e, d) == pytest.approx(0.25 * (e + d), abs=1e-14)


def test_zeta_half_is_nt_over_two():
    nt = IT2FuzzyPD(alpha=0.3, cm=0.6, reducer="nt")
    z = IT2FuzzyPD(alpha=0.3, cm=0.6, reducer="zeta", zeta=0.5)
    for e, d in random_points(200, seed=5):
        assert z(e, d) == pytest.approx(0.5 * nt(e, d), abs=1e-15)


def fd_slope(f, eps: float = 1e-8) -> tuple[float, float]:
    return (
        (f(eps, 0.0) - f(-eps, 0.0)) / (2 * eps),
        (f(0.0, eps) - f(0.0, -eps)) / (2 * eps),
    )


@pytest.mark.parametrize(
    "reducer,expected", [("km", 5.666), ("nt", 0.782), ("bmm", 1.400), ("zeta", 0.391)]
)
def test_table_i_small_signal_slopes(reducer, expected):
    f = IT2FuzzyPD(alpha=0.25, cm=0.7, reducer=reducer, zeta=0.5)
    g_e, g_de = fd_slope(f)
    assert g_e == pytest.approx(expected, abs=6e-4)
    assert g_de == pytest.approx(expected, abs=6e-4)
    assert f.small_signal_gain() == pytest.approx(g_e, rel=1e-5)


def test_type1_slope_is_cm():
    for cm in (0.3, 0.7, 1.0):
        g_e, g_de = fd_slope(T1FuzzyPD(cm))
        assert g_e == pytest.approx(cm, rel=1e-6)
        assert g_de == pytest.approx(cm, rel=1e-6)
    assert small_signal_gain("t1", cm=0.4) == 0.4


@pytest.mark.parametrize("reducer", REDUCERS)
def test_closed_form_slopes_random_heights(reducer):
    rng = np.random.default_rng(11)
    for _ in range(10):
        hz, hp = rng.uniform(0.15, 1.0, 2)
        cm, zeta = rng.uniform(0.1, 1.0), rng.uniform(0.0, 1.0)
        f = IT2FuzzyPD(heights=(hp, hz, hp), cm=cm, reducer=reducer, zeta=zeta)
        g = small_signal_gain(reducer, cm, hz, hp, zeta)
        g_e, g_de = fd_slope(f)
        assert g_e == pytest.approx(g, rel=2e-5)
        assert g_de == pytest.approx(g, rel=2e-5)
        assert f.small_signal_gains() == pytest.approx((g, g), rel=2e-5)


@pytest.mark.parametrize("reducer", REDUCERS)
def test_phi_grid_matches_scalar(reducer):
    f = IT2FuzzyPD(heights=((0.6, 0.3, 0.8), (0.9, 0.5, 0.4)), cm=0.65, reducer=reducer)
    E = np.linspace(-1.3, 1.3, 27)
    D = np.linspace(-1.1, 1.1, 23)
    Z = f.phi_grid(E[:, None], D[None, :])
    S = np.array([[f(e, d) for d in D] for e in E])
    assert np.array_equal(Z, S)  # the same core, compiled


def test_t1_phi_grid_matches_scalar():
    f = T1FuzzyPD(0.8)
    E = np.linspace(-1.2, 1.2, 25)
    Z = f.phi_grid(E[:, None], E[None, :])
    S = np.array([[f(e, d) for d in E] for e in E])
    assert np.array_equal(Z, S)


@pytest.mark.parametrize("heights", [None, (0.5, 0.2, 0.9), ((0.7, 0.35, 0.6), (0.95, 0.5, 0.3))])
def test_fast_km_equals_generic_enumeration(heights):
    f = IT2FuzzyPD(alpha=0.25, cm=0.75, reducer="km", heights=heights)
    pts = random_points(300, seed=7)
    y, fl, fu = f.firing(pts[:, 0], pts[:, 1])
    for k, (e, d) in enumerate(pts):
        yl, yr = km_reduce(y, fl[:, k], fu[:, k])
        assert f(e, d) == pytest.approx(0.5 * (yl + yr), abs=1e-14)


def test_km_reduce_simple_case():
    # two rules at y = 0 and 1 with firing [0.5, 1] each: y_l = 0.5/1.5, y_r = 1/1.5
    yl, yr = km_reduce([1.0, 0.0], [0.5, 0.5], [1.0, 1.0])
    assert yl == pytest.approx(1 / 3)
    assert yr == pytest.approx(2 / 3)


def _pyit2fls_system(h_e, h_d, cm, algorithm):
    p = pytest.importorskip("pyit2fls")
    dom = np.linspace(-1.0, 1.0, 101)
    tri = [(-1.8, -1.0, 0.0), (-1.0, 0.0, 1.0), (0.0, 1.0, 1.8)]
    sets_e = [
        p.IT2FS(dom, p.tri_mf, [*t, 1.0], p.tri_mf, [*t, h]) for t, h in zip(tri, h_e, strict=True)
    ]
    sets_d = [
        p.IT2FS(dom, p.tri_mf, [*t, 1.0], p.tri_mf, [*t, h]) for t, h in zip(tri, h_d, strict=True)
    ]
    sys = p.IT2TSK(p.product_t_norm, p.max_s_norm)
    sys.add_input_variable("E")
    sys.add_input_variable("dE")
    sys.add_output_variable("U")
    y = (-1.0, -cm, 0.0, cm, 1.0)
    for i in range(3):
        for j in range(3):
            sys.add_rule(
                [("E", sets_e[i]), ("dE", sets_d[j])],
                [("U", {"const": y[i + j], "E": 0.0, "dE": 0.0})],
            )
    sys.algorithm = getattr(p, algorithm)  # never EKM_algorithm: wrong in pyit2fls 0.9.0
    return sys


@pytest.mark.parametrize(
    "h_e,h_d,cm,algorithm",
    [
        (heights_from_alpha(0.25), heights_from_alpha(0.25), 0.7, "KM_algorithm"),
        (heights_from_alpha(0.25), heights_from_alpha(0.25), 0.7, "EIASC_algorithm"),
        ((0.5, 0.3, 0.9), (0.5, 0.3, 0.9), 0.5, "KM_algorithm"),
        ((0.7, 0.35, 0.6), (0.95, 0.5, 0.3), 0.8, "KM_algorithm"),
    ],
)
def test_km_matches_pyit2fls(h_e, h_d, cm, algorithm):
    sys = _pyit2fls_system(h_e, h_d, cm, algorithm)
    f = IT2FuzzyPD(heights=(h_e, h_d), cm=cm, reducer="km")
    g = np.linspace(-1.0, 1.0, 17)
    worst = 0.0
    for e in g:
        for d in g:
            ref = sys.evaluate({"E": float(e), "dE": float(d)})["U"]
            worst = max(worst, abs(ref - f(float(e), float(d))))
    assert worst < 1e-9


def test_invalid_parameters():
    with pytest.raises(ValueError):
        IT2FuzzyPD(reducer="ekm")
    with pytest.raises(ValueError):
        IT2FuzzyPD(alpha=0.0)  # h_Z = 0
    with pytest.raises(ValueError):
        IT2FuzzyPD(heights=(0.5, 1.2, 0.5))
    with pytest.raises(ValueError):
        IT2FuzzyPD(cm=1.5)
    with pytest.raises(ValueError):
        IT2FuzzyPD(zeta=-0.1)


def test_scalar_returns_python_float():
    assert type(IT2FuzzyPD()(0.3, -0.2)) is float
    assert type(T1FuzzyPD()(0.3, -0.2)) is float


def test_consequent_table():
    tab = IT2FuzzyPD(cm=0.6).consequents()
    assert tab.tolist() == [[-1.0, -0.6, 0.0], [-0.6, 0.0, 0.6], [0.0, 0.6, 1.0]]
