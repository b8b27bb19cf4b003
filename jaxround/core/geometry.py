"""Where vehicles are: the compiled network as device arrays, and who leads whom.

Shapes: M vehicle slots, R routes, L lanes, K lanes per route, G legs.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core.crossing_tables import CrossingArrays
from jaxround.core.network import CompiledNetwork
from jaxround.core.reductions import first_min

#: Far away (m).
FAR = 1e6


@dataclass(frozen=True)
class NetArrays:
    """`CompiledNetwork` as device arrays (static for a jitted step)."""

    lane_length: jax.Array  # (L,)
    lane_speed: jax.Array  # (L,)
    lane_next: jax.Array  # (L,)
    lane_sibling: jax.Array  # (L,)
    lane_diverge: jax.Array  # (L,)
    lane_partner: jax.Array  # (L,)
    lane_converge: jax.Array  # (L,)
    route_lanes: jax.Array  # (R, K)
    route_lane_start: jax.Array  # (R, K), +inf padded
    route_length: jax.Array  # (R,)
    route_origin: jax.Array  # (R,) the entry (G) each route starts at
    lane_offset: jax.Array  # (R, L), nan where off-route
    yield_offset: jax.Array  # (R,)
    conflict_offset: jax.Array  # (R, G), nan where the route does not pass
    through_length: jax.Array  # (G,)
    entry_internal_length: jax.Array  # (G,)
    entry_visibility: jax.Array  # (G,)
    entry_lane: jax.Array  # (G,)
    leg_entries: jax.Array  # (n_legs, G) float 1 where entry g is the leg's
    through_lane: jax.Array  # (G,) the ring's through lane at each entry
    lane_internal: jax.Array  # (L,) bool
    normal_cum: jax.Array  # (R, K) metres of normal lanes before lane k
    internal_cum: jax.Array  # (R, K) metres of internal lanes before lane k
    conflict_index: jax.Array  # (R, G) route index k of the through lane at leg g
    merge_index: jax.Array  # (R, K) first merging internal lane at or after k, -1
    merge_positions: tuple[int, ...]  # route indices k where some route merges
    prev_lane_length: jax.Array  # (R, G) length of the lane before it
    normal_before: jax.Array  # (R, G) normal metres up to the link before it
    internal_before: jax.Array  # (R, G) internal metres up to the link before it
    next_link_index: jax.Array  # (R,) route index k of the first link after the entry
    next_link_offset: jax.Array  # (R,) where it starts along the route (+inf: none)
    route_arrives: jax.Array  # (R,) bool: vehicles leave at the route's end
    all_arrive: bool  # every route's does (static: one-lane roundabouts)
    entry_crossing: jax.Array  # (G,) the entry whose through link g's crosses
    has_crossings: bool  # some entry's does (static: two-lane entries)
    crossing: CrossingArrays | None  # internal lanes that cross; None: none

    @classmethod
    def from_network(cls, net: CompiledNetwork) -> NetArrays:
        f = jnp.float32
        start = np.where(np.isnan(net.route_lane_start), np.inf, net.route_lane_start)
        internal = np.array([lid.startswith(":") for lid in net.lane_ids])
        r_n, k_n = net.route_lanes.shape
        lanes = np.maximum(net.route_lanes, 0)
        seg = np.where(net.route_lanes >= 0, net.lane_length[lanes], 0.0)  # (R, K)
        is_int = internal[lanes] & (net.route_lanes >= 0)
        normal_cum = np.concatenate(
            [np.zeros((r_n, 1)), np.cumsum(np.where(is_int, 0.0, seg), 1)[:, :-1]], 1
        )
        internal_cum = np.concatenate(
            [np.zeros((r_n, 1)), np.cumsum(np.where(is_int, seg, 0.0), 1)[:, :-1]], 1
        )
        g_n = net.n_entries
        conflict_index = np.zeros((r_n, g_n), np.int32)
        for r in range(r_n):
            for g in range(g_n):
                hit = np.nonzero(net.route_lanes[r] == net.ring_through[g])[0]
                conflict_index[r, g] = hit[0] if hit.size else 2
        rows = np.arange(r_n)[:, None]
        prev_lane = net.route_lanes[rows, conflict_index - 1]
        merges = (net.route_lanes >= 0) & (net.lane_partner[lanes] >= 0)
        merge_index = -np.ones((r_n, k_n), np.int32)
        for r in range(r_n):
            nxt = -1
            for k in range(k_n - 1, -1, -1):
                if merges[r, k]:
                    nxt = k
                merge_index[r, k] = nxt
        # the first link after the entry that leaves a normal lane (the ring
        # lane after the entry's internal lane ends there): SUMO's request
        # for it is what a vehicle that slowed down for its entry withdraws
        next_link = np.full(r_n, k_n - 1, np.int32)
        for r in range(r_n):
            inner = np.nonzero(is_int[r])[0]
            later = inner[inner > inner[0] + 1] if inner.size else inner
            if later.size:
                next_link[r] = later[0]
        next_offset = np.where(
            is_int[np.arange(r_n), next_link], start[np.arange(r_n), next_link], np.inf
        )
        return cls(
            lane_length=jnp.asarray(net.lane_length, f),
            lane_speed=jnp.asarray(net.lane_speed, f),
            lane_next=jnp.asarray(net.lane_next),
            lane_sibling=jnp.asarray(net.lane_sibling),
            lane_diverge=jnp.asarray(net.lane_diverge, f),
            lane_partner=jnp.asarray(net.lane_partner),
            lane_converge=jnp.asarray(net.lane_converge, f),
            route_lanes=jnp.asarray(net.route_lanes),
            route_lane_start=jnp.asarray(start, f),
            route_length=jnp.asarray(net.route_length, f),
            route_origin=jnp.asarray(net.entry_of_route),
            lane_offset=jnp.asarray(net.lane_offset, f),
            yield_offset=jnp.asarray(net.yield_offset, f),
            conflict_offset=jnp.asarray(net.conflict_offset, f),
            through_length=jnp.asarray(net.lane_length[net.ring_through], f),
            entry_internal_length=jnp.asarray(net.lane_length[net.entry_internal], f),
            entry_visibility=jnp.asarray(net.entry_visibility, f),
            entry_lane=jnp.asarray(net.entry_lane),
            leg_entries=jnp.asarray(
                net.entry_leg[None, :] == np.arange(net.n_legs)[:, None], f
            ),
            through_lane=jnp.asarray(net.ring_through),
            lane_internal=jnp.asarray(internal),
            normal_cum=jnp.asarray(normal_cum, f),
            internal_cum=jnp.asarray(internal_cum, f),
            conflict_index=jnp.asarray(conflict_index),
            merge_index=jnp.asarray(merge_index),
            merge_positions=tuple(int(k) for k in np.nonzero(merges.any(axis=0))[0]),
            prev_lane_length=jnp.asarray(net.lane_length[prev_lane], f),
            normal_before=jnp.asarray(normal_cum[rows, conflict_index - 1], f),
            internal_before=jnp.asarray(internal_cum[rows, conflict_index - 1], f),
            next_link_index=jnp.asarray(next_link),
            next_link_offset=jnp.asarray(next_offset, f),
            route_arrives=jnp.asarray(
                np.ones(r_n, bool) if net.route_arrives is None else net.route_arrives
            ),
            all_arrive=net.all_arrive,
            entry_crossing=jnp.asarray(
                -np.ones(g_n, np.int32)
                if net.entry_crossing is None
                else net.entry_crossing
            ),
            has_crossings=net.entry_crossing is not None
            and bool(np.any(net.entry_crossing >= 0)),
            crossing=None
            if net.crossings is None
            else CrossingArrays.build(net.crossings, net.route_lanes),
        )


def locate(net: NetArrays, route: jax.Array, pos: jax.Array) -> tuple[jax.Array, ...]:
    """Lane of each vehicle from its route position.

    Args:
        route: int (M,); pos: float (M,) front position along the route.

    Returns:
        (k, lane, pos_on_lane): int (M,) index in the route, int (M,) lane,
        float (M,) position on that lane.
    """
    starts = net.route_lane_start[route]  # (M, K)
    k = jnp.clip(jnp.sum(starts <= pos[:, None], axis=1) - 1, 0, starts.shape[1] - 1)
    lane = jnp.take_along_axis(net.route_lanes[route], k[:, None], axis=1)[:, 0]
    pos_on_lane = pos - jnp.take_along_axis(starts, k[:, None], axis=1)[:, 0]
    return k, lane, pos_on_lane


def project(
    net: NetArrays, route: jax.Array, lane: jax.Array, pos_on_lane: jax.Array
) -> jax.Array:
    """Position of every vehicle j along the route of every vehicle i.

    A vehicle on a lane of i's route is at that lane's offset plus its lane
    position. A vehicle on the sibling of a lane of i's route (exit vs
    through) at a position before the divergence point is placed on that
    lane, as far before that lane's divergence point as it is before its
    own (``MSLink::getLeaderInfo``'s same-source gap: distToCrossing -
    minGap - leaderBackDist). Others are nan: vehicles merging in from
    another lane are link leaders (`link_leaders.link_leader`).

    Returns:
        float (M_i, M_j).
    """
    lane_offset = net.lane_offset[route]  # (M_i, L)
    direct = lane_offset[:, lane] + pos_on_lane[None, :]  # (M, M)
    sib = net.lane_sibling[lane]  # (M,)
    sib_offset = lane_offset[:, jnp.maximum(sib, 0)]  # (M, M)
    not_apart = (sib >= 0) & (pos_on_lane < net.lane_diverge[lane])
    shift = net.lane_diverge[jnp.maximum(sib, 0)] - net.lane_diverge[lane]  # (M,)
    via_sibling = jnp.where(
        not_apart[None, :], sib_offset + (pos_on_lane + shift)[None, :], jnp.nan
    )
    return jnp.where(jnp.isnan(direct), via_sibling, direct)


def back_projection(
    net: NetArrays, route: jax.Array, pos: jax.Array, length: jax.Array
) -> jax.Array:
    """Where each vehicle's back lies along each vehicle's route, (M_i, M_j).

    SUMO follows a leader as long as any part of it occupies a lane ahead on
    the follower's route: a vehicle turning off still leads until its back
    has left the shared lane, and while its back is on that lane it leads
    as a same-source link leader too, from where the two internal lanes
    part (``MSLink::getLeaderInfo``): the nearer counts.
    """
    _, lane, pos_on_lane = locate(net, route, jnp.maximum(pos - length, 0.0))
    back = project(net, route, lane, pos_on_lane)
    _, front_lane, front_on_lane = locate(net, route, pos)
    front = project(net, route, front_lane, front_on_lane)
    return nearer_back(net, route, front_lane, front, back, length)


def nearer_back(
    net: NetArrays,
    route: jax.Array,
    front_lane: jax.Array,
    front: jax.Array,
    back: jax.Array,
    length: jax.Array,
) -> jax.Array:
    """``back`` (R, M) along the routes ``route`` (R,), where a vehicle
    whose front lies on the sibling of a route's lane (``front_lane`` (M,),
    ``front`` its `project`) has its back on the lane both leave: the nearer
    of that back and its back as a same-source link leader, ``front -
    length`` (``MSLink::getLeaderInfo``)."""
    turning_off = jnp.isnan(net.lane_offset[route][:, front_lane]) & jnp.isfinite(front)
    return jnp.where(turning_off, jnp.fmin(back, front - length), back)


def past_the_parting(
    net: NetArrays, route: jax.Array, pos: jax.Array, length: jax.Array
) -> jax.Array:
    """bool (M_i, M_j): vehicle j's back lies on the internal lane that parts
    from a lane of i's route (it leads i only as a same-source link leader,
    `project`), and i's front has passed where the two part. SUMO then no
    longer asks that link for leaders (``MSLink::getLeaderInfo``: the foe
    lane is skipped while ``distToCrossing < 0`` outside lane changing)."""
    _, back_lane, _ = locate(net, route, jnp.maximum(pos - length, 0.0))
    sibling = net.lane_sibling[back_lane]  # (M_j,)
    other = jnp.maximum(sibling, 0)
    offsets = net.lane_offset[route]  # (M_i, L)
    parting = offsets[:, other] + net.lane_diverge[other][None, :]  # nan: off
    off_route = jnp.isnan(offsets[:, back_lane]) & (sibling >= 0)[None, :]
    return off_route & (pos[:, None] > parting)


def leaders(
    proj: jax.Array, pos: jax.Array, active: jax.Array, length: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Nearest vehicle ahead along each vehicle's route (masked argmin).

    Args:
        proj: (M, M) from `project`; pos: (M,); active: bool (M,).
        length: vehicle length (scalar).

    Returns:
        (leader, gap): int (M,) slot of the leader (-1 for none) and float (M,)
        bumper-to-bumper gap (FAR for none).
    """
    m = pos.shape[0]
    ahead = proj - pos[:, None]  # (M, M)
    eye = jnp.eye(m, dtype=bool)
    # equal positions: the lower slot counts as ahead, so two never both lead
    slot_order = jnp.arange(m)[None, :] < jnp.arange(m)[:, None]
    # (nan, off the route, is neither > 0 nor == 0)
    ok = active[None, :] & ~eye & ((ahead > 0) | ((ahead == 0) & slot_order))
    nearest, leader = first_min(jnp.where(ok, ahead, jnp.inf), axis=1)
    has = jnp.isfinite(nearest) & active
    gap = jnp.where(has, nearest - length, FAR)
    return jnp.where(has, leader, -1), gap


def normal_done(net: NetArrays, route: jax.Array, pos: jax.Array) -> jax.Array:
    """Metres of normal (non-internal) lanes driven so far along the route, (M,)."""
    k, lane, pos_on_lane = locate(net, route, pos)
    before = jnp.take_along_axis(net.normal_cum[route], k[:, None], axis=1)[:, 0]
    return before + jnp.where(net.lane_internal[lane], 0.0, pos_on_lane)


def internal_done(net: NetArrays, route: jax.Array, pos: jax.Array) -> jax.Array:
    """Metres of internal lanes driven so far along the route, (M,)."""
    k, lane, pos_on_lane = locate(net, route, pos)
    before = jnp.take_along_axis(net.internal_cum[route], k[:, None], axis=1)[:, 0]
    return before + jnp.where(net.lane_internal[lane], pos_on_lane, 0.0)
