"""BatchCascade (controllers.batched) against N scalar PositionCascade objects: both call the same
row function (controllers.cascade.vehicle_step), so every row equals its scalar cascade bit for
bit."""

from __future__ import annotations

import copy
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controllers import FPID, IT2FPID, PID, REDUCERS
from controllers.attitude import GeometricAttitudeController, XMixer
from controllers.axis import AX_NS, S
from controllers.batched import NP, NS, P_MASS, BatchCascade
from controllers.cascade import PositionCascade
from numkit.geometry import quat_to_rot9

ROTORS = [(0.2, -0.2), (-0.2, 0.2), (0.2, 0.2), (-0.2, -0.2)]
SPIN = [1, 1, -1, -1]


def _pick(rng: np.random.Generator, options: list):
    return options[int(rng.integers(len(options)))]


def _axis(kind: str, rng: np.random.Generator, **kw):
    common = dict(
        derivative=kw.pop("derivative", _pick(rng, ["error", "measurement"])),
        i_limit=kw.pop("i_limit", _pick(rng, [None, float(rng.uniform(0.2, 3.0))])),
        u_limit=kw.pop("u_limit", _pick(rng, [None, float(rng.uniform(1.0, 5.0)),
                                              (float(-rng.uniform(1, 4)),
                                               float(rng.uniform(1, 4)))])),
        d_tau=kw.pop("d_tau", _pick(rng, [0.0, 0.05])),
    )
    if kind == "pid":
        return PID(rng.uniform(0.5, 4.0), rng.uniform(0.0, 1.0), rng.uniform(0.5, 3.0), **common)
    gains = (rng.uniform(0.1, 1.0), rng.uniform(0.1, 1.0), rng.uniform(1.0, 8.0),
             rng.uniform(0.0, 2.0))
    if kind == "t1":
        return FPID(*gains, cm=rng.uniform(0.3, 1.0), **common)
    reducer = kw.pop("reducer", _pick(rng, list(REDUCERS)))
    heights = kw.pop("heights", None)
    if heights is None and rng.random() < 0.5:
        heights = (tuple(rng.uniform(0.1, 1.0, 3)), tuple(rng.uniform(0.1, 1.0, 3)))
    return IT2FPID(*gains, alpha=rng.uniform(0.1, 0.6), cm=rng.uniform(0.3, 1.0),
                   reducer=reducer, zeta=rng.uniform(0.0, 1.0), heights=heights, **common)


def make_cascades(kinds, seed: int, **kw) -> list[PositionCascade]:
    """One cascade per entry of ``kinds`` (a kind name or a 3-tuple per axis), random gains."""
    rng = np.random.default_rng(seed)
    out = []
    for kind in kinds:
        ks = (kind,) * 3 if isinstance(kind, str) else kind
        axes = [_axis(k, rng, **dict(kw)) for k in ks]
        att = GeometricAttitudeController(rng.uniform(0.01, 0.05, 3), wn=(9.0, 9.0, 3.0),
                                          zeta=(0.9, 0.9, 0.9))
        mix = XMixer(ROTORS, SPIN, 0.016, f_max=float(rng.uniform(8.0, 20.0)))
        out.append(PositionCascade(axes, float(rng.uniform(1.0, 3.0)), 9.81, att, mix,
                                   tilt_max=math.radians(rng.uniform(15.0, 40.0)),
                                   accel_feedforward=bool(rng.random() < 0.8),
                                   a_limit=float(rng.uniform(3.0, 8.0))))
    return out


def inputs(n: int, ticks: int, seed: int, scale: float = 1.0):
    """Random tick inputs; ``scale`` large → saturating errors."""
    rng = np.random.default_rng(seed)
    for _ in range(ticks):
        q = rng.normal(size=(n, 4))
        q[:, 0] += 3.0
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        R = np.array([quat_to_rot9(*row) for row in q])
        big = scale * rng.choice([0.1, 1.0, 10.0], size=(n, 1))
        yield (rng.normal(size=(n, 3)) * big, rng.normal(size=(n, 3)) * big, R,
               rng.normal(size=(n, 3)) * 2.0, rng.normal(size=(n, 3)) * big,
               rng.normal(size=(n, 3)) * big, rng.normal(size=(n, 3)) * 2.0,
               rng.uniform(-4.0, 4.0, n))


def close(a, b) -> bool:
    """Bit for bit (NaN never occurs here)."""
    return a == b


def check(cascades, ticks=300, seed=1, scale=1.0, dt=0.01, bc=None):
    bc = BatchCascade.from_cascades(cascades) if bc is None else bc
    n = len(cascades)
    sat = 0
    for p, v, R, w, pr, vr, ar, yaw in inputs(n, ticks, seed, scale):
        f = bc.update((p, v, R, w), (pr, vr, ar, yaw), dt)
        for i, c in enumerate(cascades):
            fs = c.update(p[i], v[i], tuple(R[i]), w[i], pr[i], vr[i], ar[i], yaw[i], dt)
            assert all(close(x, y) for x, y in zip(f[i], fs, strict=True)), (i, f[i], fs)
            si, bi = c.internals(), bc.internals(i)
            assert list(si) == list(bi)
            assert all(close(bi[k], si[k]) for k in si), (i, si, bi)
            sat += si["mixer_saturated"]
    return bc, sat


@pytest.mark.parametrize("kind", ["pid", "t1"])
def test_types_match_scalar(kind):
    check(make_cascades([kind] * 5, seed=3), scale=1.0)


@pytest.mark.parametrize("reducer", REDUCERS)
def test_it2_reducers_match_scalar(reducer):
    check(make_cascades(["it2"] * 5, seed=4, reducer=reducer))


@pytest.mark.parametrize("derivative", ["error", "measurement"])
@pytest.mark.parametrize("d_tau", [0.0, 0.1])
def test_derivative_modes_and_filter(derivative, d_tau):
    cs = make_cascades(["pid", "t1", "it2"], seed=5, derivative=derivative, d_tau=d_tau)
    check(cs, ticks=100)


def test_limits_and_saturation():
    """Large errors: i_limit / u_limit clamps, tilt limit, mixer saturation all exercised."""
    cs = make_cascades(["pid", "t1", "it2", ("pid", "it2", "t1")] * 2, seed=6, i_limit=0.5,
                       u_limit=(-2.0, 3.0))
    _, sat = check(cs, ticks=300, scale=10.0)
    assert sat > 50
    assert any(c.tilt > 0.99 * c.tilt_max for c in cs)


def test_mixed_batch_and_initial_state():
    cs = make_cascades(["pid", "t1", "it2", ("it2", "pid", "t1")] * 3, seed=7)
    # advance the scalar cascades first: from_cascades must copy their state
    for p, v, R, w, pr, vr, ar, yaw in inputs(len(cs), 20, seed=11):
        for i, c in enumerate(cs):
            c.update(p[i], v[i], tuple(R[i]), w[i], pr[i], vr[i], ar[i], yaw[i], 0.01)
    bc = BatchCascade.from_cascades(cs)
    for i, c in enumerate(cs):
        assert bc.internals(i) == c.internals()
    check(cs, bc=bc, ticks=200, scale=3.0)
    bc.reset()
    for c in cs:
        c.reset()
    check(cs, bc=bc, ticks=50, seed=12)


def _run_rows(bc: BatchCascade, rows, data, dt=0.01):
    out = []
    for p, v, R, w, pr, vr, ar, yaw in data:
        sel = [a[rows] for a in (p, v, R, w, pr, vr, ar, yaw)]
        out.append(bc.update(sel[:4], sel[4:], dt).copy())
    return np.array(out)


def test_row_independence():
    """Vehicle 3's thrusts are bit-identical alone, in a batch of 7 and in a batch of 64."""
    cs = make_cascades(["pid", "t1", "it2", ("it2", "t1", "pid")] * 16, seed=8)
    data = list(inputs(64, 200, seed=13, scale=3.0))
    full = BatchCascade.from_cascades(cs)
    alone = BatchCascade.from_cascades([cs[3]])
    seven = BatchCascade.from_cascades(cs[:7])
    f64 = _run_rows(full, np.arange(64), data)
    f1 = _run_rows(alone, np.array([3]), data)
    f7 = _run_rows(seven, np.arange(7), data)
    assert np.array_equal(f1[:, 0], f64[:, 3])
    assert np.array_equal(f7[:, 3], f64[:, 3])
    assert np.array_equal(alone.state[0], full.state[3])


def test_active_mask():
    cs = make_cascades(["it2", "pid", "t1", "it2"], seed=9)
    bc = BatchCascade.from_cascades(cs)
    ref = BatchCascade.from_cascades(cs)
    data = list(inputs(4, 60, seed=14))
    mask = np.array([True, False, True, False])
    for k, (p, v, R, w, pr, vr, ar, yaw) in enumerate(data):
        active = mask if 20 <= k < 40 else None
        before = bc.state.copy()
        f = bc.update((p, v, R, w), (pr, vr, ar, yaw), 0.01, active=active).copy()
        if active is not None:
            assert np.array_equal(bc.state[~mask], before[~mask])
            assert np.all(f[~mask] == 0.0)
            rows = np.flatnonzero(mask)
            fr = ref.update((p, v, R, w), (pr, vr, ar, yaw), 0.01)  # reference for active rows
            assert np.array_equal(f[rows], fr[rows])
            ref.state[~mask] = bc.state[~mask]
        else:
            fr = ref.update((p, v, R, w), (pr, vr, ar, yaw), 0.01)
            assert np.array_equal(f, fr)


def test_mass_change_and_views():
    cs = make_cascades(["it2", "pid", "t1"], seed=10)
    bc = BatchCascade.from_cascades(cs)
    assert bc.n == 3 and bc.params.shape == (3, NP) and bc.state.shape == (3, NS)
    assert np.allclose(bc.mass, [c.mass for c in cs])
    for k, (p, v, R, w, pr, vr, ar, yaw) in enumerate(inputs(3, 100, seed=15)):
        if k % 10 == 5:
            m = 0.97 * cs[1].mass
            cs[1].mass = m
            bc.mass[1] = m
        f = bc.update((p, v, R, w), (pr, vr, ar, yaw), 0.01)
        for i, c in enumerate(cs):
            fs = c.update(p[i], v[i], tuple(R[i]), w[i], pr[i], vr[i], ar[i], yaw[i], 0.01)
            assert all(close(x, y) for x, y in zip(f[i], fs, strict=True))
    assert np.array_equal(bc.thrust, [c.thrust for c in cs])
    assert np.array_equal(bc.a_cmd, [c.a_cmd for c in cs])
    assert np.array_equal(bc.torque, [c.torque for c in cs])
    bc.mass = 2.0
    assert np.all(bc.params[:, P_MASS] == 2.0)


_NO_JIT = """
import json, sys
sys.path[:0] = [sys.argv[1]]
from test_batched_controllers import inputs, make_cascades
cs = make_cascades(["pid", "t1", "it2", ("it2", "pid", "t1")], seed=16)
out = []
for p, v, R, w, pr, vr, ar, yaw in inputs(len(cs), 15, seed=1, scale=5.0):
    out.append([c.update(p[i], v[i], tuple(R[i]), w[i], pr[i], vr[i], ar[i], yaw[i], 0.01)
                for i, c in enumerate(cs)])
print(json.dumps([[[float(x) for x in f] for f in row] for row in out]))
"""


def test_without_numba_the_same_functions_run_as_python():
    """NUMBA_DISABLE_JIT=1 (what runs where numba is missing): the same row functions as
    Python give the compiled results to rounding (libm vs Python's math)."""
    tests = Path(__file__).resolve().parent
    env = dict(os.environ, NUMBA_DISABLE_JIT="1",
               PYTHONPATH=os.pathsep.join([str(tests.parent), os.environ.get("PYTHONPATH", "")]))
    res = subprocess.run([sys.executable, "-c", _NO_JIT, str(tests)], env=env, check=True,
                         capture_output=True, text=True, timeout=300)
    py = json.loads(res.stdout)
    cs = make_cascades(["pid", "t1", "it2", ("it2", "pid", "t1")], seed=16)
    for k, (p, v, R, w, pr, vr, ar, yaw) in enumerate(inputs(len(cs), 15, seed=1, scale=5.0)):
        for i, c in enumerate(cs):
            f = c.update(p[i], v[i], tuple(R[i]), w[i], pr[i], vr[i], ar[i], yaw[i], 0.01)
            np.testing.assert_allclose(py[k][i], f, rtol=1e-12, atol=1e-12)


def test_refusals():
    cs = make_cascades(["pid"], seed=17)

    class Sub(PID):
        pass

    bad = PositionCascade([Sub(1.0), PID(1.0), PID(1.0)], 1.0, 9.81, cs[0].attitude,
                          cs[0].mixer)
    with pytest.raises(ValueError, match="PID, FPID and IT2FPID"):
        BatchCascade.from_cascades([bad])
    with pytest.raises(ValueError, match="at least one"):
        BatchCascade.from_cascades([])
    bc = BatchCascade.from_cascades(cs)
    p, v, R, w, pr, vr, ar, yaw = next(inputs(1, 1, seed=0))
    with pytest.raises(ValueError, match="dt"):
        bc.update((p, v, R, w), (pr, vr, ar, yaw), 0.0)
    with pytest.raises(ValueError, match="batch size"):
        bc.update((p, v, R, w), (pr, vr, ar, np.zeros(2)), 0.01)


def test_sub_objects_share_the_cascade_row():
    """The cascade adopts its axis controllers, attitude controller and mixer: writes through
    them (a draining tank's J) reach the row, a deep copy is adopted again, and a cascade of
    other classes (here subclasses, run through their own update / mix) gives the same bits."""
    class SubPID(PID):
        pass

    class SubMixer(XMixer):
        pass

    cs = make_cascades(["pid"] * 2, seed=18)
    a = cs[0]
    b = PositionCascade([SubPID(x.Kp, x.Ki, x.Kd, derivative=x.derivative, i_limit=x.i_limit,
                                u_limit=x.u_limit, d_tau=x.d_tau) for x in a.axes], a.mass, a.g,
                        GeometricAttitudeController(a.attitude.J), SubMixer(ROTORS, SPIN, 0.016,
                                                                            a.mixer.f_max),
                        tilt_max=a.tilt_max, accel_feedforward=a.ff == 1.0, a_limit=a.a_limit)
    b.attitude._p[:] = a.attitude._p  # same gains
    a.attitude.J = b.attitude.J = (0.03, 0.04, 0.05)
    c = copy.deepcopy(a)
    for p, v, R, w, pr, vr, ar, yaw in inputs(1, 100, seed=19, scale=3.0):
        args = (p[0], v[0], tuple(R[0]), w[0], pr[0], vr[0], ar[0], yaw[0], 0.01)
        fa, fb, fc = a.update(*args), b.update(*args), c.update(*args)
        assert fa == fb == fc
        assert a.internals() == b.internals() == c.internals()
    assert a.axes[2].integral == a.state[2 * AX_NS + S.I]
    assert c.axes[2].integral == c.state[2 * AX_NS + S.I]
    assert BatchCascade.from_cascades([a]).J[0].tolist() == [0.03, 0.04, 0.05]
    with pytest.raises(ValueError, match="PID, FPID and IT2FPID"):
        BatchCascade.from_cascades([b])
