"""What an AV's policy sees: one row of numbers per vehicle slot.

Two observers, chosen by name in the scenario config (``agent.observer``):

- ``"paper"``: Eq. 1 of the paper, 10 numbers: own position and acceleration;
  position and relative acceleration of the front, back, left and right
  neighbours; positions over the longest route (x_max), accelerations over the
  AVs' maximum acceleration. A missing neighbour reads position -1 and
  relative acceleration 0. On single-lane roads there is never a left or
  right neighbour.
- ``"rich"``: the paper's 10 numbers plus what a driver at a roundabout
  looks at: own speed, the gap to and speed of the vehicle ahead, the
  distance to the yield line, how soon the ring traffic reaches the entry,
  how far round the ring the exit is, and the time spent waiting.

Both read only positions along routes, speeds, accelerations and waiting
times, which SUMO reports too: the SUMO controller builds an `EnvState` of
those from libsumo and calls these same functions.

Shapes: M vehicle slots, G legs. Rows of empty slots are 0.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core.geometry import NetArrays, leaders, locate, project
from jaxround.core.neighbours import soonest_ring_arrival
from jaxround.core.params import EnvParams
from jaxround.core.reductions import first_min
from jaxround.core.state import EnvState

#: Position of a missing neighbour (positions are otherwise in [0, 1]).
MISSING = -1.0
#: Scale of gaps and distances in the rich observer, m.
DISTANCE_SCALE = 50.0
#: Scale of speeds in the rich observer, m/s.
SPEED_SCALE = 15.0
#: Horizon of the ring traffic's arrival at the entry, s.
RING_HORIZON_S = 10.0

#: Numbers per slot of each observer (``"lanes"``: `jaxround.envs.lane_view`).
OBSERVATION_SIZES = {"paper": 10, "rich": 17, "lanes": 24}


def paper_observation(
    net: NetArrays, state: EnvState, params: EnvParams
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Eq. 1 of the paper for every slot.

    Returns:
        (obs, leader, gap): float (M, 10); int (M,) slot ahead (-1 for none)
        and float (M,) bumper-to-bumper gap to it, for the rich observer.
    """
    x_max = jnp.max(net.route_length)
    a_max = params.av.accel
    _, lane, pos_on_lane = locate(net, state.route, state.pos)
    routes = jnp.arange(net.route_length.shape[0])
    # every front along every route (R, M), read along each vehicle's route
    front = project(net, routes, lane, pos_on_lane)[state.route]  # (M, M)
    leader, gap = leaders(front, state.pos, state.active, params.vehicle.length)
    # the follower: the nearest front behind this vehicle's back on its route
    behind = state.pos[:, None] - params.vehicle.length - front  # (M, M)
    m = state.pos.shape[0]
    others = jnp.arange(m)[None, :] != jnp.arange(m)[:, None]
    ok = state.active[None, :] & others & (behind >= 0)  # nan (off the route): no
    nearest_behind, follower = first_min(jnp.where(ok, behind, jnp.inf), axis=1)
    has_follower = jnp.isfinite(nearest_behind) & state.active
    has_leader = leader >= 0
    lead = jnp.maximum(leader, 0)
    a = state.accel
    x_front = jnp.where(has_leader, state.pos + gap + params.vehicle.length, 0.0)
    x_back = jnp.where(
        has_follower, state.pos - params.vehicle.length - nearest_behind, 0.0
    )
    none = jnp.zeros(m)
    obs = jnp.stack(
        [
            state.pos / x_max,
            a / a_max,
            jnp.where(has_leader, x_front / x_max, MISSING),
            jnp.where(has_leader, (a[lead] - a) / a_max, 0.0),
            jnp.where(has_follower, x_back / x_max, MISSING),
            jnp.where(has_follower, (a[follower] - a) / a_max, 0.0),
            none + MISSING,  # left: single-lane roads have no neighbour beside
            none,
            none + MISSING,  # right
            none,
        ],
        axis=-1,
    )
    return jnp.where(state.active[:, None], obs, 0.0), leader, gap


def rich_observation(
    net: NetArrays,
    state: EnvState,
    params: EnvParams,
    route_destination: jax.Array,
) -> jax.Array:
    """The paper's 10 numbers and 7 more, float (M, 17).

    Args:
        route_destination: int (R,) exit leg of each route.
    """
    return rich_observation_and_leader(net, state, params, route_destination)[0]


def rich_observation_and_leader(
    net: NetArrays,
    state: EnvState,
    params: EnvParams,
    route_destination: jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """`rich_observation`, float (M, 17), and the slot ahead of each slot,
    int (M,) (-1 for none), for controllers that also ask who leads."""
    base, leader, gap = paper_observation(net, state, params)
    g = net.through_length.shape[0]
    lead = jnp.maximum(leader, 0)
    has_leader = leader >= 0
    origin = net.route_origin[state.route]  # (M,)
    to_line = net.yield_offset[state.route] - state.pos  # (M,)
    # how soon the ring traffic upstream reaches this vehicle's entry: each
    # vehicle's distance to the ring's point level with the entry over its
    # speed (at least 1 m/s); from positions only, so SUMO gives the same
    soonest = soonest_ring_arrival(
        net, state.route, state.pos, state.speed, state.active, origin
    )
    legs_to_exit = (route_destination[state.route] - origin) % g
    extra = jnp.stack(
        [
            state.speed / SPEED_SCALE,
            jnp.where(has_leader, jnp.minimum(gap / DISTANCE_SCALE, 1.0), 1.0),
            jnp.where(has_leader, (state.speed[lead] - state.speed) / SPEED_SCALE, 0.0),
            jnp.clip(to_line / DISTANCE_SCALE, -1.0, 1.0),
            jnp.clip(soonest / RING_HORIZON_S, 0.0, 1.0),
            legs_to_exit / g,
            jnp.minimum(state.waiting_s / params.vehicle.time_to_impatience, 1.0),
        ],
        axis=-1,
    )
    obs = jnp.concatenate([base, extra], axis=-1)
    return jnp.where(state.active[:, None], obs, 0.0), leader
