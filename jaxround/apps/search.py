"""The best constant AV setting, and what a state-dependent controller adds.

`run_search` does one case (a scenario, a share of AVs, a demand):

1. CMA-ES (`jaxround.analysis.cmaes`) over constant settings (the AV vType's
   tau, impatience, accel, jmTimegapMinor and a ``cruise:V`` speed;
   `jaxround.analysis.setting_search`), each generation's population scored
   on the search seeds in one compiled JAX program;
   then a line search over tau, the number that decides the conflicts
   (`refine_tau`);
2. CMA-ES over the parameters of the state-dependent controller
   (`jaxround.analysis.state_controller`), started at the best constant;
3. a final check on held-out evaluation seeds: the AV vType uncontrolled,
   the best constant and the controller, per-seed objective, and the paired
   differences of constant vs vType and controller vs constant with 95%
   t-intervals over the seeds (as `jaxround.analysis.compare`'s);
4. optionally the vType and the best constant again in SUMO on the same
   evaluation seeds (a declared vType and ``cruise:V``, as the headroom
   study's variants), paired as `compare.paired_difference` pairs them.

It also gives the front of crossing time against CO2 of every constant
scored. Seeds: search seeds are 200 and above, evaluation seeds 100 and
above; training draws its schedules in JAX.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxround.analysis.cmaes import SearchTrace, minimise
from jaxround.analysis.compare import mean_ci, paired_difference
from jaxround.analysis.setting_search import (
    SPACE,
    Objective,
    SearchProblem,
    bounds,
    describe,
    from_unit,
    vtype_setting,
)
from jaxround.analysis.state_controller import (
    ablations,
    score_controllers,
    start_of,
)
from jaxround.scenario.config import ScenarioConfig

#: Added to the objective per vehicle that had not left at the step limit.
MISSING_PENALTY = 1000.0
#: Added to the objective per conflict per 1,000 vehicles above the limit
#: of the constraint form (about 0.1 s of every vehicle's crossing each).
CONFLICT_PENALTY = 5.0


@dataclasses.dataclass(frozen=True)
class SearchBudget:
    """How much a case searches.

    Attributes:
        population: CMA-ES population per generation.
        generations: generations of the constant search.
        state_generations: generations of the controller's search.
        std: CMA-ES initial step (unit cube of the settings; raw theta).
    """

    population: int = 12
    generations: int = 8
    state_generations: int = 8
    std: float = 0.25


def fitness_of(
    scores: dict[str, np.ndarray], conflict_limit: float | None = None
) -> np.ndarray:
    """float (K,): mean objective over the seeds, missing vehicles penalised,
    and with a `conflict_limit` (per 1,000 vehicles, mean over the seeds)
    each conflict per 1,000 vehicles above it too."""
    fitness = scores["objective"].mean(1) + MISSING_PENALTY * scores["missing"].sum(1)
    if conflict_limit is None:
        return fitness
    excess = np.maximum(scores["conflicts_per_1000"].mean(1) - conflict_limit, 0.0)
    return fitness + CONFLICT_PENALTY * excess


def pareto_front(time_s: np.ndarray, co2_g: np.ndarray) -> np.ndarray:
    """Indices of the points no other point beats in both, by time, int (F,)."""
    order = np.lexsort((co2_g, time_s))
    front, best_co2 = [], np.inf
    for i in order:
        if co2_g[i] < best_co2:
            front.append(int(i))
            best_co2 = co2_g[i]
    return np.asarray(front, int)


def search_constants(
    problem: SearchProblem,
    budget: SearchBudget,
    seed: int = 0,
    conflict_limit: float | None = None,
) -> tuple[SearchTrace, dict[str, np.ndarray]]:
    """CMA-ES over constant settings from the middle of the box (tau from the
    time-gap floor up); the trace (in the unit cube) and the scores (K, S) of
    every point scored."""
    kept: list[dict[str, np.ndarray]] = []

    def fitness(unit: np.ndarray) -> np.ndarray:
        scores = problem.score_settings(np.asarray(from_unit(unit, problem.min_tau)))
        kept.append(scores)
        return fitness_of(scores, conflict_limit)

    trace = minimise(
        fitness, np.full(len(SPACE), 0.5, np.float32), budget.std,
        budget.population, budget.generations, seed, desc="constants",
    )  # fmt: skip
    return trace, {k: np.concatenate([s[k] for s in kept]) for k in kept[0]}


def search_controller(
    problem: SearchProblem,
    setting: np.ndarray,
    budget: SearchBudget,
    seed: int = 0,
    conflict_limit: float | None = None,
) -> SearchTrace:
    """CMA-ES over the state-dependent controller, from the constant `setting`."""

    def fitness(thetas: np.ndarray) -> np.ndarray:
        return fitness_of(score_controllers(problem, setting, thetas), conflict_limit)

    return minimise(
        fitness, start_of(setting, problem.min_tau), budget.std, budget.population,
        budget.state_generations, seed, desc="state controller",
    )  # fmt: skip


#: Steps of the line search over tau around the best constant, s.
TAU_LINE = np.arange(-0.2, 0.2001, 0.025)


def refine_tau(
    problem: SearchProblem, setting: np.ndarray, conflict_limit: float | None
) -> np.ndarray:
    """The best constant after a line search over its tau (`TAU_LINE` around
    it, inside the box), its other numbers held: the time gap decides the
    conflicts, so the constraint's boundary is found along it more finely
    than CMA-ES's few generations find it. Returns the better setting (D,)."""
    low, high = bounds(problem.min_tau)["tau"]
    taus = np.unique(np.clip(setting[0] + TAU_LINE, low, high))
    line = np.repeat(setting[None], len(taus), 0)
    line[:, 0] = taus
    fitness = fitness_of(problem.score_settings(line), conflict_limit)
    return line[int(np.argmin(fitness))].astype(np.float32)


def paired_objective(policy: np.ndarray, baseline: np.ndarray) -> dict[str, Any]:
    """Policy minus baseline of per-seed objectives (S,), with the 95%
    t-interval over seeds, absolute and relative to the baseline (None
    relative to a baseline of 0, e.g. no conflicts)."""
    diff = np.asarray(policy, np.float64) - np.asarray(baseline, np.float64)
    base = float(np.mean(baseline))
    ci = mean_ci(diff)
    relative = ci is not None and base != 0
    return {
        "baseline": base,
        "policy": float(np.mean(policy)),
        "diff": float(diff.mean()),
        "rel_diff": float(diff.mean()) / base if base else None,
        "ci95_seeds": None if ci is None else [ci[1], ci[2]],
        "rel_ci95_seeds": [ci[1] / base, ci[2] / base] if relative else None,
        "per_seed_diff": diff.tolist(),
    }


def _means(scores: dict[str, np.ndarray], row: int) -> dict[str, float]:
    means = ("objective", "time_s", "co2_g", "exit_time_s", "exit_co2_g",
             "conflicts_per_1000")  # fmt: skip
    return {k: float(np.mean(scores[k][row])) for k in means} | {
        k: int(scores[k][row].sum()) for k in ("missing", "overflow")
    }


def run_search(
    cfg: ScenarioConfig,
    penetration: float,
    search_seeds: Sequence[int],
    eval_seeds: Sequence[int],
    budget: SearchBudget = SearchBudget(),
    objective: Objective = Objective(),
    max_vehicles: int | str | None = None,
    conflict_limit: str | float | None = None,
) -> dict[str, Any]:
    """One case, steps 1-3 of the module docstring; a JSON-able dict.

    `conflict_limit`: the constraint form, conflicts per 1,000 vehicles no
    more than this (mean over the search seeds); ``"vtype"``: no more than
    the AVs' own vType uncontrolled on those seeds; None: no constraint.
    """
    t0 = time.perf_counter()
    # one compiled program per controller kind serves every batch and seed
    # count below (the final check's in blocks of the search's shape)
    search = SearchProblem(
        cfg, penetration, search_seeds, objective, max_vehicles,
        rows=budget.population,
    )  # fmt: skip
    vtype = vtype_setting(cfg)
    if conflict_limit == "vtype":
        own = search.score_settings(vtype[None])
        conflict_limit = float(own["conflicts_per_1000"].mean())
    elif conflict_limit is not None:
        conflict_limit = float(conflict_limit)
    trace, scored = search_constants(search, budget, conflict_limit=conflict_limit)
    best = refine_tau(
        search, np.asarray(from_unit(trace.best, search.min_tau)), conflict_limit
    )
    t_constant = time.perf_counter() - t0
    state_trace = search_controller(search, best, budget, conflict_limit=conflict_limit)
    t_state = time.perf_counter() - t0 - t_constant

    check = search.with_seeds(eval_seeds)
    constants = check.score_settings(np.stack([vtype, best]))
    parts = ablations(state_trace.best)
    state = score_controllers(check, best, np.stack(list(parts.values())))
    obj = {
        "vtype": constants["objective"][0],
        "constant": constants["objective"][1],
        "state": state["objective"][0],
    }
    settings = np.asarray(from_unit(trace.points, search.min_tau))
    conflicts = {
        "vtype": constants["conflicts_per_1000"][0],
        "constant": constants["conflicts_per_1000"][1],
        "state": state["conflicts_per_1000"][0],
    }
    front = pareto_front(scored["time_s"].mean(1), scored["co2_g"].mean(1))
    return {
        "scenario": cfg.name,
        "penetration": penetration,
        "n_vehicles": cfg.demand.n_vehicles,
        "window_s": cfg.demand.duration_s,
        "origin_share": list(cfg.demand.origin_share),
        "objective": dataclasses.asdict(objective),
        "min_av_tau_s": search.min_tau,
        "conflict_limit_per_1000": conflict_limit,
        "budget": dataclasses.asdict(budget),
        "search_seeds": list(search_seeds),
        "eval_seeds": list(eval_seeds),
        "max_vehicles": search.env.max_vehicles,
        "wall_s": {"constant_search": t_constant, "state_search": t_state,
                   "total": time.perf_counter() - t0},
        "best_constant": describe(best),
        "best_constant_search_objective": trace.best_fitness,
        "state_theta": state_trace.best.tolist(),
        "state_search_objective": state_trace.best_fitness,
        "generations": {"constant": trace.generations,
                        "state": state_trace.generations},
        "eval": {
            "vtype": _means(constants, 0),
            "constant": _means(constants, 1),
            "state": _means(state, 0),
        },
        "constant_vs_vtype": paired_objective(obj["constant"], obj["vtype"]),
        "state_vs_constant": paired_objective(obj["state"], obj["constant"]),
        # conflicts per 1,000 vehicles, paired over the evaluation seeds
        "conflicts": {
            "constant_vs_vtype": paired_objective(
                conflicts["constant"], conflicts["vtype"]
            ),
            "state_vs_constant": paired_objective(
                conflicts["state"], conflicts["constant"]
            ),
        },
        # which numbers' state dependence the controller's gain comes from
        "state_parts": {
            name: {
                **_means(state, i),
                "vs_constant": paired_objective(
                    state["objective"][i], obj["constant"]
                ),
            }
            for i, name in enumerate(parts)
        },
        "scored": {
            "settings": settings.tolist(),
            "time_s": scored["time_s"].mean(1).tolist(),
            "co2_g": scored["co2_g"].mean(1).tolist(),
            "objective": scored["objective"].mean(1).tolist(),
            "conflicts_per_1000": scored["conflicts_per_1000"].mean(1).tolist(),
        },
        "front": front.tolist(),
        "search_missing": int(scored["missing"].sum()),
        "search_overflow": int(scored["overflow"].sum()),
    }  # fmt: skip


def sumo_recheck(
    cfg: ScenarioConfig,
    penetration: float,
    eval_seeds: Sequence[int],
    best: dict[str, float | None],
    objective: Objective = Objective(),
    workers: int | None = None,
) -> dict[str, Any]:
    """Step 4: the vType and the best constant in SUMO on the evaluation
    seeds; the paired differences of time and CO2 (`paired_difference`) and
    of the objective."""
    from jaxround.apps.headroom import Variant, variant_config
    from jaxround.scenario.schedule import make_schedule
    from sumo_export.runner import run_many
    from sumo_export.scripted import ScriptedControllerFactory

    cruise = best.get("cruise_mps")
    own = tuple((k, float(v)) for k, v in best.items() if k != "cruise_mps")
    spec = None if cruise is None else f"cruise:{cruise:.4g}"
    scheds = [make_schedule(cfg, seed=s, penetration=penetration) for s in eval_seeds]
    runs = {}
    for label, variant in (("vtype", Variant("vtype")), ("constant", Variant(
            "constant", own, spec))):  # fmt: skip
        factory = ScriptedControllerFactory(spec) if variant.controller else None
        runs[label] = [
            r.records
            for r in run_many(
                variant_config(cfg, variant), scheds, workers=workers,
                controller=factory,
            )
        ]  # fmt: skip

    def per_seed(records: list[Any]) -> np.ndarray:
        return np.array([
            objective(np.nanmean(r.crossing_time_s[r.arrived]),
                      np.nanmean(r.co2_g[r.arrived]))
            for r in records
        ])  # fmt: skip

    return {
        "controller": spec,
        "vtype_numbers": dict(own),
        "paired": paired_difference(runs["constant"], runs["vtype"]),
        "objective": paired_objective(per_seed(runs["constant"]),
                                      per_seed(runs["vtype"])),
        "arrived": {k: [int(r.arrived.sum()) for r in v] for k, v in runs.items()},
        "conflicts_per_1000": {
            k: [float(r.conflicts.sum() * 1000.0 / len(r.conflicts)) for r in v]
            for k, v in runs.items()
        },
    }  # fmt: skip


def front_table(result: dict[str, Any]) -> str:
    """The time-CO2 front of the constants scored, a Markdown table."""
    s = result["scored"]
    lines = ["| time s | CO2 g | objective | " + " | ".join(SPACE) + " |",
             "|---" * (3 + len(SPACE)) + "|"]  # fmt: skip
    for i in result["front"]:
        numbers = describe(s["settings"][i])
        cells = ["none" if v is None else f"{v:.3g}" for v in numbers.values()]
        lines.append(
            f"| {s['time_s'][i]:.2f} | {s['co2_g'][i]:.2f} | "
            f"{s['objective'][i]:.2f} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines)


def summary(result: dict[str, Any]) -> str:
    """Best constant, controller, paired differences: a few lines."""
    ev, cv = result["eval"], result["constant_vs_vtype"]
    sv, wall = result["state_vs_constant"], result["wall_s"]

    def pct(d: dict[str, Any]) -> str:
        lo, hi = d["rel_ci95_seeds"] or (float("nan"), float("nan"))
        return f"{100 * d['rel_diff']:+.2f}% [{100 * lo:+.2f}, {100 * hi:+.2f}]"

    warn = ""
    if result["search_overflow"] or any(e["overflow"] for e in ev.values()):
        warn = "\nwarning: slots overflowed; pass a larger --max-vehicles"
    return "\n".join([
        f"best constant: {result['best_constant']}",
        f"eval objective (seeds {result['eval_seeds'][0]}..): vType "
        f"{ev['vtype']['objective']:.3f}, constant {ev['constant']['objective']:.3f}, "
        f"state controller {ev['state']['objective']:.3f}",
        f"constant vs vType: {pct(cv)}; state controller vs constant: {pct(sv)}",
        "conflicts per 1,000 veh (eval): " + ", ".join(
            f"{k} {e['conflicts_per_1000']:.1f}" for k, e in ev.items()
        ) + (f"; limit {limit:.1f}" if (limit := result.get(
            "conflict_limit_per_1000")) is not None else ""),
        "state dependence of one number only, vs constant: " + ", ".join(
            f"{k} {pct(v['vs_constant'])}" for k, v in result["state_parts"].items()
            if k != "full"
        ),
        "owed at exit (time s / CO2 g): " + ", ".join(
            f"{k} {e['exit_time_s']:.2f} / {e['exit_co2_g']:.2f}" for k, e in ev.items()
        ),
        f"wall: constants {wall['constant_search']:.0f} s, controller "
        f"{wall['state_search']:.0f} s, total {wall['total']:.0f} s",
    ]) + warn  # fmt: skip
