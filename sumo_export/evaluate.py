"""Run a scenario in SUMO over several seeds and penetrations and summarise it."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from tqdm.auto import tqdm

from jaxround.config import ScenarioConfig
from jaxround.metrics import class_metrics, mean_over_runs
from jaxround.schedule import make_schedule
from sumo_export.runner import SumoRun, run_many

SAFETY_KEYS = ("collisions", "emergency_brakings", "teleports")


def summarise_runs(cfg: ScenarioConfig, runs: Sequence[SumoRun]) -> dict[str, Any]:
    """The `jaxround sumo` JSON of several runs of one penetration.

    Returns:
        ``{"per_seed": [...], "mean": {"all": M, "hv": M, "av": M,
        "collisions": n, "emergency_brakings": n, "teleports": n}}``; the three
        counters in "mean" are totals over the seeds.
    """
    per_seed = []
    for run in runs:
        entry = class_metrics(run.records, cfg.demand.duration_s)
        entry.update({k: getattr(run, k) for k in SAFETY_KEYS})
        entry["sim_end_s"] = run.sim_end_s
        per_seed.append(entry)
    classes = mean_over_runs([{k: e[k] for k in ("all", "hv", "av")} for e in per_seed])
    mean = dict(classes)
    for key in SAFETY_KEYS:
        mean[key] = int(sum(e[key] for e in per_seed))
    return {"per_seed": per_seed, "mean": mean}


def sumo_sweep(
    cfg: ScenarioConfig,
    penetrations: Sequence[float],
    seeds: Sequence[int],
    workers: int | None = None,
    show_progress: bool = True,
) -> dict[float, dict[str, Any]]:
    """Run every (penetration, seed) schedule in SUMO, several processes at once.

    Returns:
        ``{penetration: summarise_runs(...)}`` in the order given.
    """
    jobs = [(p, s) for p in penetrations for s in seeds]
    base = {s: make_schedule(cfg, seed=s, penetration=0.0) for s in seeds}
    schedules = [base[s].with_penetration(p) for p, s in jobs]
    bar = tqdm(total=len(jobs), desc="SUMO runs", unit="run", disable=not show_progress)
    runs = run_many(cfg, schedules, workers=workers, progress=lambda _: bar.update())
    bar.close()
    out: dict[float, dict[str, Any]] = {}
    for p in penetrations:
        mine = [r for (pj, _), r in zip(jobs, runs, strict=True) if pj == p]
        out[p] = summarise_runs(cfg, mine)
    return out
