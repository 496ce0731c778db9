"""A numpy-vectorised batched KF (einsum / matmul over the batch axis), written from the
formulas independently of :mod:`estimators.batched`'s row functions: a reference the batched
rows are checked against (``tests/test_batched_estimators.py``), and the baseline of the speed
comparison ``python tests/oracles/batched_numpy.py`` (µs per vehicle-tick: predict with the IMU
input every tick, an update every tenth; numpy KF, the numba BatchKF, the four filters of a
BatchBank)."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from estimators.batched import BatchBank, BatchKF


def numpy_predict(x, P, F, Q, u, pos, vel, hh, dt) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised batched predict (einsum/matmul: the matmuls over the batch are not
    guaranteed row-independent bit for bit, so it agrees with the rows to rounding only)."""
    x = np.einsum("ij,nj->ni", F, x)
    P = np.matmul(np.matmul(F, P), F.T) + Q
    if u is not None:
        x[:, pos] += hh * u
        x[:, vel] += dt * u
    return x, P


def numpy_kf_update(x, P, R, H, z, mask) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised batched KF update of the masked rows (Joseph form, as the rows)."""
    xs, Ps, Rs, zs = x[mask], P[mask], R[mask], z[mask]
    PHT = np.matmul(Ps, H.T)
    S = np.matmul(H, PHT) + Rs
    Si = np.linalg.inv(S)
    nu = zs - np.einsum("ij,nj->ni", H, xs)
    nis = np.einsum("ni,nij,nj->n", nu, Si, nu)
    K = np.matmul(PHT, Si)
    xs = xs + np.einsum("nij,nj->ni", K, nu)
    A = np.eye(x.shape[1]) - np.matmul(K, H)
    Ps = np.matmul(np.matmul(A, Ps), A.transpose(0, 2, 1)) + np.matmul(
        np.matmul(K, Rs), K.transpose(0, 2, 1))
    x[mask], P[mask] = xs, Ps
    return x, P, nis


def _bench_one(N: int, ticks: int, fix_every: int, repeats: int) -> dict[str, float]:
    import estimators

    params = dict(model="cvb", dim=3, dt=0.01, q=0.05, r=[0.5, 0.5, 0.01], q_bias=1e-4)
    extra: dict[str, dict[str, Any]] = {
        "kf": {}, "mckf": dict(sigma=2.0, max_iter=10, recovery="kf"),
        "pca-kf": dict(window=10, mode="hankel"),
        "pca-mckf": dict(window=10, mode="hankel", sigma=2.0, max_iter=10, recovery="kf")}
    rng = np.random.default_rng(N)
    bank = BatchBank.from_filters([{k: estimators.make(k, **params, **v)
                                    for k, v in extra.items()} for _ in range(N)])
    u = rng.standard_normal((ticks, N, 3))
    z = rng.standard_normal((ticks, N, 3))
    kf = BatchKF.from_filters([estimators.make("kf", **params) for _ in range(N)])
    st = {"x": kf.x.copy(), "P": kf.P.copy()}
    mask = np.ones(N, dtype=bool)

    def run_numpy(t: int) -> None:
        st["x"], st["P"] = numpy_predict(st["x"], st["P"], kf.F, kf.Q, u[t], kf.pos_idx,
                                          kf.vel_idx, 0.5 * kf.dt * kf.dt, kf.dt)
        if t % fix_every == 0:
            st["x"], st["P"], _ = numpy_kf_update(st["x"], st["P"], kf.R, kf.H, z[t], mask)

    def run_kf(t: int) -> None:
        kf.predict(u[t])
        if t % fix_every == 0:
            kf.update(z[t], mask)

    def run_bank(t: int) -> None:
        bank.predict(u[t])
        if t % fix_every == 0:
            bank.update(z[t], mask)

    times = []
    for step in (run_numpy, run_kf, run_bank):
        for t in range(fix_every):  # warm-up (numba: compile or load from the cache)
            step(t)
        best = math.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            for t in range(ticks):
                step(t)
            best = min(best, time.perf_counter() - t0)
        times.append(best * 1e6 / (ticks * N))
    return {"numpy_kf_us": times[0], "numba_kf_us": times[1], "numba_bank4_us": times[2]}


def benchmark(sizes: Sequence[int] = (1, 64, 256), ticks: int = 400, fix_every: int = 10,
              repeats: int = 3) -> dict[int, dict[str, float]]:
    """µs per vehicle-tick (best of ``repeats``) of predict (+IMU input) every tick and an
    update every ``fix_every``-th tick: numpy-vectorised KF (batched matmul/einsum) vs the
    numba kernels (KF alone, and the four filters of a :class:`BatchBank`)."""
    return {N: _bench_one(N, ticks, fix_every, repeats) for N in sizes}


if __name__ == "__main__":  # pragma: no cover
    t0 = time.perf_counter()
    _bench_one(1, 2, 1, 1)
    print(f"first use of the kernels (compile or cache load): {time.perf_counter() - t0:.2f} s")
    for N, r in benchmark().items():
        print(N, {k: round(v, 3) for k, v in r.items()})
