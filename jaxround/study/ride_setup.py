"""What SUMO runs for a ride: its spec, the schedule with the ego in it, the
scenario as SUMO steps it and the command line (`jaxround.study.sim` runs it).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxround.scenario.config import DriversConfig, ScenarioConfig
from jaxround.scenario.schedule import Schedule, make_schedule

#: The ego's speedFactor: it enters at 60% of the leg's limit (departSpeed max).
EGO_SPEED_FACTOR = 0.6


@dataclass(frozen=True)
class RideSpec:
    """What a ride process needs (picklable).

    Attributes:
        ride_id: the ride's id.
        config: the scenario (YAML path or built-in name).
        share: the AVs' share of the background traffic; None for the
            practice ride (no traffic).
        policy: who drives the AVs (`jaxround.apps.drivers`: a policy file,
            a scripted controller or ``uncontrolled``; None in practice).
        seed: the schedule's seed.
        warmup_s: simulated seconds before the ego enters.
        ride_s: longest ride, seconds of driving.
        step_s: SUMO's step, s.
        ego_origin: leg index the ego enters from.
        ego_destination: leg index it leaves at.
        passes: times the ego drives its route (each a crossing).
    """

    ride_id: str
    config: str
    share: float | None
    policy: str | None
    seed: int
    warmup_s: float
    ride_s: float
    step_s: float
    ego_origin: int
    ego_destination: int
    passes: int = 1


def ride_schedule(
    cfg: ScenarioConfig, spec: RideSpec
) -> tuple[ScenarioConfig, Schedule, int]:
    """The background schedule with the ego inserted at the end of the warm-up.

    Returns:
        (the scenario with one more vehicle, the schedule (N + 1,), the ego's
        index). The AV count is the background's: the ego is never an AV.
    """
    if spec.share is None:  # practice: the ego alone
        empty = np.zeros(0)
        base = Schedule(
            empty,
            empty.astype(np.int32),
            empty.astype(np.int32),
            empty,
            empty.astype(np.int32),
            0.0,
        )
    else:
        base = make_schedule(cfg, seed=spec.seed, penetration=spec.share)
    n = base.n_vehicles
    k = int(np.searchsorted(base.depart_s, spec.warmup_s, side="right"))
    schedule = Schedule(
        depart_s=np.insert(base.depart_s, k, spec.warmup_s),
        origin=np.insert(base.origin, k, spec.ego_origin).astype(np.int32),
        destination=np.insert(base.destination, k, spec.ego_destination).astype(
            np.int32
        ),
        speed_factor=np.insert(base.speed_factor, k, EGO_SPEED_FACTOR),
        av_rank=np.insert(base.av_rank, k, n).astype(np.int32),
        penetration=base.n_av / (n + 1),
    )
    demand = dataclasses.replace(cfg.demand, n_vehicles=n + 1)
    return dataclasses.replace(cfg, demand=demand), schedule, k


def ride_config(cfg: ScenarioConfig, step_s: float) -> ScenarioConfig:
    """The scenario as SUMO runs a ride: its step `step_s` and, on two-lane
    roads, the drivers' action step too. With a 0.5 s action step in 0.1 s
    steps SUMO 1.28's two-lane ring locks up within minutes (LC2013 enacts
    its speed advice an action step late; SUMO issue #4457; docs/study.md).
    """
    ride = cfg.with_overrides(dt_s=step_s)
    if cfg.network.single_lane:
        return ride
    hv, av = ride.drivers.hv, ride.drivers.av
    drivers = DriversConfig(
        hv=dataclasses.replace(hv, action_step_length=step_s),
        av=dataclasses.replace(av, action_step_length=step_s),
    )
    return dataclasses.replace(ride, drivers=drivers)


def sumo_command(sumocfg: Path) -> list[str]:
    """libsumo's command line for a ride: quiet, collisions as overlaps only."""
    return [
        "sumo",
        "-c",
        str(sumocfg),
        "--no-step-log",
        "true",
        "--no-warnings",
        "true",
        "--duration-log.disable",
        "true",
        "--collision.mingap-factor",
        "0",
    ]
