"""Departures: scheduled vehicles enter the road and take a vehicle slot.

Follows SUMO 1.28's ``MSInsertionControl::emitVehicles`` and
``MSLane::insertVehicle`` for departPos="base", departSpeed="max" (the speeds
are `jaxround.core.insertion`'s).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core import dynamics, geometry, insertion
from jaxround.core.geometry import NetArrays
from jaxround.core.params import EnvParams
from jaxround.core.reductions import first_min
from jaxround.core.state import EnvState
from jaxround.envs import queues


def insert_departures(
    net: NetArrays,
    state: EnvState,
    params: EnvParams,
    t: jax.Array,
    *,
    dt: float,
    n_substeps: int,
) -> EnvState:
    """Insert the first waiting vehicle of each leg where its approach has room.

    As SUMO with departPos="base", departSpeed="max": the vehicle's back at
    the start of its approach, at the highest speed that is safe behind
    the vehicle ahead; otherwise it waits (and blocks later vehicles of
    its leg) until the next step.

    Insertion is a hard decision and carries no gradient: its inputs are
    frozen with `stop_gradient` (the inserted speed's sensitivity is left
    out, which also keeps the backward pass small to compile).

    Each leg's candidate is its next vehicle in `EnvState.leg_vehicles`, so
    a step reads G vehicles of the schedule, not all N.

    Shapes: G legs, N scheduled vehicles, M slots. The k-th inserting leg takes
    the k-th free slot; one with no free slot is counted in `state.stats.overflow`.
    """
    s = state.schedule
    p = jax.lax.stop_gradient(params)
    pos, speed = jax.lax.stop_gradient((state.pos, state.speed))
    g, n, m = net.entry_lane.shape[0], s.depart_s.shape[0], state.active.shape[0]
    # each leg's next vehicle (N: none left), a candidate once it is due
    # (schedule indices below `queues.due`): SUMO's per-lane insertion queue
    cand = jnp.take_along_axis(
        state.leg_vehicles, state.leg_inserted[:, None], axis=1, mode="fill",
        fill_value=n,
    )[:, 0]  # (G,)  # fmt: skip
    has = cand < queues.due(state, t)
    c = jnp.minimum(cand, n - 1)
    route = s.route[c]  # (G,)
    front = jnp.full(g, p.vehicle.length + dynamics.DEPART_OFFSET)
    # the nearest vehicle ahead of the new one's front, along its route
    back = jnp.maximum(pos - p.vehicle.length, 0.0)
    _, lane, pos_on_lane = geometry.locate(net, state.route, back)
    proj = geometry.project(net, route, lane, pos_on_lane)  # (G, M) backs
    ahead = jnp.where(state.active[None, :], proj - front[:, None], jnp.nan)
    ahead = jnp.where(jnp.isnan(ahead) | (ahead < -p.vehicle.length), jnp.inf, ahead)
    nearest, j = first_min(ahead, axis=1)
    gap = nearest - p.vehicle.min_gap  # SUMO's gap2pred
    v_lane = jnp.minimum(
        net.lane_speed[net.route_lanes[route, 0]] * s.speed_factor[c],
        p.vehicle.max_speed,
    )
    free_lane = jnp.isinf(gap)
    # SUMO lowers the speed first for the vehicle ahead, then for the stop
    # the vehicle plans at its yield line (beyond the visibility distance)
    pi = p.for_vehicles(s.is_av[c])  # (G,) the inserted vehicles' own
    v_follow = insertion.insertion_speed(
        v_lane, v_lane, speed[j],
        jnp.where(free_lane, 1e6, jnp.maximum(gap, 0.0)),
        pi, dt, n_substeps,
    )  # fmt: skip
    v_ins = jnp.where(free_lane, v_lane, v_follow)
    v_ins = insertion.insertion_stop_speed(
        v_ins, v_lane, net.yield_offset[route] - front, pi, dt,
        n_substeps,
    )  # fmt: skip
    room = free_lane | (gap >= 0.0)
    ok = has & room
    # slots: the k-th inserting leg takes the k-th free slot
    free = jnp.nonzero(~state.active, size=g, fill_value=m)[0]  # (G,)
    rank = jnp.cumsum(ok) - 1
    slot = jnp.where(ok, free[jnp.clip(rank, 0, g - 1)], m)
    overflow = ok & (slot >= m)
    ok = ok & (slot < m)
    slot = jnp.where(ok, slot, m)  # m: dropped by the scatters below
    vids = jnp.where(ok, c, n)

    def put(arr: jax.Array, values: jax.Array) -> jax.Array:
        return arr.at[slot].set(values.astype(arr.dtype), mode="drop")

    return state.replace(
        active=put(state.active, jnp.ones(g, bool)),
        vid=put(state.vid, c),
        route=put(state.route, route),
        pos=put(state.pos, front),
        speed=put(state.speed, v_ins),
        accel=put(state.accel, jnp.zeros(g)),
        is_av=put(state.is_av, s.is_av[c]),
        speed_factor=put(state.speed_factor, s.speed_factor[c]),
        waiting_s=put(state.waiting_s, jnp.zeros(g)),
        co2_mg=put(state.co2_mg, jnp.zeros(g)),
        fuel_mg=put(state.fuel_mg, jnp.zeros(g)),
        inserted=state.inserted.at[vids].set(True, mode="drop"),
        leg_inserted=state.leg_inserted + ok.astype(jnp.int32),
        insert_s=state.insert_s.at[vids].set(t, mode="drop"),
        stats=state.stats.replace(overflow=state.stats.overflow + jnp.sum(overflow)),
    )
