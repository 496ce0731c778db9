"""Tests of the fuzzy PIDs and the PID (controllers.fpid, controllers.pid, factory)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controllers import (
    FPID,
    IT2FPID,
    PAPER_TABLE_I,
    PID,
    IT2FuzzyPD,
    equivalent_pid,
    make_controller,
    small_signal_gain,
)

DT = 0.01
GAINS = {"Ke": 0.8, "Kd": 0.3, "K0": 2.0, "K1": 1.5}


def all_controllers(**kw):
    return [
        IT2FPID(**GAINS, **kw),
        IT2FPID(**GAINS, reducer="nt", **kw),
        FPID(**GAINS, **kw),
        PID(1.2, 0.8, 0.3, **kw),
    ]


def test_it2fpid_law_by_hand():
    c = IT2FPID(**GAINS, alpha=0.3, cm=0.6)
    core = IT2FuzzyPD(alpha=0.3, cm=0.6)
    errors = [0.5, 0.7, 3.0, -0.4, 0.0, 0.1]
    prev, integ = None, 0.0
    for e in errors:
        ed = 0.0 if prev is None else (e - prev) / DT
        prev = e
        E = max(-1.0, min(1.0, GAINS["Ke"] * e))
        dE = max(-1.0, min(1.0, GAINS["Kd"] * ed))
        U = core(E, dE)
        integ += DT * U
        u = GAINS["K0"] * U + GAINS["K1"] * integ
        assert c.update(e, DT) == pytest.approx(u, abs=1e-15)
        assert (c.E, c.dE, c.U, c.integral, c.u) == pytest.approx((E, dE, U, integ, u))
        assert c.u_pd + c.u_pi == pytest.approx(c.u)


def test_pid_law_by_hand():
    c = PID(2.0, 0.5, 0.1)
    errors = [1.0, 0.5, -0.25]
    prev, integ = None, 0.0
    for e in errors:
        ed = 0.0 if prev is None else (e - prev) / DT
        prev = e
        integ += DT * e
        u = 2.0 * e + 0.5 * integ + 0.1 * ed
        assert c.update(e, DT) == pytest.approx(u, abs=1e-15)
        assert (c.p, c.i, c.d) == pytest.approx((2.0 * e, 0.5 * integ, 0.1 * ed))


@pytest.mark.parametrize("idx", range(4))
def test_first_call_has_no_derivative(idx):
    c = all_controllers()[idx]
    c.update(5.0, DT, measurement=-5.0)
    assert c.de == 0.0
    c.update(5.5, DT)
    assert c.de == pytest.approx(0.5 / DT)


@pytest.mark.parametrize("idx", range(4))
def test_derivative_sign_and_measurement_mode(idx):
    ce = all_controllers()[idx]
    cm = all_controllers(derivative="measurement")[idx]
    r = 1.0
    ys = [0.0, 0.1, 0.25, 0.3, 0.2]
    for y in ys:
        ue = ce.update(r - y, DT)
        um = cm.update(r - y, DT, measurement=y)
        # constant setpoint: -dy/dt == de/dt, identical outputs
        assert um == pytest.approx(ue, rel=1e-12, abs=1e-12)
    # measurement rising => error falling => negative derivative
    assert ce.de == pytest.approx((0.2 - 0.3) * -1.0 / DT)
    cm.update(r - 0.5, DT, measurement=0.5)
    assert cm.de < 0.0


@pytest.mark.parametrize("idx", range(4))
def test_setpoint_step_no_kick_with_measurement_derivative(idx):
    cm = all_controllers(derivative="measurement")[idx]
    ce = all_controllers()[idx]
    y = 0.2
    for _ in range(3):
        cm.update(0.0 - y, DT, measurement=y)
        ce.update(0.0 - y, DT)
    cm.update(1.0 - y, DT, measurement=y)  # setpoint jumps 0 -> 1, y unchanged
    ce.update(1.0 - y, DT)
    assert cm.de == 0.0
    assert ce.de == pytest.approx(1.0 / DT)


def test_measurement_mode_requires_measurement():
    with pytest.raises(ValueError):
        IT2FPID(**GAINS, derivative="measurement").update(1.0, DT)
    with pytest.raises(ValueError):
        PID(1.0, derivative="measurement").update(1.0, DT)
    with pytest.raises(ValueError):
        PID(1.0, derivative="velocity")


@pytest.mark.parametrize("dt", [0.0, -0.01, math.nan])
def test_bad_dt(dt):
    with pytest.raises(ValueError):
        IT2FPID(**GAINS).update(1.0, dt)


@pytest.mark.parametrize("idx", range(4))
def test_reset_restores_fresh_behaviour(idx):
    rng = np.random.default_rng(2)
    errs = rng.normal(size=30)
    fresh = all_controllers(d_tau=0.02)[idx]
    used = all_controllers(d_tau=0.02)[idx]
    for e in rng.normal(size=17):
        used.update(float(e), DT)
    used.reset()
    assert used.integral == 0.0
    for e in errs:
        assert used.update(float(e), DT) == fresh.update(float(e), DT)


def test_reset_with_integral_preload():
    c = IT2FPID(**GAINS)
    c.reset(integral=0.4)
    assert c.update(0.0, DT) == pytest.approx(GAINS["K1"] * 0.4)


@pytest.mark.parametrize("idx", range(4))
def test_integral_clamp(idx):
    c = all_controllers(i_limit=0.3)[idx]
    ki = c.K1 if not isinstance(c, PID) else c.Ki
    for _ in range(2000):
        c.update(2.0, DT)
        assert abs(ki * c.integral) <= 0.3 + 1e-12
    assert abs(ki * c.integral) == pytest.approx(0.3)
    for _ in range(2000):
        c.update(-2.0, DT)
    assert ki * c.integral == pytest.approx(-0.3)


@pytest.mark.parametrize("idx", range(4))
def test_output_clamp_with_conditional_integration(idx):
    lim = 1.0
    # derivative on a constant measurement: no derivative term, only P and I act
    c = all_controllers(u_limit=lim, derivative="measurement")[idx]
    free = all_controllers(derivative="measurement")[idx]
    for _ in range(1500):  # long saturation
        u = c.update(3.0, DT, measurement=0.0)
        free.update(3.0, DT, measurement=0.0)
        assert -lim <= u <= lim
    assert u == lim
    # the integral stopped growing once saturated: far below the unconstrained one
    assert abs(c.integral) < 0.5 * abs(free.integral)

    # after the error reverses, the clamped controller leaves saturation much sooner
    def steps_to_negative(ctrl):
        for k in range(1, 5000):
            if ctrl.update(-0.5, DT, measurement=0.0) < 0.0:
                return k
        return 5000

    assert steps_to_negative(c) < 0.5 * steps_to_negative(free)


def test_asymmetric_output_limits():
    c = PID(10.0, u_limit=(-0.5, 2.0))
    assert c.update(1.0, DT) == 2.0
    assert c.update(-1.0, DT) == -0.5
    with pytest.raises(ValueError):
        PID(1.0, u_limit=(1.0, -1.0))


@pytest.mark.parametrize("reducer", ["km", "nt", "bmm", "zeta"])
def test_fuzzy_pid_is_odd_in_gains(reducer):
    pos = IT2FPID(**GAINS, reducer=reducer)
    neg = IT2FPID(**{k: -v for k, v in GAINS.items()}, reducer=reducer)
    for e in np.random.default_rng(3).normal(size=50):
        assert neg.update(float(e), DT) == pytest.approx(pos.update(float(e), DT), abs=1e-14)


def test_derivative_filter_smooths():
    raw = PID(0.0, 0.0, 1.0)
    filt = PID(0.0, 0.0, 1.0, d_tau=0.05)
    raw.update(0.0, DT)
    filt.update(0.0, DT)
    assert raw.update(1.0, DT) == pytest.approx(1.0 / DT)
    assert 0.0 < filt.update(1.0, DT) < 0.5 / DT
    for _ in range(300):  # constant slope: the filtered derivative converges to it
        e = raw.e + 0.01
        raw.update(e, DT)
        filt.update(e, DT)
    assert filt.de == pytest.approx(1.0, rel=1e-6)


def test_equivalent_pid_formula():
    kp, ki, kd = equivalent_pid(2.0, 3.0, 5.0, 7.0, 0.5)
    assert (kp, ki, kd) == pytest.approx((0.5 * (10 + 21), 0.5 * 14, 0.5 * 15))
    kp, ki, kd = equivalent_pid(2.0, 3.0, 5.0, 7.0, (0.5, 2.0))
    assert (kp, ki, kd) == pytest.approx((10 * 0.5 + 21 * 2.0, 14 * 0.5, 15 * 2.0))


def _ramp_response(ctrl, slope, n):
    return np.array([ctrl.update(slope * k, DT) for k in range(n)])


@pytest.mark.parametrize("reducer", ["km", "nt", "bmm", "zeta", "t1"])
def test_equivalent_pid_matches_linearisation(reducer):
    gains = {"Ke": 1e-4, "Kd": 2e-6, "K0": 3.0, "K1": 40.0}
    if reducer == "t1":
        fz = FPID(**gains, cm=0.6)
        g = 0.6
    else:
        fz = IT2FPID(**gains, alpha=0.3, cm=0.6, reducer=reducer)
        g = small_signal_gain(reducer, 0.6, 0.3, 0.7, 0.5)
    kp, ki, kd = fz.equivalent_pid()
    assert (kp, ki, kd) == pytest.approx(equivalent_pid(**gains, G=g), rel=1e-12)
    # error ramp from 0: E and dE stay tiny and of the same sign
    slope = 1e-5
    u_fz = _ramp_response(fz, slope, 200)
    u_lin = _ramp_response(PID(kp, ki, kd), slope, 200)
    assert 0.0 < fz.E < 1e-6 and 0.0 < fz.dE < 1e-6
    np.testing.assert_allclose(u_fz[1:], u_lin[1:], rtol=1e-5)


@pytest.mark.parametrize("reducer", ["nt", "bmm", "zeta"])
def test_equivalent_pid_any_small_signal_for_smooth_reducers(reducer):
    gains = {"Ke": 1e-7, "Kd": 1e-9, "K0": 3.0, "K1": 40.0}
    fz = IT2FPID(**gains, reducer=reducer)
    lin = PID(*fz.equivalent_pid())
    errs = np.concatenate([[0.0], np.random.default_rng(5).normal(size=100)])
    u_fz = [fz.update(float(e), DT) for e in errs]
    u_lin = [lin.update(float(e), DT) for e in errs]
    np.testing.assert_allclose(u_fz, u_lin, rtol=0, atol=2e-5 * np.max(np.abs(u_lin)))


def test_equivalent_pid_unequal_heights_uses_numeric_slopes():
    fz = IT2FPID(**GAINS, heights=((0.7, 0.35, 0.7), (0.9, 0.5, 0.9)))
    g_e, g_de = fz.core.small_signal_gains()
    assert g_e != pytest.approx(g_de)
    assert fz.equivalent_pid() == pytest.approx(equivalent_pid(**GAINS, G=(g_e, g_de)))


def test_make_controller():
    assert isinstance(make_controller("it2-fpid", **GAINS), IT2FPID)
    assert isinstance(make_controller("t1-fpid", **GAINS, cm=0.5), FPID)
    assert isinstance(make_controller("pid", Kp=1.0, Ki=0.1), PID)
    c = make_controller("it2-fpid", **PAPER_TABLE_I, reducer="zeta")
    assert c.core.reducer == "zeta" and c.core.alpha == 0.25
    with pytest.raises(ValueError, match="it2-fpid.*t1-fpid.*pid"):
        make_controller("lqr")


def test_update_returns_python_float():
    for c in all_controllers():
        assert type(c.update(0.3, DT)) is float
