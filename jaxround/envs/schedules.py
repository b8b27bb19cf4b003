"""Departure schedules in JAX: the SUMO-side schedule converted, or one drawn.

A `jaxround.core.state.Schedule` holds N scheduled vehicles (N,) each.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core.network import CompiledNetwork
from jaxround.core.params import EnvParams
from jaxround.core.sampling import inverse_cdf, smallest_k, sorted_uniform
from jaxround.core.state import Schedule
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import Schedule as NumpySchedule


def from_numpy(
    network: CompiledNetwork,
    cfg: ScenarioConfig,
    n_schedule: int,
    schedule: NumpySchedule,
) -> Schedule:
    """The JAX form of a schedule drawn by `schedule.make_schedule`."""
    if schedule.n_vehicles != n_schedule:
        raise ValueError(
            f"schedule has {schedule.n_vehicles} vehicles, the environment {n_schedule}"
        )
    route = network.route_index[schedule.origin, schedule.destination]
    drivers = cfg.drivers
    factor = schedule.class_speed_factors(drivers.hv.speed_dev, drivers.av.speed_dev)
    return Schedule(
        depart_s=jnp.asarray(schedule.depart_s, jnp.float32),
        route=jnp.asarray(route, jnp.int32),
        origin=jnp.asarray(schedule.origin, jnp.int32),
        speed_factor=jnp.asarray(factor, jnp.float32),
        is_av=jnp.asarray(schedule.is_av),
    )


def draw(
    network: CompiledNetwork,
    n_schedule: int,
    dt: float,
    key: jax.Array,
    params: EnvParams,
) -> Schedule:
    """A random schedule in JAX with the distribution of `make_schedule`.

    Drawn without sorting (`step` draws one for every roundabout at every
    step, for its automatic reset): sorted departure times from
    exponential gaps, origins and destinations by inverse CDF, the AVs as
    the vehicles with the smallest random keys (a binary search for the
    cut).
    """
    n = n_schedule
    k_t, k_o, k_d, k_s, k_av = jax.random.split(key, 5)
    t = sorted_uniform(k_t, n, params.demand.duration_s)
    depart = jnp.floor(t / dt) * dt
    origin = inverse_cdf(
        k_o, jnp.broadcast_to(params.demand.origin_share, (n, network.n_legs))
    )
    dest = inverse_cdf(k_d, params.demand.od[origin])
    z = jax.random.truncated_normal(
        k_s, -0.8 / jnp.maximum(params.human.speed_dev, 1e-6),
        1.0 / jnp.maximum(params.human.speed_dev, 1e-6), (n,),
    )  # fmt: skip
    speed_factor = jnp.round((1.0 + params.human.speed_dev * z) * 1e4) / 1e4
    # round(p * N) with halves up, as `n_av_at`; the margin absorbs float32
    n_av = jnp.floor(params.demand.penetration * n + 0.5 + 1e-3).astype(jnp.int32)
    route = jnp.asarray(network.route_index)[origin, dest]
    is_av = smallest_k(k_av, n, n_av)
    # as `Schedule.class_speed_factors`: AVs scale their deviation from 1
    scale = params.av.speed_dev / jnp.maximum(params.human.speed_dev, 1e-6)
    av_factor = jnp.round((1.0 + (speed_factor - 1.0) * scale) * 1e4) / 1e4
    return Schedule(
        depart_s=depart.astype(jnp.float32),
        route=route.astype(jnp.int32),
        origin=origin.astype(jnp.int32),
        speed_factor=jnp.where(is_av, av_factor, speed_factor).astype(jnp.float32),
        is_av=is_av,
    )
