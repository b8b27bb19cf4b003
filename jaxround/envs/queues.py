"""Queue statistics of an episode: vehicles queued on each approach, as SUMO's
``getLastStepHaltingNumber`` plus those waiting to be inserted."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core import dynamics, geometry
from jaxround.core.geometry import NetArrays
from jaxround.core.params import EnvParams
from jaxround.core.relax import soft_step
from jaxround.core.state import EnvState


def due(state: EnvState, t: jax.Array) -> jax.Array:
    """How many scheduled vehicles are due to have departed by time `t`,
    int (): the schedule is in departure order, so a binary search."""
    return jnp.searchsorted(state.schedule.depart_s, t + 1e-4, side="right")


def waiting_per_leg(state: EnvState, t: jax.Array) -> jax.Array:
    """Vehicles of each leg due by `t` that have not entered yet, int (G,):
    each leg's due vehicles are those of its schedule indices below `due`
    (a binary search per leg), less those inserted (`EnvState.leg_inserted`)."""
    n_due = due(state, t)
    due_per_leg = jax.vmap(lambda row: jnp.searchsorted(row, n_due, side="left"))(
        state.leg_vehicles
    )
    return due_per_leg - state.leg_inserted


def queued_per_leg(
    net: NetArrays, state: EnvState, t: jax.Array, temperature: jax.Array
) -> jax.Array:
    """Vehicles queued on each approach at time `t`, float (G,): halting there
    (speed below `dynamics.HALTING_SPEED`, as SUMO's getLastStepHaltingNumber)
    plus those due that wait to be inserted. Above temperature 0 (m/s) the
    halting test is smooth (`jaxround.core.relax`); insertion stays exact."""
    _, lane, _ = geometry.locate(net, state.route, state.pos)
    on_entry = lane[None, :] == net.entry_lane[:, None]  # (G, M)
    slow = soft_step(dynamics.HALTING_SPEED - state.speed, temperature)
    halting = state.active * slow
    return jnp.sum(on_entry * halting[None, :], axis=1) + waiting_per_leg(state, t)


def count_queues(
    net: NetArrays, state: EnvState, params: EnvParams, t: jax.Array
) -> EnvState:
    """Queued vehicles per leg: halting on the approach plus waiting to enter."""
    q = queued_per_leg(net, state, t, jnp.float32(0.0))
    within = t <= params.demand.duration_s + 1e-4
    stats = state.stats
    return state.replace(
        stats=stats.replace(
            queue_sum=stats.queue_sum + jnp.where(within, q, 0.0),
            queue_max=jnp.where(
                within, jnp.maximum(stats.queue_max, q), stats.queue_max
            ),
            queue_samples=stats.queue_samples + within.astype(jnp.int32),
        )
    )
