"""Controller tuning: BB-BC (or PSO, or CMA-ES) over IT2-FPID gains on simulated scenarios.

``ag-uav tune SPEC.toml`` (see ``examples/tune.toml``) minimises

    J(x) = Σ_s w_s · J_s(x)

over a box of config keys (``[params]``, e.g. ``"controller.xy.ke" = {lo = 0.1, hi = 10,
log = true}``: ``log`` searches log10 of the value). Each scenario ``s`` is flown with the
candidate's gains and the *same* run seeds for every candidate (common random numbers):
``noise_seed`` (one) or ``noise_seeds = [..]`` (several; ``J_s`` is the mean over them, so that
the tuning does not fit one wind and GNSS draw):

- ``kind = "step"``: hover at 3 m, step of ``size`` m on ``axis`` (x, y or z) at ``t_step``
  (:func:`ag_uav.engine.scenarios.step_response`); error e(t) = p_ref − p over the 3 axes after the
  step;
- ``kind = "mission"``: the base config's mission, cut at ``max_time_s`` of sim time (take-off and
  the first leg(s)); error e(t) = p_ref − p_true over every tick.

with ``J_s = ∫|e|² dt`` (ISE), ``∫ (t − t0)|e| dt`` (ITAE) or 0 (``metric = "none"``), plus
``effort_weight · Σ|Δf|²`` (rotor-thrust increments, N²) and, for mission scenarios, the dose on
the ground: ``[dose_weights]`` (e.g. ``dose_cv = 1.0, underdosed_fraction = 2.0``) adds
``Σ_k w_k · m_k`` over the mission's dose metrics (:data:`ag_uav.engine.missions.DOSE_KEYS`, the
names of its summary; a metric that is undefined, nothing having landed on the field, counts
as 1). A crash (or a non-finite cost) costs
``crash_penalty · (2 − t_crash / duration)`` — finite, and worse the earlier it happens — and
every scenario cost is capped at ``crash_penalty``.

Population members are evaluated in parallel on the :mod:`~ag_uav.jobs.executor` seam. After every
iteration the optimiser state is checkpointed atomically (``checkpoint.json``); every evaluation is
also appended to ``evals.jsonl`` (flushed per line), so ``--resume`` continues exactly where a
killed run stopped — finished iterations and finished evaluations of the current one are not
re-run, and the result equals an uninterrupted run (the optimiser RNG state is checkpointed; the
cost is deterministic). The configured default gains are put in the initial population (member 0)
so the tuned cost can never be worse than the default's.

Held-out validation (``validation_seeds = [..]``, disjoint from the tuning seeds, checked):
after the optimisation the ``validate_top`` (3) distinct candidates of lowest tuning cost (from
the evaluation journal) are flown on the validation seeds with the same scenarios and cost; the
one of lowest validation cost is shipped, and its validation cost is reported beside its tuning
cost (printed, ``before_after.md``, ``tune.json``: ``validation``, ``shipped_*``).

Outputs in ``--out``: ``best_gains.toml`` (a config fragment ``[controller.xy] ke = ...`` that
``fly --config`` and batch presets accept), ``convergence.png``, ``before_after.md`` (default vs
tuned on the same scenarios, also printed) and ``tune.json``.
"""

from .cost import (
    candidate_config,
    evaluate_candidate,
    evaluate_candidates,
    mission_trajectories,
    mission_trajectory,
    scenario_cost,
    scenario_costs,
)
from .outputs import TuneResult, gains_toml, top_candidates, validate, write_outputs
from .search import LOST_RETRIES, TuneStopped, default_values, run_tune
from .spec import MAX_POP, Param, Scenario, TuneSpec, check_pop, load_spec, spec_from_dict

__all__ = ["Param", "Scenario", "TuneSpec", "TuneResult", "load_spec", "spec_from_dict",
           "run_tune", "evaluate_candidate", "scenario_cost", "candidate_config", "gains_toml",
           "default_values", "TuneStopped", "LOST_RETRIES", "top_candidates", "validate",
           "check_pop", "MAX_POP", "mission_trajectory", "mission_trajectories",
           "scenario_costs", "evaluate_candidates", "write_outputs"]
