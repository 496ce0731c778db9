"""``ag-uav bench``: speed figures measured in one process and one run.

Closed-loop speed of the default mission (no log, no renders) against raw MuJoCo stepping of the
very same compiled model, in sim-seconds per wall-second, and their ratio. Ratios taken in one run
are what to quote: absolute figures move with machine load.
"""

from __future__ import annotations

import copy
import math
import os
import statistics
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import mujoco

from ...config import Config
from .physics import (
    TRUE_STATE_OVERRIDES,
    batched_capture,
    batched_rate,
    batched_summaries,
    closed_loop,
    paired,
    physics_alone,
    raw_stepping,
    spread,
)


def _median_rate(fn: Callable[[], tuple[float, float]], repeats: int) -> float:
    """Median of sim-seconds per wall-second over ``repeats`` calls of ``fn`` -> (sim_s, wall_s)."""
    rates = []
    for _ in range(repeats):
        sim_s, wall_s = fn()
        rates.append(sim_s / wall_s)
    return statistics.median(rates)


def machine_facts() -> dict[str, Any]:
    """``machine``: what the figures were measured on. The CPU's model name and the CPU LLVM
    compiles the kernels for, the cores this process may use, the versions that set the speed,
    and a plain Python loop's time per iteration (``python_loop_ns``, :func:`python_loop_ns`).
    Machines of one kind differ in speed (docs/speed.md), and the engine's loop is partly the
    Python around its kernels: this figure, beside ``raw_mujoco``, tells whether figures from
    two machines can be compared."""
    import platform

    import llvmlite.binding as llvm
    import numba

    from ..executor import default_workers

    return {"cpu": _cpu_model(), "llvm_cpu": llvm.get_host_cpu_name(), "cores": default_workers(),
            "python": platform.python_version(), "numba": numba.__version__,
            "mujoco": mujoco.__version__, "python_loop_ns": python_loop_ns()}


def python_loop_ns(n: int = 1_000_000, repeats: int = 3) -> float:
    """Nanoseconds per iteration of ``for i in range(n): x += i * 2`` (median of ``repeats``)."""

    def once() -> float:
        x, t0 = 0, time.perf_counter()
        for i in range(n):
            x += i * 2
        return (time.perf_counter() - t0) / n * 1e9

    return round(statistics.median(once() for _ in range(repeats)), 1)


def _cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or the platform's processor string."""
    import platform

    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:  # pragma: no cover - not Linux
        pass
    return platform.processor() or "unknown"  # pragma: no cover


def run_bench(cfg: Config, repeats: int = 3, quick: bool = False) -> dict[str, Any]:
    out: dict[str, Any] = {"repeats": repeats, "machine": machine_facts()}
    c = with_overrides(cfg, TRUE_STATE_OVERRIDES)
    if quick:
        c.sim.max_time_s = min(c.sim.max_time_s, 60.0)
    ce = with_overrides(c, ESTIMATOR_LOG_OVERRIDES)
    last: dict = {}

    def cl() -> tuple[float, float]:
        sim_s, wall_s, s = closed_loop(c)
        last.update(s)
        return sim_s, wall_s

    closed = _median_rate(cl, repeats)
    sim_len = last.get("sim_time_s", 60.0)
    nsub = round(1.0 / (c.sim.timestep_s * c.sim.control_hz))
    raw1 = _median_rate(lambda: raw_stepping(c, sim_len, 1), repeats)
    rawn = _median_rate(lambda: raw_stepping(c, sim_len, nsub), repeats)
    out["closed_loop"] = {
        "sim_s_per_wall_s": round(closed, 1),
        "mission_sim_s": sim_len,
        "completed": last.get("completed"),
        "control_hz": c.sim.control_hz,
        "timestep_s": c.sim.timestep_s,
    }
    out["raw_mujoco"] = {
        "per_step_call_sim_s_per_wall_s": round(raw1, 1),
        f"nstep{nsub}_call_sim_s_per_wall_s": round(rawn, 1),
    }
    single = _median_rate(lambda: closed_loop(ce)[:2], repeats)
    out["single_estimators"] = {
        "sim_s_per_wall_s": round(single, 1),
        "config": ", ".join(f"{k}={v}" for k, v in ESTIMATOR_LOG_OVERRIDES.items()),
        "ratio_vs_raw_per_step": round(single / raw1, 3),
    }
    out["ratio_closed_vs_raw_per_step"] = round(closed / raw1, 3)
    out["ratio_closed_vs_raw_nstep"] = round(closed / rawn, 3)
    out["logging"] = logging_cost(c, repeats)
    for extra in _EXTRA:
        try:
            out.update(extra(c, repeats, quick))
        except Exception as e:  # a failing extra must not hide the main figures
            out[f"{extra.__name__}_error"] = f"{type(e).__name__}: {e}"
    return out


#: the estimator configuration the logging section also measures: RTK GNSS, PCA-MCKF in the loop,
#: KF/MCKF/PCA-KF shadows (logs /gps and four /estimator/<name> channels on top of the state)
ESTIMATOR_LOG_OVERRIDES: dict[str, Any] = {
    "gps.preset": "rtk-m350",
    "estimator.name": "pca-mckf",
    "estimator.shadow": ["kf", "mckf", "pca-kf"],
}


def with_overrides(cfg: Config, overrides: dict[str, Any]) -> Config:
    """``cfg`` with dotted-key ``overrides`` applied (validated like ``--set``)."""
    from ...config import config_from_dict

    data = cfg.to_dict()
    for k, v in overrides.items():
        node = data
        parts = k.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = copy.deepcopy(v)
    return config_from_dict(data)



class LoopCpu:
    """``tick_hook`` that samples the process CPU time every 64 ticks: the loop's CPU seconds
    (first tick to the last sample), which a busy shared machine moves far less than wall time.
    The same hook runs in the unlogged and the logged loops, so it cancels in their ratio."""

    def __init__(self) -> None:
        self.k = 0
        self.first = self.last = 0.0

    def __call__(self, t: float, data: Any) -> None:
        k = self.k
        self.k = k + 1
        if k & 63 == 0:
            self.last = time.process_time()
            if k == 0:
                self.first = self.last

    @property
    def seconds(self) -> float:
        return self.last - self.first


def logging_cost(cfg: Config, repeats: int = 3) -> dict[str, Any]:
    """Loop wall time of the mission with the full MCAP channel set (no renders) and the light set
    against the same loop unlogged, and the same for the estimator configuration
    (:data:`ESTIMATOR_LOG_OVERRIDES` applied to ``cfg``).

    Each repeat flies the unlogged loop and right after it the logged ones, so every ratio is
    taken between neighbouring runs (a load change on a shared machine hits both); the ratios
    are the medians of those per-repeat ratios, with their min and max as the spread.  The
    ``*_cpu`` ratios are the same from the loop's process CPU time, ``*_cpu_with_writer`` with
    the log's writer process's CPU time added (the log's encoding, compression and writes run
    there, on another core: :mod:`ag_uav.record.sink`); ``*_inline_writer`` the wall ratio with
    the writer in the loop's process (``RunLog(writer="inline")``, what a batch's logs use);
    ``*_us_per_message`` is the logged loop's added wall time (the medians' difference) over the
    messages the log wrote.
    """
    import tempfile
    from pathlib import Path

    from ...engine.missions import simulate
    from ...record.runlog import RunLog

    c = copy.deepcopy(cfg)
    c.log.render = False
    ce = with_overrides(c, ESTIMATOR_LOG_OVERRIDES)

    msgs: dict[str, int] = {}

    def fly(conf: Config, path: Path | None, channels: str = "full",
            writer: str = "process") -> tuple[float, ...]:
        hook = LoopCpu()
        if path is None:
            wall = simulate(conf, tick_hook=hook).summary["loop_wall_time_s"]
            return wall, hook.seconds, hook.seconds
        with RunLog(path, channels=channels, rates={"camera": 0.0}, metadata={},
                    config_toml="", layout=False, writer=writer) as log:
            wall = simulate(conf, log=log, tick_hook=hook).summary["loop_wall_time_s"]
            msgs[path.stem.rstrip("0123456789")] = sum(log.counts.values())
        return wall, hook.seconds, hook.seconds + log.writer_cpu_s

    runs: dict[str, list[tuple[float, ...]]] = {
        k: [] for k in ("plain", "full", "light", "inline", "e_plain", "e_full", "e_inline")}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for i in range(repeats):
            runs["plain"].append(fly(c, None))
            runs["full"].append(fly(c, d / f"full{i}.mcap"))
            runs["light"].append(fly(c, d / f"light{i}.mcap", "light"))
            runs["inline"].append(fly(c, d / f"inline{i}.mcap", writer="inline"))
            runs["e_plain"].append(fly(ce, None))
            runs["e_full"].append(fly(ce, d / f"est{i}.mcap"))
            runs["e_inline"].append(fly(ce, d / f"einline{i}.mcap", writer="inline"))
        size = (d / "full0.mcap").stat().st_size
        e_size = (d / "est0.mcap").stat().st_size
    return _log_figures(runs, msgs, size, e_size)


def _log_figures(runs: dict[str, list[tuple[float, ...]]], msgs: dict[str, int], size: int,
                 e_size: int) -> dict[str, Any]:
    """:func:`logging_cost`'s figures from its runs ((wall, loop CPU, loop + writer CPU) per
    repeat and kind), the messages per log and the two logs' sizes."""
    med = statistics.median

    def ratios(num: str, den: str, j: int = 0) -> list[float]:
        return [a[j] / b[j] for a, b in zip(runs[num], runs[den], strict=True)]

    def wall(k: str) -> float:
        return round(med(r[0] for r in runs[k]), 3)

    r_full, r_light, r_est = ratios("full", "plain"), ratios("light", "plain"), ratios(
        "e_full", "e_plain")

    def us_per_msg(num: str, den: str, key: str) -> float:  # the log's added time per message
        return round((wall(num) - wall(den)) / max(msgs.get(key, 0), 1) * 1e6, 2)

    return {"unlogged_loop_s": wall("plain"), "full_log_loop_s": wall("full"),
            "light_log_loop_s": wall("light"),
            "full_over_unlogged": round(med(r_full), 3),
            "full_over_unlogged_spread": spread(r_full),
            "full_over_unlogged_cpu": round(med(ratios("full", "plain", 1)), 3),
            "full_over_unlogged_cpu_with_writer": round(med(ratios("full", "plain", 2)), 3),
            "full_over_unlogged_inline_writer": round(med(ratios("inline", "plain")), 3),
            "light_over_unlogged": round(med(r_light), 3),
            "full_log_mb": round(size / 1e6, 2),
            "full_log_messages": msgs.get("full", 0),
            "full_log_us_per_message": us_per_msg("full", "plain", "full"),
            "estimators_unlogged_loop_s": wall("e_plain"),
            "estimators_full_log_loop_s": wall("e_full"),
            "estimators_ratio": round(med(r_est), 3),
            "estimators_ratio_spread": spread(r_est),
            "estimators_ratio_cpu": round(med(ratios("e_full", "e_plain", 1)), 3),
            "estimators_ratio_cpu_with_writer": round(med(ratios("e_full", "e_plain", 2)), 3),
            "estimators_ratio_inline_writer": round(med(ratios("e_inline", "e_plain")), 3),
            "estimators_full_log_mb": round(e_size / 1e6, 2),
            "estimators_full_log_messages": msgs.get("est", 0),
            "estimators_full_log_us_per_message": us_per_msg("e_full", "e_plain", "est"),
            "estimators_config": ", ".join(f"{k}={v}" for k, v in
                                           ESTIMATOR_LOG_OVERRIDES.items())}


def _workers(cfg: Config, repeats: int, quick: bool) -> dict[str, Any]:
    from .workers import bench_workers

    return bench_workers(cfg, repeats=max(1, min(repeats, 2)), quick=quick)


def _estimators(cfg: Config, repeats: int, quick: bool) -> dict[str, Any]:
    from .estimators import bench_estimators

    return {"estimators": bench_estimators(repeats=repeats, n=500 if quick else 2000)}



def _batched(c: Config, repeats: int, quick: bool) -> dict[str, Any]:
    """``batched`` (true state), ``batched_estimators`` (:data:`ESTIMATOR_LOG_OVERRIDES`: the
    INS bank) and ``batched_ideal_attitude`` (the same four rules as position filters on the
    idealised attitude, the bank batches flew before the INS): N missions in one engine batch,
    vehicle-sim-s per wall-s, against what the engine drives, measured in this run:
    ``ratio_vs_physics``, MuJoCo alone replaying the very same flights (initial states and
    controls captured from the engine) on the same threads, at its best way of spreading them,
    paired run by run with the engine (:func:`_paired`); ``ratio_vs_hover_physics``, MuJoCo
    alone stepping hovering copies (no ground contacts: a cheaper reference); ``ratio_vs_raw``,
    one raw ``mj_step`` loop. The engine flies in its default lanes (one per thread, each in a
    thread of its own: ``lanes``); ``one_engine_*`` is the same batch as one engine whose
    rollout uses every thread (no lanes), against the same reference. The batches of
    :data:`ALSO_WITHOUT_DOSE` are flown once more without the dose model
    (:func:`_without_dose`)."""
    from ...engine.physics import default_threads

    n, sim_s = (16, 20.0) if quick else (64, 60.0)
    threads = default_threads(n)
    ce = with_overrides(c, ESTIMATOR_LOG_OVERRIDES)
    batched_capture(ce, 2, 1.0)  # load the compiled kernels outside the timed loops
    hover = _median_rate(lambda: physics_alone(c, n, sim_s, threads, "threads"), repeats)
    out: dict[str, Any] = {}
    ci = with_overrides(ce, {"estimator.nav": "ideal-attitude"})
    for key, conf in (("batched", c), ("batched_estimators", ce),
                      ("batched_ideal_attitude", ci)):
        raw = _median_rate(lambda: raw_stepping(c, sim_s, 1), repeats)
        pr = paired(conf, n, sim_s, threads, repeats)
        rate, physics = pr["sim_s_per_wall_s"], pr["physics_sim_s_per_wall_s"]
        one = batched_capture(conf, n, sim_s, lanes=1)
        bare = _without_dose(conf, n, sim_s, threads, repeats) if key in ALSO_WITHOUT_DOSE else {}
        out[key] = {"vehicles": n, "mission_sim_s": sim_s, "engine_threads": threads, **pr,
                    "sim_s_per_wall_s": round(rate, 1),
                    "physics_sim_s_per_wall_s": round(physics, 1),
                    "one_engine_sim_s_per_wall_s": round(one[0] / one[1], 1),
                    "one_engine_ratio_vs_physics": round(one[0] / one[1] / physics, 3),
                    "hover_physics_sim_s_per_wall_s": round(hover, 1),
                    "ratio_vs_hover_physics": round(rate / hover, 3),
                    "raw_per_step_sim_s_per_wall_s": round(raw, 1),
                    "ratio_vs_raw": round(rate / raw, 3), **bare}
    out["batched_estimators"]["config"] = ", ".join(
        f"{k}={v}" for k, v in ESTIMATOR_LOG_OVERRIDES.items())
    out["batched_ideal_attitude"]["config"] = (out["batched_estimators"]["config"]
                                               + ", estimator.nav=ideal-attitude")
    return out


#: the batches whose ``ratio_vs_physics`` targets (≥ 0.85 true state, ≥ 0.60 the four-rule
#: bank on the idealised attitude) hold for the flight without the dose on the ground: they are
#: also measured without it, the workload the targets are stated for
ALSO_WITHOUT_DOSE = ("batched", "batched_ideal_attitude")


def _without_dose(conf: Config, n: int, sim_s: float, threads: int,
              repeats: int) -> dict[str, Any]:
    """``ratio_vs_physics_without_deposition``: the same batch with ``spray.deposition`` off,
    paired with the replay of its own flights as :func:`_paired` does (the dose model only
    observes, so the flights, hence the physics, are the same)."""
    pr = paired(with_overrides(conf, {"spray.deposition": False}), n, sim_s, threads, repeats)
    return {"sim_s_per_wall_s_without_deposition": round(pr["sim_s_per_wall_s"], 1),
            "ratio_vs_physics_without_deposition": pr["ratio_vs_physics"],
            "ratio_vs_physics_without_deposition_spread": pr["ratio_vs_physics_spread"]}


def _deposition(c: Config, repeats: int, quick: bool) -> dict[str, Any]:
    """``deposition``: the dose on the ground's share of the loop. ``loop_share``: the
    deposition stage's own wall time (``Depositing.step``, the only method timed) over the
    loop's, for one whole mission (true state) and for a batch of N of 60 s
    (``loop_share_batched``); medians of ``repeats`` flights, with their min and max.
    ``loop_share_difference``: (loop time with ``spray.deposition`` − without) / with, each
    repeat flying with and right after it without, also from the loop's CPU seconds
    (``*_cpu``). Both shares of one flight come from the same loop; the differences come from
    two, and on a busy machine they move with the load more than with the dose model."""
    sim_s = 20.0 if quick else 60.0
    n = 16 if quick else 64
    whole = with_overrides(c, {"spray.deposition": True})
    if quick:
        whole.sim.max_time_s = min(whole.sim.max_time_s, 120.0)
    on = with_overrides(whole, {"sim.max_time_s": sim_s})
    batched_rate(on, 2, 1.0)  # compiled kernels loaded outside the timed loops
    flown: dict[str, float] = {}

    def one(conf: Config) -> list[dict]:
        s = closed_loop(conf)[2]
        flown["sim_s"] = s["sim_time_s"]
        return [s]

    def many(conf: Config) -> list[dict]:
        return batched_summaries(conf, n, sim_s)

    out = {**_stage_share(one, whole, repeats, ""), **_stage_share(many, on, repeats, "_batched")}
    for fly, conf, key in ((one, whole, ""), (many, on, "_batched")):
        out.update(_difference_share(fly, conf, repeats, key))
    return {"deposition": {
        **out, "mission_sim_s": flown["sim_s"], "batched_vehicles": n,
        "batched_mission_sim_s": sim_s, "target": 0.15}}


def _stage_share(fly: Callable[[Config], list[dict]], on: Config, repeats: int,
                 key: str) -> dict[str, Any]:
    """``loop_share{key}``: the deposition stage's wall time over the loop's, the engine on one
    thread (a batch as one lane), so that the stage's time and the loop's are of one thread
    (see :func:`_deposition`). The kernels must be loaded before: a compile in tick 0 is kept
    out of the loop's time but not out of the stage's."""
    shares = []
    for _ in range(repeats):
        acc: Counter = Counter()
        with _timed_stages(acc, only=("dose_model",)), _one_thread():
            wall = _loop_times(fly(on))[0]
        shares.append(acc["dose_model"] / wall)
    return {f"loop_share{key}": round(statistics.median(shares), 3),
            f"loop_share{key}_spread": spread(shares)}


def _difference_share(fly: Callable[[Config], list[dict]], on: Config, repeats: int,
                      key: str) -> dict[str, Any]:
    """``loop_share_difference{key}`` and its ``_cpu`` twin (see :func:`_deposition`)."""
    off = with_overrides(on, {"spray.deposition": False})
    wall, cpu = [], []
    for _ in range(repeats):
        a, b = _loop_times(fly(on)), _loop_times(fly(off))
        wall.append((a[0] - b[0]) / a[0])
        cpu.append((a[1] - b[1]) / a[1])
    k = f"loop_share_difference{key}"
    return {k: round(statistics.median(wall), 3), f"{k}_spread": spread(wall),
            f"{k}_cpu": round(statistics.median(cpu), 3), f"{k}_cpu_spread": spread(cpu)}


def _loop_times(summaries: list[dict]) -> tuple[float, float]:
    """(loop wall, loop CPU) seconds of one flight or of one batch (each run's summary holds
    its share of the batch's loop)."""
    return (sum(s["loop_wall_time_s"] for s in summaries),
            sum(s["loop_cpu_time_s"] for s in summaries))


#: the engine's stages as :func:`_stages` times them: (class in engine.stages, method, key)
_STAGES = (("Guard", "start", "guard"), ("Sensing", "step", "imu"),
           ("Feedback", "step", "feedback"), ("Control", "step", "cascade"),
           ("Spraying", "step", "spray_job"), ("Disturbance", "step", "wind"),
           ("Depositing", "step", "dose_model"), ("Recorder", "step", "record"))


@contextmanager
def _timed_stages(acc: Counter, only: tuple[str, ...] | None = None) -> Iterator[None]:
    """Every stage's method (and the physics step; ``only``: those keys alone) wrapped to add
    its wall time to ``acc`` for the duration of the block; the classes are restored after it."""
    from ...engine import loop, stages

    saved = [(getattr(stages, c), m, k) for c, m, k in _STAGES] + [(loop.Engine, "physics",
                                                                     "physics")]
    saved = [x for x in saved if only is None or x[2] in only]
    originals = [(cls, m, getattr(cls, m)) for cls, m, _ in saved]

    def timed(f: Callable[..., Any], key: str) -> Callable[..., Any]:
        def g(*a: Any, **kw: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return f(*a, **kw)
            finally:
                acc[key] += time.perf_counter() - t0
        return g

    try:
        for (cls, m, f), (_, _, key) in zip(originals, saved, strict=True):
            setattr(cls, m, timed(f, key))
        yield
    finally:
        for cls, m, f in originals:
            setattr(cls, m, f)


def _stages(c: Config, repeats: int, quick: bool) -> dict[str, Any]:
    """``stages``: where one lane's time goes. N missions as one engine on one thread (a lane
    of a 2N batch on 2 cores), each stage's wall time per vehicle and tick, the physics' too,
    and the stages' total ÷ the physics (a batch's ``ratio_vs_physics`` is about 1 / (1 + it),
    less the lanes' contention); a second batch, the first warms the memory and kernels."""
    n, sim_s = (8, 10.0) if quick else (32, 20.0)
    out: dict[str, Any] = {"vehicles": n, "mission_sim_s": sim_s}
    with _one_thread():
        for key, conf in (("true_state", c), ("ins_bank", with_overrides(
                c, ESTIMATOR_LOG_OVERRIDES))):
            batched_capture(conf, n, sim_s, lanes=1)
            acc: Counter = Counter()
            with _timed_stages(acc):
                sim, wall, _ = batched_capture(conf, n, sim_s, lanes=1)
            vt = sim * conf.sim.control_hz   # vehicle-ticks
            row = {k: round(v / vt * 1e6, 2) for k, v in acc.most_common()}
            staged = sum(v for k, v in acc.items() if k != "physics")
            row["loop_rest"] = round((wall - staged - acc["physics"]) / vt * 1e6, 2)
            row["stages_over_physics"] = round((wall - acc["physics"]) / acc["physics"], 3)
            out[key] = row
    return {"stages_us_per_vehicle_tick": out}


@contextmanager
def _one_thread() -> Iterator[None]:
    """Engines built in the block fly on one thread (one lane, a one-thread rollout)."""
    prev = os.environ.get("AG_UAV_ENGINE_THREADS")
    os.environ["AG_UAV_ENGINE_THREADS"] = "1"
    try:
        yield
    finally:
        if prev is None:
            os.environ.pop("AG_UAV_ENGINE_THREADS", None)
        else:
            os.environ["AG_UAV_ENGINE_THREADS"] = prev


def _first_run(c: Config, repeats: int, quick: bool) -> dict[str, Any]:
    """``first_run``: the default mission's first run in a fresh process with an empty numba
    cache (:mod:`ag_uav.jobs.bench.first_run`): its wall time and the compile, kernel by kernel."""
    from .first_run import measure_first_run

    return {"first_run": measure_first_run()}


def _vehicles(c: Config, repeats: int, quick: bool) -> dict[str, Any]:
    """``vehicles``: the default mission on each preset, single and batched, against MuJoCo
    stepping that preset's own model (:mod:`ag_uav.jobs.bench.vehicles`)."""
    from .vehicles import bench_vehicles

    return {"vehicles": bench_vehicles(repeats=repeats, quick=quick)}


def _big_job(c: Config, repeats: int, quick: bool) -> dict[str, Any]:
    """``big_job``: the 38 ha job flown whole in a fresh process, with the full log
    (:mod:`ag_uav.jobs.bench.big`); skipped with ``--quick``."""
    if quick:
        return {}
    from .big import measure_big_job

    return {"big_job": measure_big_job()}


_EXTRA: list[Callable[[Config, int, bool], dict[str, Any]]] = [_estimators, _workers, _batched,
                                                               _deposition, _stages, _vehicles,
                                                               _first_run, _big_job]


def print_bench(out: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title="ag-uav bench (one process, one run)")
    t.add_column("measurement")
    t.add_column("value", justify="right")

    def walk(d: dict, prefix: str = "") -> None:
        for k, v in d.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            else:
                if isinstance(v, float) and not math.isfinite(v):
                    v = "n/a"
                t.add_row(f"{prefix}{k}", str(v))

    walk(out)
    Console().print(t)
