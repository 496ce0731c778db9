"""The search: the optimiser (BB-BC, PSO or CMA-ES) asked and told each iteration, the
evaluations spread over the executor, the checkpoint and the evaluation journal that
``--resume`` continues from."""

from __future__ import annotations

import contextlib
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...config import ConfigError, config_from_dict
from ...record.atomic import atomic_write_text
from ..batch import (
    exception_line,
    get_dotted,
    read_jsonl,
    repair_jsonl,
)
from ..executor import Executor, SerialExecutor
from .cost import chunk, evaluate_candidates
from .outputs import TuneResult, top_candidates, write_outputs
from .spec import TuneSpec


def default_values(spec: TuneSpec) -> list[float]:
    """The base config's current values of the tuned keys (the "before" gains)."""
    d = config_from_dict(spec.base).to_dict()
    return [float(get_dotted(d, p.key)) for p in spec.params]


def _make_optimizer(spec: TuneSpec) -> Any:
    from controllers.optim import BBBC, CMAES, PSO

    lo = [p.bounds[0] for p in spec.params]
    hi = [p.bounds[1] for p in spec.params]
    oo = dict(spec.optimizer_options)
    if spec.optimizer == "pso":
        if isinstance(oo.get("inertia"), list):
            oo["inertia"] = tuple(oo["inertia"])
            oo["max_iter"] = spec.iters
        return PSO(lo, hi, pop=spec.pop, rng=spec.seed, **oo)
    if spec.optimizer == "cmaes":
        return CMAES(lo, hi, pop=spec.pop, rng=spec.seed, **oo)
    return BBBC(lo, hi, pop=spec.pop, rng=spec.seed, **oo)


def _opt_from_state(state: dict[str, Any]) -> Any:
    from controllers.optim import BBBC, CMAES, PSO

    return {"pso": PSO, "cmaes": CMAES}.get(state["kind"], BBBC).from_state(state)


def _population(opt: Any) -> np.ndarray:
    return opt.ask()


def _set_member(opt: Any, i: int, u: np.ndarray) -> None:
    if hasattr(opt, "population"):
        opt.population[i] = u
    else:
        opt.x[i] = u


def _xkey(u: Sequence[float]) -> str:
    return json.dumps([float(v) for v in u])


class TuneStopped(RuntimeError):
    """Evaluations were lost to the machinery after the retries (one line); the checkpoint of the
    last finished iteration and the evaluation journal are kept, ``--resume`` continues."""


#: times a chunk of evaluations whose worker died is resubmitted before the tune stops
LOST_RETRIES = 2


def run_tune(spec: TuneSpec, out_dir: str | Path, executor: Executor | None = None, *,
             resume: bool = False, fresh: bool = False, iters: int | None = None,
             progress: bool = True, outputs: bool = True,
             on_iteration: Callable[[int, dict[str, Any]], None] | None = None,
             warn: Callable[[str], None] | None = None) -> TuneResult:
    """Run (or resume) the optimisation; see the module docstring.

    Nothing is silent: a chunk whose engine batch failed and was evaluated one candidate at a
    time is a warning (``warn``, default one line on stderr) and counted (``engine_fallbacks``
    per iteration, :attr:`TuneResult.n_fallback`, ``tune.json``); evaluations lost to a dead
    worker are resubmitted :data:`LOST_RETRIES` times, then :class:`TuneStopped` (a lost
    executor: :class:`~ag_uav.jobs.executor.ExecutorLost`) ends the call, never a made-up cost.
    ``out_dir`` belongs to this tune while it runs (:func:`ag_uav.jobs.outdir.hold`).
    """
    from ..outdir import hold

    with hold(out_dir, "tune", "wait for it to finish, or choose another --out"):
        return _run_tune(spec, Path(out_dir), executor, resume=resume, fresh=fresh, iters=iters,
                         progress=progress, outputs=outputs, on_iteration=on_iteration,
                         warn=warn)


def _run_tune(spec: TuneSpec, out: Path, executor: Executor | None, *, resume: bool,
              fresh: bool, iters: int | None, progress: bool, outputs: bool,
              on_iteration: Callable[[int, dict[str, Any]], None] | None,
              warn: Callable[[str], None] | None) -> TuneResult:
    ck_path, ev_path = out / "checkpoint.json", out / "evals.jsonl"
    if (ck_path.exists() or ev_path.exists()) and not (resume or fresh):
        raise ConfigError(f'--out = "{out}": already holds a tuning checkpoint; use --resume to '
                          "continue it or --fresh to start over")
    out.mkdir(parents=True, exist_ok=True)
    executor = executor or SerialExecutor()
    n_iter = iters if iters is not None else spec.iters
    h = spec.hash()
    x0 = default_values(spec)
    opt, log_stats = _start(spec, ck_path, ev_path, h, x0, resume, fresh)
    ev = _EvalLog(ev_path, h, spec, progress, n_iter, opt.iteration, warn)
    t_start = time.perf_counter()
    try:
        while opt.iteration < n_iter:
            t_it = time.perf_counter()
            U = _population(opt)
            k = opt.iteration + 1
            results, n_fb = ev.evaluate(executor, U, k)
            costs = [r["cost"] for r in results]
            opt.tell(costs)
            fin = np.array([c for c in costs if math.isfinite(c)])
            stat = {"iteration": k, "best_so_far": opt.best_f, "gen_min": float(fin.min()),
                    "gen_median": float(np.median(fin)),
                    "crashes": sum(bool(r["crash"]) for r in results),
                    "engine_fallbacks": n_fb, "wall_s": round(time.perf_counter() - t_it, 3)}
            log_stats.append(stat)
            atomic_write_text(ck_path, json.dumps({
                "version": 1, "spec_hash": h, "spec_name": spec.name,
                "optimizer": opt.state_dict(), "iterations": log_stats, "default_values": x0}))
            if ev.bar is not None:
                ev.bar.set_postfix(best=f"{opt.best_f:.4g}", refresh=False)
            if on_iteration is not None:
                on_iteration(k, stat)
    finally:
        ev.close()
    best = [p.from_internal(v) for p, v in zip(spec.params, opt.best_x, strict=True)]
    res = TuneResult(best_values=best, best_cost=float(opt.best_f), default_values=x0,
                     default_cost=math.nan, history=list(opt.history), iterations=opt.iteration,
                     n_evals=ev.n_new, wall_s=time.perf_counter() - t_start, out_dir=out,
                     n_fallback=ev.n_fallback)
    res.top = top_candidates(spec, ev.cache, spec.validate_top)
    if outputs:
        write_outputs(spec, res, executor, log_stats)
    return res


def _start(spec: TuneSpec, ck_path: Path, ev_path: Path, h: str, x0: list[float],
           resume: bool, fresh: bool) -> tuple[Any, list[dict[str, Any]]]:
    """The optimiser and the iteration log: from the checkpoint (``resume``), or new (with the
    default gains as member 0)."""
    if resume and ck_path.exists():
        try:
            ck = json.loads(ck_path.read_bytes().decode("utf-8"))
            state, its, ck_hash = ck["optimizer"], ck.get("iterations", []), ck.get("spec_hash")
        except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError):
            raise ConfigError(f'--resume: "{ck_path}" is damaged (not a tuning checkpoint); '
                              "use --fresh") from None
        if ck_hash != h:
            raise ConfigError(f'--resume: "{ck_path}" was written for a different spec '
                              "(params, scenarios, optimizer or a field file changed); use "
                              "--fresh")
        return _opt_from_state(state), its
    if fresh:
        for p in (ck_path, ev_path):
            p.unlink(missing_ok=True)
    opt = _make_optimizer(spec)
    if spec.include_default:
        u0 = np.array([p.to_internal(v) for p, v in zip(spec.params, x0, strict=True)])
        lo = np.array([p.bounds[0] for p in spec.params])
        hi = np.array([p.bounds[1] for p in spec.params])
        _set_member(opt, 0, np.clip(u0, lo, hi))
    return opt, []


class _EvalLog:
    """The evaluations of one :func:`run_tune` call: the journal (``evals.jsonl``, a cache of
    finished evaluations), the progress bar, warnings and counters."""

    def __init__(self, path: Path, h: str, spec: TuneSpec, progress: bool, n_iter: int,
                 it0: int, warn: Callable[[str], None] | None) -> None:
        self.h, self.spec, self._warn = h, spec, warn
        self.cache: dict[str, dict[str, Any]] = {}
        self.bar = None
        if progress:
            from ..._progress import progress_bar

            self.bar = progress_bar(total=n_iter * spec.pop, initial=it0 * spec.pop,
                                    unit="eval", desc=f"tune {spec.name}", dynamic_ncols=True,
                                    smoothing=0.05)
        if path.exists():  # finished evaluations (resume: those of the current iteration)
            repair_jsonl(path)
            recs, bad = read_jsonl(path)
            if bad:
                self.warn(f"{path}: skipped {bad} unreadable line(s); those evaluations are "
                          "run again")
            for rec in recs:
                if rec.get("h") == h and isinstance(rec.get("result"), dict):
                    self.cache[_xkey(rec["u"])] = rec["result"]
        self.path = path
        self.f = path.open("a")
        self.n_new = self.n_fallback = 0

    def warn(self, msg: str) -> None:
        if self._warn is not None:
            return self._warn(msg)
        import sys

        line = f"ag-uav: warning: {msg}"
        if self.bar is not None:
            self.bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr)

    def evaluate(self, executor: Executor, U: np.ndarray, k: int
                 ) -> tuple[list[dict[str, Any]], int]:
        """Every member's result (cached ones reused); and how many fell back to one at a time."""
        results: list[dict[str, Any] | None] = [None] * len(U)
        for i, u in enumerate(U):
            results[i] = self.cache.get(_xkey(u))
        todo = [i for i, r in enumerate(results) if r is None]
        if self.bar is not None:
            self.bar.update(len(U) - len(todo))
        n_fb = 0
        for attempt in range(LOST_RETRIES + 1):
            lost: list[int] = []
            tasks = [{"spec": self.spec, "values": [p.from_internal(v) for p, v in
                                                    zip(self.spec.params, U[i], strict=True)]}
                     for i in todo]
            chunks = chunk(tasks, executor.workers)
            for c, rs in executor.map_unordered(
                    evaluate_candidates, [[tasks[j] for j in ch] for ch in chunks],
                    return_exceptions=True):
                if isinstance(rs, BaseException):
                    lost += [todo[j] for j in chunks[c]]
                    last = exception_line(rs)
                    continue
                n_fb += self._record(k, U, [todo[j] for j in chunks[c]], rs, results)
            if not lost:
                return results, n_fb  # type: ignore[return-value]
            self.warn(f"iteration {k}: {len(lost)} evaluations lost to the machinery ({last})"
                      + ("; resubmitting" if attempt < LOST_RETRIES else ""))
            todo = lost
        raise TuneStopped(f"tune {self.spec.name}: {len(todo)} evaluations of iteration {k} lost "
                          f"to the machinery {LOST_RETRIES + 1} times ({last}); the checkpoint "
                          f"of iteration {k - 1} is kept, --resume continues")

    def _record(self, k: int, U: np.ndarray, idx: list[int], rs: list[dict[str, Any]],
                results: list[dict[str, Any] | None]) -> int:
        fb = next((r["engine_fallback"] for r in rs if r.get("engine_fallback")), "")
        if fb:
            self.warn(f"iteration {k}: an engine batch of {len(rs)} candidates failed ({fb}); "
                      "evaluated one at a time")
            self.n_fallback += len(rs)
        for i, r in zip(idx, rs, strict=True):
            results[i] = r
            self.cache[_xkey(U[i])] = r
            try:
                self.f.write(json.dumps({"h": self.h, "iter": k, "i": i, "u": U[i].tolist(),
                                         "result": r}) + "\n")
                self.f.flush()
                os.fsync(self.f.fileno())
            except OSError as e:
                raise OSError(e.errno, e.strerror or str(e), str(self.path)) from None
            self.n_new += 1
            if self.bar is not None:
                self.bar.update(1)
        return len(rs) if fb else 0

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.f.close()
        if self.bar is not None:
            self.bar.close()
