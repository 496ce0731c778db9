"""estimators.batched: the batch rows equal the scalar filters bit for bit (both call the row
functions where each law lives), row independence, options."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import estimators
from estimators.batched import (
    BatchBank,
    BatchKF,
    BatchMCKF,
    BatchPCAKF,
    BatchPCAMCKF,
    batch_class,
)

DT = 0.01
R_MODES = [np.diag([0.02, 0.02, 0.0025]), np.diag([0.5, 0.5, 0.0025]),
           np.array([[2.0, 0.3, 0.0], [0.3, 1.5, 0.0], [0.0, 0.0, 0.0025]])]
TOL = dict(rtol=1e-9, atol=1e-9)


def _make(name: str, i: int, model: str = "cvb", mode: str = "hankel", recovery="kf",
          window: int = 10, sigma: float = 2.0):
    """A scalar filter as ag_uav.navigation.estimation.make_filter builds it (options vary with
    i)."""
    params = {"model": model, "dim": 3, "dt": DT, "q": 0.05, "r": list(np.diag(R_MODES[i % 3]))}
    if model == "cvb":
        params["q_bias"] = 1e-4
    if "mckf" in name:
        params.update(sigma=sigma + 0.25 * (i % 2), max_iter=10 if i % 3 else 3,
                      recovery=recovery)
    if name.startswith("pca"):
        params.update(window=window, mode=mode)
    return estimators.make(name, **params)


def _scenario(N: int, ticks: int, seed: int) -> dict[str, np.ndarray]:
    """Per-vehicle IMU inputs, fixes (with spikes, a 15-25 m step lasting ~40 fixes on some
    vehicles, outage gaps), fix masks, R-mode switches and the tick of the first fix."""
    rng = np.random.default_rng(seed)
    acc = np.cumsum(0.3 * rng.standard_normal((ticks, N, 3)), axis=0) * 0.05
    vel = np.cumsum(acc * DT, axis=0) + rng.standard_normal((1, N, 3))
    pos = np.cumsum(vel * DT, axis=0) + 50.0 * rng.standard_normal((1, N, 3))
    u = acc + 0.05 * rng.standard_normal((ticks, N, 3)) + 0.02
    z = pos + 0.3 * rng.standard_normal((ticks, N, 3))
    z += (rng.random((ticks, N, 3)) < 0.06) * rng.choice([-1.0, 1.0], (ticks, N, 3)) * 20.0
    fix = rng.random((ticks, N)) < 0.45
    for i in range(N):
        g0 = rng.integers(20, ticks - 60)
        fix[g0 : g0 + rng.integers(10, 50), i] = False  # outage
        if i % 2 == 0:  # a sustained step: the MCKFs lock out and their recovery rules run
            s0 = rng.integers(30, ticks - 120)
            z[s0 : s0 + 90, i, :2] += rng.uniform(15.0, 25.0)
    rmode = np.minimum(np.cumsum(rng.random((ticks, N)) < 0.02, axis=0), 2)
    first = rng.integers(0, 15, N)
    return {"u": u, "z": z, "fix": fix, "rmode": rmode, "first": first}


def _run_scalar(filters, sc, ticks: int, snap_every: int = 0):
    """The scalar reference loop (FilterBank._step_bank + EstimatorFeedback._init/R switch)."""
    N = len(filters)
    pos = filters[0].model.pos_idx
    vel = filters[0].model.vel_idx
    hh = 0.5 * DT * DT
    snaps = []
    init = [False] * N
    for t in range(ticks):
        for i, f in enumerate(filters):
            if not init[i]:
                if t == sc["first"][i]:
                    x0 = np.zeros(f.n)
                    x0[pos] = sc["z"][t, i]
                    P0 = 4.0 * np.eye(f.n)
                    P0[pos, pos] = np.diag(R_MODES[0])
                    f.x, f.P = x0, P0
                    init[i] = True
                continue
            f.predict()
            a = sc["u"][t, i]
            for k in range(3):
                f.x[pos[k]] += hh * a[k]
                f.x[vel[k]] += DT * a[k]
            if sc["fix"][t, i]:
                if t and sc["rmode"][t, i] != sc["rmode"][t - 1, i]:
                    f.R = R_MODES[sc["rmode"][t, i]]
                f.update(sc["z"][t, i])
        if snap_every and t % snap_every == snap_every - 1:
            snaps.append((np.stack([f.x for f in filters]), np.stack([f.P for f in filters]),
                          np.array([f.nis for f in filters])))
    return snaps


def _run_batch(bf, sc, ticks: int, snap_every: int = 0, rows=None):
    """The same loop, batched; ``rows`` picks the scenario's vehicles for the batch rows."""
    rows = np.arange(bf.N) if rows is None else np.asarray(rows)
    u, z, fix, rmode, first = (sc["u"][:, rows], sc["z"][:, rows], sc["fix"][:, rows],
                               sc["rmode"][:, rows], sc["first"][rows])
    P0 = 4.0 * np.eye(bf.n)
    P0[bf.pos_idx, bf.pos_idx] = np.diag(R_MODES[0])
    snaps = []
    init = np.zeros(bf.N, dtype=bool)
    for t in range(ticks):
        bf.predict(u[t], active=init)
        new = first == t
        if new.any():
            x0 = np.zeros((bf.N, bf.n))
            x0[:, bf.pos_idx] = z[t]
            bf.initialise(new, x0, P0)
            init |= new
        mask = fix[t] & init & ~new
        if t:
            sw = mask & (rmode[t] != rmode[t - 1])
            for i in np.flatnonzero(sw):
                bf.R[i] = R_MODES[rmode[t, i]]
        bf.update(z[t], mask)
        if snap_every and t % snap_every == snap_every - 1:
            snaps.append((bf.x.copy(), bf.P.copy(), bf.nis.copy()))
    return snaps


CASES = [
    ("kf", {}),
    ("mckf", {"recovery": "kf"}),
    ("mckf", {"recovery": "inflate"}),
    ("mckf", {"recovery": None}),
    ("pca-kf", {"mode": "hankel"}),
    ("pca-kf", {"mode": "channels"}),
    ("pca-mckf", {"mode": "hankel", "recovery": "inflate"}),
    ("pca-mckf", {"mode": "channels", "recovery": "kf", "window": 20}),
    ("mckf", {"model": "cv", "recovery": "kf"}),
    ("pca-kf", {"model": "cv", "window": 12}),
]


@pytest.mark.parametrize("name,opts", CASES, ids=[f"{n}-{o}" for n, o in CASES])
def test_equivalence_with_scalar(name, opts):
    N, ticks = 6, 400
    sc = _scenario(N, ticks, seed=sum(map(ord, name)) + 7 * len(opts))
    scal = [_make(name, i, **opts) for i in range(N)]
    bf = batch_class(scal[0]).from_filters([_make(name, i, **opts) for i in range(N)])
    ref = _run_scalar(scal, sc, ticks, snap_every=25)
    got = _run_batch(bf, sc, ticks, snap_every=25)
    # the batch rows and the scalar objects call the same row functions: bit for bit
    for (xr, Pr, nr), (xb, Pb, nb) in zip(ref, got, strict=True):
        np.testing.assert_array_equal(xb, xr)
        np.testing.assert_array_equal(Pb, Pr)
        np.testing.assert_array_equal(nb, nr)
    if "mckf" in name:
        np.testing.assert_array_equal(bf.n_rejected, [f.n_rejected for f in scal])
        np.testing.assert_array_equal(bf.n_iter, [f.n_iter for f in scal])
    if name.startswith("pca"):
        np.testing.assert_array_equal(bf.z_filtered, np.stack([f.z_filtered for f in scal]))
        np.testing.assert_array_equal(bf.ring_state[:, 1], [f.pca.count for f in scal])


def test_scenario_exercises_mckf_branches():
    """The scenario makes the MCKF iterate, reject, recover (both rules) and lock out."""
    N, ticks = 6, 400
    sc = _scenario(N, ticks, seed=3)
    seen = {}
    for rec in ("kf", "inflate", None):
        fs = [_make("mckf", i, recovery=rec) for i in range(N)]
        bf = BatchMCKF.from_filters([_make("mckf", i, recovery=rec) for i in range(N)])
        iters, rej, recov = set(), 0, 0
        init = np.zeros(N, dtype=bool)
        for t in range(ticks):
            # the batched loop, recording the per-update diagnostics
            bf.predict(sc["u"][t], active=init)
            new = sc["first"] == t
            if new.any():
                x0 = np.zeros((N, 9))
                x0[:, bf.pos_idx] = sc["z"][t]
                bf.initialise(new, x0, np.eye(9))
                init |= new
            ok = bf.update(sc["z"][t], sc["fix"][t] & init & ~new)
            iters.update(bf.n_iter[ok].tolist())
            rej += int(bf.rejected[ok].sum())
            recov += int(bf.recovered[ok].sum())
        seen[rec] = (iters, rej, recov)
        assert max(iters) >= 3 and rej > 20
        del fs
    assert seen["kf"][2] > 0 and seen["inflate"][2] > 0 and seen[None][2] == 0


def test_row_independence_bit_identical():
    """Vehicle i's results do not depend on N or on the other rows' data (bit for bit)."""
    ticks = 300
    sc = _scenario(64, ticks, seed=11)
    names = ("kf", "mckf", "pca-kf", "pca-mckf")

    def bank(rows):
        return BatchBank.from_filters([{k: _make(k, int(i)) for k in names} for i in rows])

    def run(rows):
        b = bank(rows)
        out = {}
        for k in names:
            _run_batch(b[k], sc, ticks, rows=rows)
            out[k] = (b[k].x.copy(), b[k].P.copy(), b[k].nis.copy())
        return out

    full = run(np.arange(64))
    for i in (0, 5, 37, 63):
        alone = run(np.array([i]))
        seven = run(np.array([(i + 3) % 64, (i + 17) % 64, (i + 9) % 64, i, (i + 1) % 64,
                              (i + 40) % 64, (i + 2) % 64]))
        for k in names:
            for a, b7, b64 in zip(alone[k], seven[k], full[k], strict=True):
                assert np.array_equal(a[0], b7[3], equal_nan=True), (k, i)
                assert np.array_equal(a[0], b64[i], equal_nan=True), (k, i)


def test_update_mask_nonfinite_and_roundtrip():
    N = 3
    fs = [_make("pca-mckf", i) for i in range(N)]
    bf = BatchPCAMCKF.from_filters(fs)
    rng = np.random.default_rng(0)
    for _ in range(15):
        bf.predict(rng.standard_normal((N, 3)))
        bf.update(rng.standard_normal((N, 3)))
    x, P, nis, pcs = bf.x.copy(), bf.P.copy(), bf.nis.copy(), bf.ring_state.copy()
    z = rng.standard_normal((N, 3))
    z[1, 0] = np.nan
    ok = bf.update(z, np.array([False, True, False]))
    assert not ok.any()  # row 1: NaN fix (no fix, not pushed), others masked out
    np.testing.assert_array_equal(bf.x, x)
    np.testing.assert_array_equal(bf.P, P)
    np.testing.assert_array_equal(bf.nis, nis)
    np.testing.assert_array_equal(bf.ring_state, pcs)
    ok = bf.update(z, np.array([True, True, False]))
    assert ok.tolist() == [True, False, False]
    # to_filter: the scalar filter continues exactly where the batch row is
    f = bf.to_filter(2, _make("pca-mckf", 2))
    for _ in range(20):
        u, zz = rng.standard_normal((N, 3)), rng.standard_normal((N, 3)) * 3
        bf.predict(u)
        f.predict()
        f.x[bf.pos_idx] += 0.5 * DT * DT * u[2]
        f.x[bf.vel_idx] += DT * u[2]
        bf.update(zz)
        f.update(zz[2])
    np.testing.assert_allclose(bf.x[2], f.x, **TOL)
    np.testing.assert_allclose(bf.P[2], f.P, **TOL)
    assert bf.n_rejected[2] == f.n_rejected and bf.ring_state[2, 1] == f.pca.count


def test_bank_views_set_R_and_initialise():
    names = ("kf", "mckf", "pca-kf", "pca-mckf")
    bank = BatchBank.from_filters([{k: _make(k, i) for k in names} for i in range(4)])
    assert isinstance(bank["kf"], BatchKF) and isinstance(bank["pca-kf"], BatchPCAKF)
    x0 = np.zeros(9)
    x0[[0, 3, 6]] = [1.0, 2.0, 3.0]
    bank.initialise(np.array([0, 2]), x0, np.eye(9))
    np.testing.assert_array_equal(bank.positions("mckf")[[0, 2]], [[1.0, 2.0, 3.0]] * 2)
    np.testing.assert_array_equal(bank.positions("mckf")[1], [0.0, 0.0, 0.0])
    assert bank.velocities("kf").shape == (4, 3)
    bank.set_R(R_MODES[2], rows=[1])
    np.testing.assert_array_equal(bank["pca-mckf"].R[1], R_MODES[2])
    with pytest.raises(np.linalg.LinAlgError):
        bank.set_R(-np.eye(3))
    bank.predict(np.ones((4, 3)), active=np.array([True, False, True, True]))
    ok = bank.update(np.ones((4, 3)), np.array([True, True, False, False]))
    assert ok["kf"].tolist() == [True, True, False, False]


def test_refused_options():
    with pytest.raises(ValueError, match="KF instances"):
        BatchKF.from_filters([_make("pca-kf", 0)])
    with pytest.raises(ValueError, match="Q differs"):
        f1 = _make("kf", 0)
        f2 = estimators.make("kf", model="cvb", dim=3, dt=DT, q=0.07, q_bias=1e-4)
        BatchKF.from_filters([f1, f2])
    with pytest.raises(ValueError, match="adaptive_sigma"):
        BatchMCKF.from_filters([estimators.make("mckf", model="cvb", dim=3, dt=DT,
                                                adaptive_sigma=True)])
    with pytest.raises(ValueError, match="motion model"):
        BatchKF.from_filters([estimators.KF(np.eye(2), np.eye(1, 2), np.eye(2), np.eye(1))])
    with pytest.raises(ValueError, match="motion model"):
        BatchKF.from_filters([estimators.make("kf", model="ca", dim=3, dt=DT)])
    with pytest.raises(ValueError, match="window"):
        BatchPCAKF.from_filters([_make("pca-kf", 0), _make("pca-kf", 1, window=12)])
    with pytest.raises(ValueError, match="no batched version"):
        batch_class(estimators.make("kf-bias", model="cv", dim=2))


def test_runs_without_numba():
    """estimators.batched imports and runs (as plain Python) on numpy/scipy alone."""
    code = (
        "import sys; sys.modules['numba'] = None\n"
        "import numpy as np, estimators\n"
        "from estimators.batched import BatchBank\n"
        "from estimators._jit import HAVE_NUMBA\n"
        "assert not HAVE_NUMBA\n"
        "mk = lambda k: estimators.make(k, model='cvb', dim=3, dt=0.01,\n"
        "                               **({'window': 5} if k.startswith('pca') else {}))\n"
        "names = ('kf', 'mckf', 'pca-kf', 'pca-mckf')\n"
        "fs = {k: mk(k) for k in names}\n"
        "b = BatchBank.from_filters([{k: mk(k) for k in names}])\n"
        "rng = np.random.default_rng(1)\n"
        "for t in range(12):\n"
        "    z = rng.standard_normal((1, 3)) + (t == 9) * 40\n"
        "    b.predict(); b.update(z)\n"
        "    for f in fs.values(): f.predict(); f.update(z[0])\n"
        "for k in names: assert np.allclose(b[k].x[0], fs[k].x, rtol=1e-9, atol=1e-9), k\n"
    )
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True,
                       env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"}, timeout=120)
    assert r.returncode == 0, r.stderr


def test_bank_shared_pca_bit_identical():
    """BatchBank runs the PCA block once for the PCA-KF/PCA-MCKF pair where the windows are
    equal: same bits as updating each filter on its own, also after the windows diverge."""
    names = ("kf", "mckf", "pca-kf", "pca-mckf")
    N, ticks = 8, 200
    sc = _scenario(N, ticks, seed=5)
    mk = [{k: _make(k, i) for k in names} for i in range(N)]
    bank = BatchBank.from_filters(mk)
    solo = {k: batch_class(mk[0][k]).from_filters([b[k] for b in mk]) for k in names}
    assert len(bank._pairs) == 1
    for t in range(ticks):
        mask = sc["fix"][t]
        bank.predict(sc["u"][t])
        for f in solo.values():
            f.predict(sc["u"][t])
        if t == 60:  # rows 0-3 of PCA-KF alone get one more fix: windows differ from now on
            extra = np.arange(N) < 4
            bank["pca-kf"].update(sc["z"][t] + 1.0, extra)
            solo["pca-kf"].update(sc["z"][t] + 1.0, extra)
        ok = bank.update(sc["z"][t], mask)
        for k, f in solo.items():
            assert np.array_equal(f.update(sc["z"][t], mask), ok[k])
    for k in names:
        assert np.array_equal(bank[k].x, solo[k].x) and np.array_equal(bank[k].P, solo[k].P)
        assert np.array_equal(bank[k].nis, solo[k].nis, equal_nan=True)
    assert not np.array_equal(bank["pca-kf"].ring[0], bank["pca-mckf"].ring[0])
    assert np.array_equal(bank["pca-kf"].ring[5], bank["pca-mckf"].ring[5])


@pytest.mark.parametrize("model", ["cv", "cvb"])
def test_batch_kf_agrees_with_the_vectorised_numpy_reference(model):
    """BatchKF (both predict forms: CSR for "cv", 3×3 blocks for "cvb") against the
    einsum / matmul KF of tests/oracles/batched_numpy.py, to rounding."""
    from oracles.batched_numpy import numpy_kf_update, numpy_predict

    N = 6
    bf = BatchKF.from_filters([_make("kf", i, model=model) for i in range(N)])
    rng = np.random.default_rng(3)
    x, P = bf.x.copy(), bf.P.copy()
    mask = np.arange(N) % 3 != 1
    for t in range(120):
        u = rng.standard_normal((N, 3))
        bf.predict(u)
        x, P = numpy_predict(x, P, bf.F, bf.Q, u, bf.pos_idx, bf.vel_idx, 0.5 * DT * DT, DT)
        if t % 5 == 0:
            z = x[:, bf.pos_idx] + rng.standard_normal((N, 3))
            bf.update(z, mask)
            x, P, nis = numpy_kf_update(x, P, bf.R, bf.H, z, mask)
            np.testing.assert_allclose(bf.nis[mask], nis, rtol=1e-9)
    np.testing.assert_allclose(bf.x, x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(bf.P, P, rtol=1e-9, atol=1e-12)
    assert not np.array_equal(bf.x, bf.x[0])   # the rows differ: a real check
