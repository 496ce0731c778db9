"""``ag-uav bench``'s engine-against-physics figures: N missions flown as one lockstep batch, and
MuJoCo alone stepping or replaying the very same flights (``mujoco.rollout`` on threads), the
reference of the batch's ``ratio_vs_physics``."""

from __future__ import annotations

import copy
import statistics
import time
from typing import Any

import mujoco
import numpy as np

from ...config import Config
from ...vehicle.mjcf import G, build_vehicle

#: the true-state configuration the closed-loop, raw and logging ratios are measured on
TRUE_STATE_OVERRIDES: dict[str, Any] = {"estimator.name": "true", "estimator.shadow": []}


def raw_stepping(cfg: Config, sim_seconds: float, nstep: int = 1) -> tuple[float, float]:
    """Raw MuJoCo stepping of the mission's model: hover thrust, ``mj_step(m, d, nstep)`` in a
    Python loop (nstep=1: one call per physics step)."""
    veh = build_vehicle(cfg)
    m = veh.model
    d = mujoco.MjData(m)
    d.qpos[2] = 3.0
    d.ctrl[:] = veh.mass * G / sum(veh.eff)  # hover: the thrust each rotor of the frame holds
    d.act[:] = veh.mass * G / sum(veh.eff)
    n_calls = int(sim_seconds / (m.opt.timestep * nstep))
    step = mujoco.mj_step
    t0 = time.perf_counter()
    if nstep == 1:
        for _ in range(n_calls):
            step(m, d)
    else:
        for _ in range(n_calls):
            step(m, d, nstep)
    wall = time.perf_counter() - t0
    return n_calls * nstep * m.opt.timestep, wall


def closed_loop(cfg: Config) -> tuple[float, float, dict]:
    """One mission of ``cfg`` without a log: its simulated seconds, its loop's wall seconds and
    its summary."""
    from ...engine.missions import simulate

    c = copy.deepcopy(cfg)
    c.log.enabled = False
    res = simulate(c)
    s = res.summary
    return s["sim_time_s"], s["loop_wall_time_s"], s


def spread(ratios: list[float]) -> dict[str, float]:
    """The min and max of ``ratios`` (rounded): the spread beside a median."""
    return {"min": round(min(ratios), 3), "max": round(max(ratios), 3)}


def _batch_cfgs(cfg: Config, n: int, sim_s: float) -> list[Config]:
    """``n`` copies of ``cfg`` with seeds 0…n-1, no log, no renders, cut at ``sim_s``."""
    cfgs = []
    for i in range(n):
        c = copy.deepcopy(cfg)
        c.seed = i
        c.log.enabled = False
        c.log.render = False
        c.sim.max_time_s = sim_s
        cfgs.append(c)
    return cfgs


def batched_summaries(cfg: Config, n: int, sim_s: float) -> list[dict]:
    """The summaries of ``n`` missions of ``cfg`` (seeds 0…n-1, cut at ``sim_s``) flown as one
    lockstep batch (:func:`ag_uav.engine.missions.simulate_many`)."""
    from ...engine.missions import simulate_many

    return [r.summary for r in simulate_many(_batch_cfgs(cfg, n, sim_s))]


def batched_rate(cfg: Config, n: int, sim_s: float) -> tuple[float, float]:
    """Vehicle-sim-seconds and loop wall seconds of ``n`` missions of ``cfg`` flown as one
    lockstep batch (:func:`batched_summaries`)."""
    res = batched_summaries(cfg, n, sim_s)
    return sum(s["sim_time_s"] for s in res), res[0]["loop_wall_time_s"] * n


def physics_alone(cfg: Config, n: int, sim_s: float, nthread: int,
                  chunk_size: int | None | str = None) -> tuple[float, float]:
    """Vehicle-sim-seconds and wall seconds of MuJoCo alone stepping ``n`` hovering copies of
    ``cfg``'s model in control periods (``mujoco.rollout`` on ``nthread`` threads, zero warm
    start, final state kept): the reference of ``ratio_vs_hover_physics``
    (hovering: no ground contacts, so cheaper than a mission's take-off and landings)."""
    import numpy as np

    from ...engine.physics import STATE_SPEC

    veh = build_vehicle(cfg)
    m = veh.model
    d = mujoco.MjData(m)
    d.qpos[2], d.qpos[3] = 3.0, 1.0
    d.ctrl[:] = d.act[:] = veh.mass * G / sum(veh.eff)
    mujoco.mj_forward(m, d)
    s0 = np.empty(mujoco.mj_stateSize(m, STATE_SPEC))
    mujoco.mj_getState(m, d, s0, STATE_SPEC)
    periods = int(round(sim_s * cfg.sim.control_hz))
    f = np.full((periods, m.nu), veh.mass * G / sum(veh.eff))
    ctl = np.concatenate([f, np.zeros((periods, 3))], axis=1)
    models = [m] + [copy.copy(m) for _ in range(n - 1)]
    nsub = round(1.0 / (cfg.sim.timestep_s * cfg.sim.control_hz))
    wall = replay_physics(models, veh.body_id, nsub, [s0] * n, [ctl] * n, nthread,
                          chunk_size)[0]
    return n * periods * nsub * m.opt.timestep, wall


def replay_physics(models: list, body: int, nsub: int, s0: list, controls: list, nthread: int,
                   chunk_size: int | None | str = None, masses: list | None = None,
                   ) -> tuple[float, np.ndarray]:
    """MuJoCo alone replaying recorded flights: vehicle i from state ``s0[i]`` with
    ``controls[i]`` ((n_i, rotors + 3): rotor commands, applied force) held over each control
    period, as the engine hands them to the physics, and the spray job's liquid-mass changes
    (``masses[i]``: its Sprayer, whose ``mass_events`` are replayed at their ticks); the same
    bits as the flight. ``chunk_size``: the rollout pool's chunking (None: MuJoCo's default);
    ``"lanes"``: one single-thread rollout per thread on its own part of the batch, the parts
    kept in step tick by tick; ``"threads"``: the same parts, each thread replaying its part to
    the end on its own (the engine's lanes). Returns (wall seconds, final states)."""
    from concurrent.futures import ThreadPoolExecutor

    from ...engine.kernels import controls as pack

    N = len(models)
    n_i = np.array([len(c) for c in controls])
    nu = models[0].nu
    C = np.zeros((int(n_i.max()), N, nu + 3))
    for i, c in enumerate(controls):
        C[:len(c), i] = c
    S = np.array(s0, dtype=float)
    split = chunk_size in ("lanes", "threads") and nthread > 1
    parts = np.array_split(np.arange(N), nthread) if split else [np.arange(N)]
    reps = [_Replayer(models, p, body, nsub, S, 0 if split else nthread,
                      None if chunk_size in ("lanes", "threads") else chunk_size) for p in parts]
    events = _mass_events(masses, nsub * models[0].opt.timestep, parts)
    xcol = models[0].nu + 6 * body
    pool = ThreadPoolExecutor(len(parts)) if split else None

    def lane(j: int, ks: range) -> None:
        rep, ev = reps[j], events[j]
        for k in ks:
            for sp, m in ev.get(k, ()):
                sp.set_liquid_mass(m)
            act = k < n_i
            pack(rep.U, C[k, rep.sl, :nu], C[k, rep.sl, nu:], xcol, act[rep.sl])
            rep.step(S, act)

    try:
        t0 = time.perf_counter()
        if chunk_size == "threads" and pool is not None:
            for fu in [pool.submit(lane, j, range(len(C))) for j in range(len(parts))]:
                fu.result()
        else:
            for k in range(len(C)):
                futs = [pool.submit(lane, j, range(k, k + 1)) for j in range(1, len(parts))
                        ] if pool else []
                lane(0, range(k, k + 1))
                for fu in futs:
                    fu.result()
        wall = time.perf_counter() - t0
    finally:
        for r in reps:
            r.runner.close()
        if pool is not None:
            pool.shutdown()
    return wall, S


def _mass_events(masses: list | None, dt: float, parts: list[np.ndarray]
                 ) -> list[dict[int, list]]:
    """Each part's liquid-mass changes by tick ((the vehicle's Sprayer, the mass) pairs), the
    tanks filled first."""
    events: list[dict[int, list]] = [{} for _ in parts]
    for j, part in enumerate(parts):
        for i in part:
            sp = masses[i] if masses else None
            if sp is not None and sp.mass_events is not None:
                sp.set_liquid_mass(sp.job.fill_l * sp.rho)
                for t, m in sp.mass_events:
                    events[j].setdefault(int(round(t / dt)), []).append((sp, m))
    return events


class _Replayer:
    """One part of a replay: its rows (a contiguous range), a rollout on ``nthread`` threads
    and its buffers; with every row active it hands MuJoCo views, as the engine does."""

    def __init__(self, models: list, ii: np.ndarray, body: int, nsub: int, S: np.ndarray,
                 nthread: int, chunk: int | None) -> None:
        from mujoco import rollout

        from ...engine.physics import CTRL_SPEC

        m0 = models[0]
        self.ii, self.nsub, self.chunk, self.spec = ii, nsub, chunk, CTRL_SPEC
        self.sl = slice(int(ii[0]), int(ii[-1]) + 1) if len(ii) else slice(0, 0)
        self.models = [models[i] for i in ii]
        self.runner = rollout.Rollout(nthread=nthread)
        self.data = [mujoco.MjData(m0) for _ in range(max(nthread, 1))]
        n = len(ii)
        self.U = np.zeros((n, nsub, mujoco.mj_stateSize(m0, CTRL_SPEC)))
        self.so = np.empty((n, nsub, S.shape[1]))
        self.se = np.empty((n, nsub, m0.nsensordata))
        self.warm = np.zeros((n, m0.nv))

    def step(self, S: np.ndarray, act: np.ndarray) -> None:
        a = act[self.sl]
        n = int(a.sum())
        if n == len(a):
            models, S0, U, rows = self.models, S[self.sl], self.U, self.sl
        elif n:
            j = np.flatnonzero(a)
            models, S0, U = [self.models[i] for i in j], S[self.sl][j], self.U[j]
            rows = self.ii[j]
        else:
            return
        self.runner.rollout(models, self.data, S0, U, control_spec=self.spec, nstep=self.nsub,
                            initial_warmstart=self.warm[:n], state=self.so[:n],
                            sensordata=self.se[:n], skip_checks=True, chunk_size=self.chunk)
        S[rows] = self.so[:n, -1]


def _replay_args(outs: list) -> tuple:
    """(models, body, nsub, s0, controls, sprayers) of a captured engine batch."""
    models = [o.vehicle.model for o in outs]
    dt = float(outs[0].t[1] - outs[0].t[0]) if len(outs[0].t) > 1 else 0.01
    return (models, outs[0].vehicle.body_id, round(dt / models[0].opt.timestep),
            [o.s0 for o in outs], [o.controls for o in outs], [o.sprayer for o in outs])


def replay_wall(outs: list, nthread: int, way: Any) -> float:
    """Wall seconds of MuJoCo alone replaying a captured engine batch one ``way``
    (:func:`replay_physics`'s ``chunk_size``)."""
    models, body, nsub, s0, ctl, spr = _replay_args(outs)
    return replay_physics(models, body, nsub, s0, ctl, nthread, way, spr)[0]


def best_replay(outs: list, nthread: int, repeats: int) -> tuple[float, str]:
    """The physics alone of an engine batch (its outputs captured with ``capture=True``),
    replayed at MuJoCo's best way of spreading it on ``nthread`` threads (the rollout pool at
    its default chunking or 1, 2, 4, 8 chunks per thread, or one rollout per thread):
    (best wall seconds, how)."""
    from ...engine.physics import default_threads

    nthread = nthread or default_threads(len(outs))
    n = len(outs)
    ways: list[Any] = [None, "lanes", "threads"] + sorted({max(1, -(-n // (k * max(nthread, 1))))
                                                for k in (1, 2, 4, 8)})
    walls = {str(w): min(replay_wall(outs, nthread, w) for _ in range(max(1, repeats)))
             for w in ways}
    best = min(walls, key=walls.__getitem__)
    return walls[best], best


def _way(how: str) -> Any:
    """:func:`best_replay`'s ``how`` back to a ``chunk_size``."""
    return None if how == "None" else how if how in ("lanes", "threads") else int(how)


def batched_capture(cfg: Config, n: int, sim_s: float, lanes: int | None = None
                    ) -> tuple[float, float, list]:
    """Vehicle-sim-seconds, loop wall seconds and the captured outputs (initial states and
    controls) of ``n`` missions of ``cfg`` (seeds 0…n-1, cut at ``sim_s``) as one engine
    batch (``lanes``: the engine's default split, or 1 for one engine)."""
    from ...engine.missions import fly_many

    outs = fly_many(_batch_cfgs(cfg, n, sim_s), capture=True, lanes=lanes)
    dt = 1.0 / cfg.sim.control_hz
    return sum(len(o.t) for o in outs) * dt, outs[0].wall_loop_s, outs


_HOW = {"None": "rollout pool, default chunks",
        "lanes": "one single-thread rollout per thread, kept in step every tick",
        "threads": "one single-thread rollout per thread, each on its part to the end"}


def paired(conf: Config, n: int, sim_s: float, threads: int, repeats: int) -> dict[str, Any]:
    """The engine's batch against MuJoCo alone replaying it: the first batch's replay tried
    every way once (:func:`best_replay`) to pick the best; then ``repeats`` pairs, each an
    engine batch and, right after it, the replay of its very flights that way. The rates are
    medians and the ratio the median of the pairs' ratios (a pair shares the machine's state
    of the moment; a best-of-seven reference against a median engine would flatter MuJoCo).
    ``loop_cores_busy``: the engine loop's process CPU time over its wall time (median): at the
    core count, the loop waits for nothing and its ratio is the physics' share of the work."""
    first = batched_capture(conf, n, sim_s)
    sel_wall, how = best_replay(first[2], threads, 1)
    pairs = [first[:2] + (replay_wall(first[2], threads, _way(how)),)]
    busy = [first[2][0].cpu_loop_s / first[1]]
    for _ in range(max(1, repeats) - 1):
        sim, wall, outs = batched_capture(conf, n, sim_s)
        pairs.append((sim, wall, replay_wall(outs, threads, _way(how))))
        busy.append(outs[0].cpu_loop_s / wall)
    sim = pairs[0][0]
    ratios = [p[2] / p[1] for p in pairs]
    return {"lanes": first[2][0].lanes, "loop_cores_busy": round(statistics.median(busy), 3),
            "sim_s_per_wall_s": statistics.median(p[0] / p[1] for p in pairs),
            "physics_sim_s_per_wall_s": statistics.median(sim / p[2] for p in pairs),
            "physics_how": _HOW.get(how, f"rollout pool, chunks of {how}"),
            "physics_best_of_ways_sim_s_per_wall_s": round(sim / sel_wall, 1),
            "ratio_vs_physics": round(statistics.median(ratios), 3),
            "ratio_vs_physics_spread": spread(ratios)}
