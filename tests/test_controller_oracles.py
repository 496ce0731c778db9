"""The product's controller laws against the hand-written oracles (tests/oracles/controllers_ref.py)
(axis law of every kind with its limits, the X mixer, the whole position cascade), over random
inputs that saturate and wind up."""

from __future__ import annotations

import math

import numpy as np
import pytest
from oracles.controllers_ref import RefAxis, RefCascade, ref_mix, ref_phi

from controllers import FPID, IT2FPID, PID, REDUCERS
from controllers.attitude import GeometricAttitudeController, XMixer
from controllers.cascade import PositionCascade
from numkit.geometry import quat_to_rot9

TOL = 1e-12
ROTORS = [(0.2, -0.2), (-0.2, 0.2), (0.2, 0.2), (-0.2, -0.2)]
SPIN = [1, 1, -1, -1]
K_YAW = 0.016
KINDS = ["pid", "t1", *REDUCERS]


def close(a: float, b: float) -> bool:
    return abs(a - b) <= TOL * (1.0 + abs(b))


def axis_pair(kind: str, rng: np.random.Generator, windup: bool = False):
    """(product controller, oracle) with the same random parameters and limits (``windup``:
    a small integral clamp and no output clamp)."""
    pick = rng.integers
    lim = [None, float(rng.uniform(0.5, 5.0)), (float(-rng.uniform(0.5, 4)),
                                                float(rng.uniform(0.5, 4)))][pick(3)]
    common = dict(derivative=["error", "measurement"][pick(2)],
                  i_limit=[None, float(rng.uniform(0.1, 2.0))][pick(2)], u_limit=lim,
                  d_tau=[0.0, float(rng.uniform(0.01, 0.2))][pick(2)])
    if windup:
        common.update(i_limit=float(rng.uniform(0.02, 0.3)), u_limit=None)
    if kind == "pid":
        g = rng.uniform(0.1, 4.0, 3)
        return PID(*g, **common), RefAxis("pid", g, **common)
    g = (*rng.uniform(0.05, 1.5, 2), *rng.uniform(0.5, 8.0, 2))
    cm = float(rng.uniform(0.0, 1.0))
    if kind == "t1":
        return FPID(*g, cm=cm, **common), RefAxis("t1", g, cm=cm, **common)
    h_e, h_de = tuple(rng.uniform(0.05, 1.0, 3)), tuple(rng.uniform(0.05, 1.0, 3))
    zeta = float(rng.uniform(0.0, 1.0))
    c = IT2FPID(*g, cm=cm, reducer=kind, zeta=zeta, heights=(h_e, h_de), **common)
    return c, RefAxis(kind, g, cm=cm, h_e=h_e, h_de=h_de, zeta=zeta, **common)


@pytest.mark.parametrize("kind", KINDS)
def test_axis_law_matches_oracle(kind):
    """Every kind, random gains / limits / derivative modes, errors from tiny to saturating; the
    rate given on some ticks only (both derivative paths); outputs and internals equal."""
    rng = np.random.default_rng(100 + KINDS.index(kind))
    hits = {"u_clamped": 0, "i_clamped": 0}
    for j in range(12):
        c, ref = axis_pair(kind, rng, windup=j % 2 == 0)
        dt = float(rng.choice([0.005, 0.01, 0.05]))
        for k in range(150):
            e = float(rng.normal() * rng.choice([0.01, 1.0, 20.0]))
            y = float(rng.normal())
            rate = float(rng.normal() * 5.0) if rng.random() < 0.3 else None
            u = c.update(e, dt, y, rate)
            u_ref = ref.update(e, dt, y, rate)
            assert close(u, u_ref), (kind, k, u, u_ref)
            assert close(c.integral, ref.integral)
            if kind != "pid":
                assert (c.E, c.dE) == (ref.E, ref.dE)
                assert close(c.U, ref.U)
            assert ref.umin <= u <= ref.umax
            hits["u_clamped"] += u in (ref.umin, ref.umax)
            lim = c.i_limit
            K = c.Ki if kind == "pid" else c.K1
            hits["i_clamped"] += lim is not None and close(abs(K * c.integral), lim)
        c.reset()
        ref.reset()
    assert hits["u_clamped"] > 50 and hits["i_clamped"] > 50, hits


def test_output_stays_inside_the_limits_when_dropping_the_step_overshoots():
    """A step of the integral larger than the whole output range: dropping it (conditional
    integration) leaves u on the other side of the range; u is still clamped."""
    c = PID(1.0, 100.0, 0.0, u_limit=1.0)
    ref = RefAxis("pid", (1.0, 100.0, 0.0), u_limit=1.0)
    c.reset(integral=-0.05)
    ref.reset(integral=-0.05)
    for e in (3.0, -3.0, 0.5):
        assert c.update(e, 0.1) == ref.update(e, 0.1)
        assert -1.0 <= c.u <= 1.0
        assert c.integral == ref.integral


@pytest.mark.parametrize("reducer", ["t1", *REDUCERS])
def test_core_matches_nine_rule_oracle(reducer):
    rng = np.random.default_rng(3)
    for _ in range(300):
        E, dE = rng.uniform(-1.3, 1.3, 2)
        cm = float(rng.uniform(0.0, 1.0))
        if reducer == "t1":
            c = FPID(1.0, 1.0, 1.0, 0.0, cm=cm)
            ref = ref_phi(E, dE, cm)
        else:
            h_e, h_de = tuple(rng.uniform(0.05, 1.0, 3)), tuple(rng.uniform(0.05, 1.0, 3))
            zeta = float(rng.uniform(0, 1))
            c = IT2FPID(1.0, 1.0, 1.0, 0.0, cm=cm, reducer=reducer, zeta=zeta,
                        heights=(h_e, h_de))
            ref = ref_phi(E, dE, cm, reducer, h_e, h_de, zeta)
        c.update(float(E), 1.0, error_rate=float(dE))
        assert abs(c.U - ref) <= TOL, (reducer, E, dE, c.U, ref)


def test_mixer_matches_oracle_in_every_branch():
    rng = np.random.default_rng(4)
    mix = XMixer(ROTORS, SPIN, K_YAW, 12.0)
    A = np.array([[1.0] * 4, [p[1] for p in ROTORS], [-p[0] for p in ROTORS],
                  [s * K_YAW for s in SPIN]])
    Ainv = np.linalg.inv(A)
    branches = {"free": 0, "yaw": 0, "shift": 0, "clip": 0}
    for _ in range(4000):
        T = float(rng.uniform(-5.0, 60.0))
        tau = rng.normal(size=3) * rng.choice([0.1, 1.0, 5.0]) * np.array([1.0, 1.0, 0.2])
        f = mix.mix(T, *tau)
        f_ref, sat = ref_mix(Ainv, 12.0, T, tau)
        assert mix.saturated == sat
        assert all(close(a, b) for a, b in zip(f, f_ref, strict=True)), (T, tau, f, f_ref)
        g = Ainv @ [T, tau[0], tau[1], 0.0]
        key = ("free" if not sat else "yaw" if g.min() >= 0 and g.max() <= 12.0
               else "shift" if g.max() - g.min() <= 12.0 else "clip")
        branches[key] += 1
    assert min(branches.values()) > 100, branches


def cascade_pair(kinds, rng: np.random.Generator):
    """(PositionCascade, RefCascade) with the same random parameters."""
    pairs = [axis_pair(k, rng) for k in kinds]
    J = rng.uniform(0.01, 0.3, 3)
    wn, zeta = rng.uniform(3.0, 12.0, 3), rng.uniform(0.5, 1.2, 3)
    f_max, mass = float(rng.uniform(8.0, 25.0)), float(rng.uniform(1.0, 4.0))
    tilt, ff, a_lim = math.radians(rng.uniform(15, 45)), float(rng.random() < 0.7), \
        float(rng.uniform(2.0, 8.0))
    att = GeometricAttitudeController(J, wn=wn, zeta=zeta)
    c = PositionCascade([p for p, _ in pairs], mass, 9.81, att,
                        XMixer(ROTORS, SPIN, K_YAW, f_max), tilt_max=tilt,
                        accel_feedforward=bool(ff), a_limit=a_lim)
    A = np.array([[1.0] * 4, [p[1] for p in ROTORS], [-p[0] for p in ROTORS],
                  [s * K_YAW for s in SPIN]])
    ref = RefCascade([r for _, r in pairs], mass, 9.81, J, J * wn**2, 2.0 * J * zeta * wn,
                     np.linalg.inv(A), f_max, tilt, ff, a_lim)
    return c, ref


def test_cascade_matches_oracle():
    rng = np.random.default_rng(5)
    combos = [("pid",) * 3, ("t1",) * 3, *[(r,) * 3 for r in REDUCERS], ("km", "pid", "t1"),
              ("nt", "bmm", "zeta")]
    sat = tilted = 0
    for kinds in combos:
        c, ref = cascade_pair(kinds, rng)
        for _ in range(200):
            q = rng.normal(size=4)
            q[0] += 3.0
            q /= np.linalg.norm(q)
            R = quat_to_rot9(*q)
            s = float(rng.choice([0.1, 1.0, 10.0]))
            p, v, pr, vr = (rng.normal(size=3) * s for _ in range(4))
            w, ar = rng.normal(size=3) * 2.0, rng.normal(size=3) * 2.0
            yaw, dt = float(rng.uniform(-4, 4)), 0.01
            f = c.update(p, v, R, w, pr, vr, ar, yaw, dt)
            f_ref = ref.update(p, v, R, w, pr, vr, ar, yaw, dt)
            assert all(close(a, b) for a, b in zip(f, f_ref, strict=True)), (kinds, f, f_ref)
            assert c.mixer.saturated == ref.saturated and close(c.tilt, ref.tilt)
            sat += ref.saturated
            tilted += c.tilt > 0.999 * c.tilt_max
    assert sat > 200 and tilted > 100, (sat, tilted)
