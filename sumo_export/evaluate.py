"""Run a scenario in SUMO over several seeds and penetrations and summarise it.

`sumo_sweep` leaves the AVs to their SUMO vType; `sumo_policy_sweep` drives
them with an exported policy (`sumo_export.controller`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from jaxround.analysis.metrics import (
    SCORE_SCALES,
    ScoreScale,
    arrived_in_all,
    class_metrics,
    mean_over_runs,
    sweep_scale,
)
from jaxround.scenario.config import DRAIN_S, ScenarioConfig
from jaxround.scenario.schedule import make_schedule
from sumo_export.controller import PHASES, PolicyControllerFactory, policy_observer
from sumo_export.runner import ControllerFactory, SumoRun, run_many
from sumo_export.traffic import DEFAULT_SLOTS

SAFETY_KEYS = ("collisions", "emergency_brakings", "teleports")


def summarise_runs(
    cfg: ScenarioConfig,
    runs: Sequence[SumoRun],
    *,
    compared: Sequence[np.ndarray] | None = None,
    scale: ScoreScale | None = None,
) -> dict[str, Any]:
    """The `jaxround sumo` JSON of several runs of one penetration.

    Args:
        cfg: the scenario.
        runs: one per seed.
        compared: per run, bool (N,) the vehicles its means are over (those
            arrived in every run compared, `compare_drivers`); None: each
            run's own arrivals.
        scale: Eq. 5's bounds (`jaxround.analysis.metrics.sweep_scale`); None:
            each run's own ("score_scale" says which).

    Returns:
        ``{"per_seed": [...], "mean": {"all": M, "hv": M, "av": M,
        "collisions": n, "emergency_brakings": n, "teleports": n,
        "score_scale": "sweep" | "joint" | "run", "not_arrived": n}}``; the counters
        in "mean" are totals over the seeds.
    """
    per_seed = []
    for i, run in enumerate(runs):
        entry = class_metrics(
            run.records, cfg.demand.duration_s,
            compared=None if compared is None else compared[i], scale=scale,
        )  # fmt: skip
        entry.update({k: getattr(run, k) for k in SAFETY_KEYS})
        entry["sim_end_s"] = run.sim_end_s
        entry["wall_s"] = run.wall_s
        if run.controller_report is not None:
            entry["controller"] = controller_summary([run.controller_report])
        per_seed.append(entry)
    classes = mean_over_runs([{k: e[k] for k in ("all", "hv", "av")} for e in per_seed])
    mean = dict(classes)
    for key in SAFETY_KEYS:
        mean[key] = int(sum(e[key] for e in per_seed))
    mean["not_arrived"] = int(sum(e["all"]["n_not_arrived"] for e in per_seed))
    mean["score_scale"] = "run" if scale is None else scale.over
    reports = [r.controller_report for r in runs if r.controller_report is not None]
    if reports:
        mean["controller"] = controller_summary(reports)
    return {"per_seed": per_seed, "mean": mean}


def compare_drivers(
    cfg: ScenarioConfig,
    runs: dict[str, dict[float, list[SumoRun]]],
    score_scale: str | ScoreScale = "sweep",
) -> dict[str, dict[float, dict[str, Any]]]:
    """`summarise_runs` of several drivers on the same schedules, compared over
    the same vehicles: each (penetration, seed)'s means are over the vehicles
    that arrived in the run of every driver.

    Args:
        runs: ``{driver: {penetration: [SumoRun per seed]}}``, the same
            penetrations and seeds for every driver.
        score_scale: "sweep" (Eq. 5 over every run given), "run", or the
            bounds themselves (e.g. over JAX's runs and these together).

    Returns:
        ``{driver: {penetration: summarise_runs(...)}}``.

    Raises:
        ValueError: an unknown `score_scale`.
    """
    if not isinstance(score_scale, ScoreScale) and score_scale not in SCORE_SCALES:
        raise ValueError(f"score_scale {score_scale!r}, expected one of {SCORE_SCALES}")
    drivers = list(runs)
    first = runs[drivers[0]]
    compared = {
        p: [
            arrived_in_all(runs[d][p][i].records for d in drivers)
            for i in range(len(first[p]))
        ]
        for p in first
    }
    every = [r.records for by_p in runs.values() for rs in by_p.values() for r in rs]
    if isinstance(score_scale, ScoreScale):
        scale: ScoreScale | None = score_scale
    else:
        scale = sweep_scale(every) if score_scale == "sweep" else None
    return {
        d: {
            p: summarise_runs(cfg, rs, compared=compared[p], scale=scale)
            for p, rs in by_p.items()
        }
        for d, by_p in runs.items()
    }


def controller_summary(reports: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The controller's time per SUMO step over the steps of several runs.

    Args:
        reports: `PolicyController.report()` of each run.

    Returns:
        ``{"steps": n, "median_ms": x, "p99_ms": x, "mean_ms": x,
        "phases_median_ms": {phase: x}, "phases_p99_ms": {phase: x},
        "overflow_vehicle_steps": n, "commands": n, "lane_requests": n,
        "lane_requests_withheld": n}``; times are of the whole controller
        call (read, observe, policy, command) and pooled over the runs'
        steps; the counts are totals.
    """
    total = np.concatenate([np.asarray(r["step_ms"]["total"]) for r in reports])
    empty = total.size == 0
    phases = {
        k: np.concatenate([np.asarray(r["step_ms"][k]) for r in reports])
        for k in PHASES
    }
    return {
        "steps": int(total.size),
        "median_ms": None if empty else float(np.median(total)),
        "p99_ms": None if empty else float(np.percentile(total, 99)),
        "mean_ms": None if empty else float(total.mean()),
        "phases_median_ms": {
            k: None if empty else float(np.median(v)) for k, v in phases.items()
        },
        "phases_p99_ms": {
            k: None if empty else float(np.percentile(v, 99)) for k, v in phases.items()
        },
        **{
            key: int(sum(r[key] for r in reports))
            for key in (
                "overflow_vehicle_steps",
                "commands",
                "lane_requests",
                "lane_requests_withheld",
            )
        },
    }


def sumo_runs(
    cfg: ScenarioConfig,
    penetrations: Sequence[float],
    seeds: Sequence[int],
    workers: int | None = None,
    show_progress: bool = True,
    controller: ControllerFactory | None = None,
    desc: str = "SUMO runs",
    drain_s: float = DRAIN_S,
) -> dict[float, list[SumoRun]]:
    """Run every (penetration, seed) schedule in SUMO, several processes at once.

    Args:
        cfg: the scenario.
        penetrations: AV shares.
        seeds: schedule seeds (`jaxround.scenario.schedule.make_schedule`).
        workers: SUMO processes side by side; defaults to the CPUs.
        show_progress: a progress bar on stderr.
        controller: drives the AVs of every run (built in each worker, see
            `sumo_export.runner.run_many`); None leaves them to their vType.
        desc: the progress bar's label.
        drain_s: seconds after the demand horizon a run may go on.

    Returns:
        ``{penetration: [SumoRun per seed]}`` in the order given.
    """
    jobs = [(p, s) for p in penetrations for s in seeds]
    base = {s: make_schedule(cfg, seed=s, penetration=0.0) for s in seeds}
    schedules = [base[s].with_penetration(p) for p, s in jobs]
    bar = tqdm(total=len(jobs), desc=desc, unit="run", disable=not show_progress)
    runs = run_many(
        cfg, schedules, workers=workers, progress=lambda _: bar.update(),
        controller=controller, drain_s=drain_s,
    )  # fmt: skip
    bar.close()
    return {
        p: [r for (pj, _), r in zip(jobs, runs, strict=True) if pj == p]
        for p in penetrations
    }


def sumo_sweep(
    cfg: ScenarioConfig,
    penetrations: Sequence[float],
    seeds: Sequence[int],
    workers: int | None = None,
    show_progress: bool = True,
    controller: ControllerFactory | None = None,
    score_scale: str = "sweep",
) -> dict[float, dict[str, Any]]:
    """`sumo_runs`, summarised: ``{penetration: summarise_runs(...)}``, Eq. 5
    on one scale over the sweep ("sweep") or each run's own ("run")."""
    runs = sumo_runs(cfg, penetrations, seeds, workers, show_progress, controller)
    return compare_drivers(cfg, {"only": runs}, score_scale)["only"]


def policy_controller(
    cfg: ScenarioConfig,
    policy_path: str | Path,
    max_slots: int | str | None = DEFAULT_SLOTS,
) -> PolicyControllerFactory:
    """The controller factory of an exported policy, checked before any run.

    Raises:
        FileNotFoundError, ValueError: as `policy_observer`, or the policy was
            trained on other roads or drivers.
    """
    from agents.common.export import check_scenario, load_policy

    policy_observer(policy_path)  # fail here rather than in every worker
    check_scenario(load_policy(policy_path)[1], cfg)
    return PolicyControllerFactory(str(policy_path), max_slots)


def sumo_policy_sweep(
    cfg: ScenarioConfig,
    policy_path: str | Path,
    penetrations: Sequence[float],
    seeds: Sequence[int],
    workers: int | None = None,
    show_progress: bool = True,
    max_slots: int | str | None = DEFAULT_SLOTS,
) -> dict[float, dict[str, Any]]:
    """`sumo_sweep` with the AVs driven by an exported policy.

    Every run builds a `sumo_export.controller.PolicyController` in its
    worker process; collisions are checked on the junctions as in every run.

    Returns:
        ``{penetration: summarise_runs(...)}``: "mean" holds the class
        metrics (`jaxround.analysis.metrics.class_metrics`, mean over seeds), the
        safety counters (totals) and "controller" (`controller_summary`).

    Raises:
        FileNotFoundError, ValueError: as `policy_controller`; before any run.
    """
    factory = policy_controller(cfg, policy_path, max_slots)
    return sumo_sweep(
        cfg, penetrations, seeds, workers=workers, show_progress=show_progress,
        controller=factory,
    )  # fmt: skip


def controller_overhead(
    cfg: ScenarioConfig,
    policy_path: str | Path,
    penetration: float = 1.0,
    seed: int = 0,
    max_slots: int | str | None = DEFAULT_SLOTS,
) -> dict[str, Any]:
    """What the controller costs: one schedule run without it, then with it.

    The two runs go one after the other, each in a fresh worker process.
    With the policy driving, the traffic (and so the number of steps) can
    differ from the run without it.

    Returns:
        ``{"penetration", "seed", "without": R, "with": R, "controller":
        controller_summary(...)}``, R = ``{"wall_s", "steps", "sim_end_s",
        "n_arrived", "collisions"}`` (wall_s: the simulation loop, the
        controller included).
    """
    policy_observer(policy_path)
    schedule = make_schedule(cfg, seed=seed, penetration=penetration)
    factory = PolicyControllerFactory(str(policy_path), max_slots)
    (plain,) = run_many(cfg, [schedule], workers=1)
    (driven,) = run_many(cfg, [schedule], workers=1, controller=factory)

    def brief(run: SumoRun) -> dict[str, Any]:
        return {
            "wall_s": run.wall_s,
            "steps": round(run.sim_end_s / cfg.simulation.dt_s),
            "sim_end_s": run.sim_end_s,
            "n_arrived": int(run.records.arrived.sum()),
            "collisions": run.collisions,
        }

    return {
        "penetration": penetration,
        "seed": seed,
        "without": brief(plain),
        "with": brief(driven),
        "controller": controller_summary([driven.controller_report]),
    }
