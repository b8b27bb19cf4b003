"""The traffic survey of SUMO runs: what `jaxround measure` writes as targets.

Per leg and per 10-minute slot (`jaxround.analysis.survey` has the definitions): mean
and largest queue, upstream and downstream flow, averaged over the seeds'
schedules, with the human drivers' numbers of the scenario given.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from jaxround.analysis.survey import (
    CALIBRATABLE,
    SLOT_S,
    Survey,
    slot_flows,
    slot_queues,
)
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import Schedule, make_schedule
from sumo_export.runner import SumoRun, run_many


def run_survey(
    cfg: ScenarioConfig,
    run: SumoRun,
    schedule: Schedule,
    n_slots: int,
    slot_s: float = SLOT_S,
) -> dict[str, np.ndarray]:
    """One SUMO run's survey tables, each float (n_slots, n_legs)."""
    g = cfg.n_legs
    per_slot = int(round(slot_s / cfg.simulation.dt_s))
    queues = np.zeros((n_slots * per_slot, g))
    samples = np.asarray(run.queues if run.queues is not None else queues)
    n = min(len(samples), len(queues))
    queues[:n] = samples[:n]  # an empty network after the last vehicle: 0
    q_mean, q_max = slot_queues(queues, per_slot)
    rec = run.records
    return {
        "queue_mean_veh": q_mean,
        "queue_max_veh": q_max,
        "upstream_veh_h": slot_flows(rec.depart_s, rec.origin, g, n_slots, slot_s),
        "downstream_veh_h": slot_flows(
            rec.arrival_s, schedule.destination, g, n_slots, slot_s
        ),
    }


def sumo_survey(
    cfg: ScenarioConfig,
    seeds: Sequence[int],
    n_slots: int,
    slot_s: float = SLOT_S,
    workers: int | None = None,
    progress: Callable[[SumoRun], None] | None = None,
) -> Survey:
    """Run the scenario's HV-only schedules of `seeds` in SUMO and survey them."""
    schedules = [make_schedule(cfg, seed=s, penetration=0.0) for s in seeds]
    runs = run_many(cfg, schedules, workers=workers, progress=progress)
    tables: dict[str, list[np.ndarray]] = {}
    for sched, run in zip(schedules, runs, strict=True):
        one = run_survey(cfg, run, sched, n_slots, slot_s)
        for k, v in one.items():
            tables.setdefault(k, []).append(v)
    hv = cfg.drivers.hv
    return Survey(
        scenario=cfg.name,
        legs=tuple(leg.name for leg in cfg.network.legs),
        slot_s=slot_s,
        seeds=tuple(int(s) for s in seeds),
        drivers={k: float(getattr(hv, k)) for k in CALIBRATABLE},
        source="sumo",
        **{k: np.mean(v, axis=0) for k, v in tables.items()},
    )
