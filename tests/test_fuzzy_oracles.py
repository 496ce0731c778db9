"""Oracles for the fast fuzzy PD cores: scikit-fuzzy (type-1 core, IT2 firing strengths) and
pyit2fls (Nie–Tan and BMM type reducers; KM/EIASC are in test_fuzzy.py); KM by the
hand-written enumeration of tests/oracles/controllers_ref.py."""

from __future__ import annotations

import numpy as np
import pytest
from oracles.controllers_ref import km_reduce

from controllers.fuzzy import IT2FuzzyPD, T1FuzzyPD, heights_from_alpha
from controllers.fuzzy_sets import (
    SkfuzzyT1FPD,
    firing_strengths,
    lower_memberships,
    upper_memberships,
)

GRID = np.linspace(-1.0, 1.0, 81)


def _grid() -> tuple[np.ndarray, np.ndarray]:
    return np.meshgrid(GRID, GRID, indexing="ij")


def test_skfuzzy_sets_are_the_spec_triangles():
    x = np.array([-1.5, -1.0, -0.5, 0.0, 0.25, 1.0, 2.0])
    up = upper_memberships(x)
    xc = np.clip(x, -1, 1)
    np.testing.assert_allclose(up["N"], np.maximum(0, -xc), atol=1e-15)
    np.testing.assert_allclose(up["Z"], 1 - np.abs(xc), atol=1e-15)
    np.testing.assert_allclose(up["P"], np.maximum(0, xc), atol=1e-15)
    lo = lower_memberships(x, alpha=0.3)
    np.testing.assert_allclose(lo["Z"], 0.3 * up["Z"], atol=1e-15)
    np.testing.assert_allclose(lo["P"], 0.7 * up["P"], atol=1e-15)
    assert lo["N"][1] == pytest.approx(0.7)


@pytest.mark.parametrize("cm", [0.2, 0.5, 0.7, 1.0])
def test_t1_core_matches_skfuzzy_oracle_on_grid(cm):
    E, D = _grid()
    ref = SkfuzzyT1FPD(cm)(E, D)
    core = T1FuzzyPD(cm=cm)
    fast = np.array([[core(float(e), float(d)) for e, d in zip(re, rd, strict=True)]
                     for re, rd in zip(E, D, strict=True)])
    assert np.max(np.abs(fast - ref)) < 1e-9
    assert np.max(np.abs(core.phi_grid(E, D) - ref)) < 1e-9
    # the oracle is not trivially linear: with c_m != 0.5 it bends
    if cm != 0.5:
        assert np.max(np.abs(ref - (E + D) / 2)) > 0.01


@pytest.mark.parametrize("alpha,cm", [(0.25, 0.7), (0.5, 0.7), (0.83, 0.4)])
def test_it2_firing_strengths_match_skfuzzy(alpha, cm):
    E, D = _grid()
    y_ref, fl_ref, fu_ref = firing_strengths(E, D, alpha=alpha, cm=cm)
    y, fl, fu = IT2FuzzyPD(alpha=alpha, cm=cm).firing(E, D)
    np.testing.assert_array_equal(y, y_ref)
    assert np.max(np.abs(fu - fu_ref)) < 1e-9
    assert np.max(np.abs(fl - fl_ref)) < 1e-9


@pytest.mark.parametrize("alpha,cm", [(0.25, 0.7), (0.62, 0.55)])
@pytest.mark.parametrize("reducer", ["km", "nt", "bmm", "zeta"])
def test_scalar_it2_core_from_skfuzzy_firings(alpha, cm, reducer):
    """The scalar (per-tick) core equals its reducer applied to skfuzzy's firing strengths."""
    g = np.linspace(-1.0, 1.0, 21)
    E, D = np.meshgrid(g, g, indexing="ij")
    y, fl, fu = firing_strengths(E, D, alpha=alpha, cm=cm)
    core = IT2FuzzyPD(alpha=alpha, cm=cm, reducer=reducer, zeta=0.3)
    worst = 0.0
    for a in range(E.shape[0]):
        for b in range(E.shape[1]):
            lo, up = fl[:, a, b], fu[:, a, b]
            if reducer == "km":
                yl, yr = km_reduce(y, lo, up)
                ref = 0.5 * (yl + yr)
            elif reducer == "nt":
                ref = float(np.sum((lo + up) * y) / np.sum(lo + up))
            elif reducer == "bmm":
                ref = float(0.5 * np.sum(lo * y) / np.sum(lo) + 0.5 * np.sum(up * y) / np.sum(up))
            else:
                ref = float((0.3 * np.sum(lo * y) + 0.7 * np.sum(up * y)) / np.sum(lo + up))
            worst = max(worst, abs(core(float(E[a, b]), float(D[a, b])) - ref))
    assert worst < 1e-9


def _pyit2fls_tsk(heights, cm, reducer):
    p = pytest.importorskip("pyit2fls")
    dom = np.linspace(-1.0, 1.0, 101)
    tri = [(-1.8, -1.0, 0.0), (-1.0, 0.0, 1.0), (0.0, 1.0, 1.8)]
    sets = [p.IT2FS(dom, p.tri_mf, [*t, 1.0], p.tri_mf, [*t, h])
            for t, h in zip(tri, heights, strict=True)]
    tsk = p.IT2TSK(p.product_t_norm, p.max_s_norm)
    tsk.add_input_variable("E")
    tsk.add_input_variable("dE")
    tsk.add_output_variable("U")
    y = (-1.0, -cm, 0.0, cm, 1.0)
    for i in range(3):
        for j in range(3):
            tsk.add_rule([("E", sets[i]), ("dE", sets[j])],
                         [("U", {"const": y[i + j], "E": 0.0, "dE": 0.0})])
    if reducer == "nt":
        def alg(iv):
            v = p.NT_algorithm(iv)
            return (v, v)  # IT2TSK.evaluate takes the mid-point of an interval
    else:
        def alg(iv):
            v = p.BMM_algorithm(iv, [0.5, 0.5])
            return (v, v)
    tsk.algorithm = alg
    return tsk


@pytest.mark.parametrize("reducer", ["nt", "bmm"])
@pytest.mark.parametrize("alpha,cm", [(0.25, 0.7), (0.5, 0.7), (0.8, 0.45)])
def test_nt_bmm_match_pyit2fls(reducer, alpha, cm):
    tsk = _pyit2fls_tsk(heights_from_alpha(alpha), cm, reducer)
    core = IT2FuzzyPD(alpha=alpha, cm=cm, reducer=reducer)
    g = np.linspace(-1.0, 1.0, 17)
    worst = 0.0
    for e in g:
        for d in g:
            ref = tsk.evaluate({"E": float(e), "dE": float(d)})["U"]
            worst = max(worst, abs(ref - core(float(e), float(d))))
    assert worst < 1e-9
