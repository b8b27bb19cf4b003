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
    """Vehicles of each entry due by `t` that have not entered yet, int (G,):
    each entry's due vehicles are those of its schedule indices below `due`
    (a binary search per entry), less those inserted (`EnvState.leg_inserted`).
    Vehicles wait at their origin leg's entry g < n_legs; a two-lane entry's
    second lane (g >= n_legs) has none waiting."""
    n_due = due(state, t)
    due_per_leg = jax.vmap(lambda row: jnp.searchsorted(row, n_due, side="left"))(
        state.leg_vehicles
    )
    return due_per_leg - state.leg_inserted


def queued_per_leg(
    net: NetArrays, state: EnvState, t: jax.Array, temperature: jax.Array
) -> jax.Array:
    """Vehicles queued on each leg's approach at time `t`, float (n_legs,):
    halting on its entry lanes (speed below `dynamics.HALTING_SPEED`, as
    SUMO's ``edge.getLastStepHaltingNumber`` counts the whole edge) plus
    those due that wait to be inserted. Above temperature 0 (m/s) the
    halting test is smooth (`jaxround.core.relax`); insertion stays exact."""
    _, lane, _ = geometry.locate(net, state.route, state.pos)
    on_entry = lane[None, :] == net.entry_lane[:, None]  # (G, M)
    slow = soft_step(dynamics.HALTING_SPEED - state.speed, temperature)
    halting = state.active * slow
    per_entry = jnp.sum(on_entry * halting[None, :], axis=1) + waiting_per_leg(state, t)
    return net.leg_entries @ per_entry  # (n_legs, G) @ (G,)


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
