"""Insertion speeds on an empty approach: JAX against SUMO, speed factor by
speed factor (`jaxround.core.insertion.insertion_stop_speed`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.envs import departures
from jaxround.envs.roundabout import make
from jaxround.scenario.schedule import Schedule
from tests.conftest import small_config

#: Speed factors tried: 0.8 to 1.4 every 0.02, and the 1.136 of the run that
#: showed the difference.
FACTORS = np.round(np.concatenate([np.arange(0.8, 1.4001, 0.02), [1.136]]), 3)
#: Seconds between departures: each vehicle has left before the next enters.
GAP_S = 40.0


def lone_schedule(n_legs: int) -> Schedule:
    """One vehicle per speed factor, GAP_S apart, entering from every leg in
    turn and leaving two legs on."""
    n = len(FACTORS)
    origin = np.arange(n) % n_legs
    return Schedule(
        depart_s=np.arange(n) * GAP_S,
        origin=origin.astype(np.int32),
        destination=((origin + 2) % n_legs).astype(np.int32),
        speed_factor=FACTORS.astype(np.float64),
        av_rank=np.arange(n, dtype=np.int32),
        penetration=0.0,
    )


def sumo_insertion_speeds(
    cfg: Any, schedule: Schedule, workdir: Path
) -> tuple[np.ndarray, np.ndarray]:
    """SUMO's speed of each vehicle in the step it entered (before it moved),
    and its desired speed there (lane limit * speed factor): (N,), (N,)."""
    from sumo_export.runner import run_schedule
    from sumo_export.scenario import vehicle_id

    speeds: dict[str, tuple[float, float]] = {}

    def record(sumo: Any, _: float) -> None:
        for v in sumo.simulation.getDepartedIDList():
            speeds[v] = (sumo.vehicle.getSpeed(v), sumo.vehicle.getAllowedSpeed(v))

    run = run_schedule(cfg, schedule, workdir=workdir, controller=record)
    assert run.records.arrived.all()
    ids = [vehicle_id(i) for i in range(schedule.n_vehicles)]
    return np.array([speeds[v][0] for v in ids]), np.array([speeds[v][1] for v in ids])


def jax_insertion_speeds(cfg: Any, schedule: Schedule) -> np.ndarray:
    """JAX's speed of each vehicle inserted alone on the empty road, at its
    departure time, with every vehicle before it already gone."""
    env, params = make(cfg)
    _, start = env.reset_to_schedule(env.schedule_from_numpy(schedule), params)
    legs = jnp.arange(env.n_legs)

    @jax.jit
    def insert(k: jax.Array) -> jax.Array:
        # (reset may have inserted the first vehicle already: start empty)
        gone = jnp.arange(env.n_schedule) < k
        origin = start.schedule.origin
        per_leg = jnp.sum(gone[None, :] & (origin[None, :] == legs[:, None]), axis=1)
        state = start.replace(
            active=jnp.zeros_like(start.active), inserted=gone,
            leg_inserted=per_leg.astype(jnp.int32),
        )  # fmt: skip
        t = jnp.float32(GAP_S) * k
        after = departures.insert_departures(
            env.net, state, params, t, dt=env.dt, n_substeps=env.n_substeps
        )
        mine = after.active & (after.vid == k)
        return jnp.where(mine.any(), after.speed[jnp.argmax(mine)], jnp.nan)

    return np.array([float(insert(jnp.int32(k))) for k in range(len(FACTORS))])


@pytest.mark.sumo
def test_insertion_speed_matches_sumo_for_every_speed_factor(tmp_path: Path) -> None:
    cfg = small_config(n_vehicles=len(FACTORS), duration_s=GAP_S * len(FACTORS))
    schedule = lone_schedule(cfg.n_legs)
    sumo, desired = sumo_insertion_speeds(cfg, schedule, tmp_path)
    jx = jax_insertion_speeds(cfg, schedule)
    # both cases are tried: slow drivers enter at their desired speed, fast
    # ones are slowed for the yield line ahead, some twice (the recursion)
    free = np.isclose(sumo, desired, rtol=0, atol=1e-6)
    assert free[FACTORS <= 0.9].all() and not free[FACTORS >= 1.1].any()
    assert np.any(sumo < desired - 3.0)
    np.testing.assert_allclose(jx, sumo, rtol=0, atol=1e-3)
