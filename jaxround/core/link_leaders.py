"""Link leaders at the merges: the vehicles on the partner lane of each merging
lane (SUMO's ``MSLink::getLeaderInfo``), as tables built once per step.

Both lanes that merge into one ring lane are internal junction lanes (the
entry's and the ring's through lane). A vehicle about to merge is led by
every vehicle with any part on the partner lane, the gap measured to the
crossing point where the two lanes come within 2.5 m. The vehicles touching
each partner lane are one (Lm, M) table, read by every merge of every
vehicle's look-ahead; once a vehicle is on its merging lane, only the
leaders nearer the crossing than itself count, one (M, M) minimum.

Shapes: M vehicle slots, Lm merging lanes.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core.geometry import NetArrays, locate
from jaxround.core.reductions import first_min, two_smallest

if TYPE_CHECKING:
    from jaxround.core.neighbours import NeighbourTables


class LinkTable(NamedTuple):
    """Vehicles with any part on the partner lane of each merging lane. (Lm, M)
    per vehicle j unless said; the two best per lane, (Lm, 2).

    Attributes:
        valid: bool, j is active, its route uses the partner lane and it
            touches it.
        back_dist: float, SUMO's distance from j's back to the crossing
            point (larger: nearer leader).
        to_crossing: float, from j's front to the crossing point.
        front_on: bool, j's front is still on the partner lane.
        best_slot: int (Lm, 2) the two valid slots of largest back_dist
            (lowest slot first among equals); best_ok: bool (Lm, 2).
    """

    valid: jax.Array
    back_dist: jax.Array
    to_crossing: jax.Array
    front_on: jax.Array
    best_slot: jax.Array
    best_ok: jax.Array


class CurrentLink(NamedTuple):
    """For each vehicle i on a merging lane, its nearest link leader among
    those nearer the crossing than it (SUMO: two never wait for each other).
    (M,): slot (0 for none), found."""

    slot: jax.Array
    found: jax.Array


def merging_lanes(net: NetArrays) -> tuple[np.ndarray, np.ndarray]:
    """The lanes that merge with a partner, (Lm,), and each lane's row among
    them, (L,) (-1 for lanes that do not merge). Static numpy arrays."""
    partner = np.asarray(net.lane_partner)
    lanes = np.nonzero(partner >= 0)[0].astype(np.int32)
    row = -np.ones(partner.shape[0], np.int32)
    row[lanes] = np.arange(lanes.shape[0], dtype=np.int32)
    return lanes, row


def first_other(
    best: jax.Array, found: jax.Array, me: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Of two candidates (..., 2), the first that is not slot `me`: (slot,
    found), (...,) each."""
    skip = best[..., 0] == me
    slot = jnp.where(skip, best[..., 1], best[..., 0])
    ok = jnp.where(skip, found[..., 1], found[..., 0])
    return slot, ok


def link_table(
    net: NetArrays,
    route: jax.Array,
    pos: jax.Array,
    active: jax.Array,
    length: jax.Array,
) -> LinkTable:
    """The vehicles touching each merging lane's partner, (Lm, M)."""
    lanes, _ = merging_lanes(net)
    partner = net.lane_partner[lanes]  # (Lm,)
    q_off = net.lane_offset[route][:, partner].T  # (Lm, M): where it starts for j
    q_len = net.lane_length[partner][:, None]
    q_conv = net.lane_converge[partner][:, None]
    back_on_q = pos[None, :] - length - q_off
    front_on_q = pos[None, :] - q_off
    touches = (front_on_q > 0) & (back_on_q < q_len)
    back_dist = q_len - q_conv - back_on_q
    extra = jnp.maximum(0.0, q_conv - net.lane_converge[lanes][:, None])
    back_dist = jnp.where(back_dist < 0, back_dist + extra, back_dist)
    valid = active[None, :] & ~jnp.isnan(q_off) & touches
    best, value = two_smallest(jnp.where(valid, -back_dist, jnp.inf), axis=1)
    found = jnp.isfinite(value)
    return LinkTable(
        valid=valid,
        back_dist=back_dist,
        to_crossing=q_len - q_conv - front_on_q,
        front_on=front_on_q <= q_len,
        best_slot=best,
        best_ok=found,
    )


def current_link(
    net: NetArrays,
    link: LinkTable,
    route: jax.Array,
    pos: jax.Array,
    active: jax.Array,
) -> CurrentLink:
    """For a vehicle on a merging lane: the nearest link leader nearer the
    crossing than itself (the ring's through lane wins a tie), (M,)."""
    lanes, row_of = merging_lanes(net)
    k, lane, _ = locate(net, route, pos)
    row = jnp.asarray(row_of)[lane]  # (M,)
    r = jnp.maximum(row, 0)
    start = jnp.take_along_axis(net.route_lane_start[route], k[:, None], axis=1)[:, 0]
    to_crossing = start + net.lane_length[lane] - net.lane_converge[lane] - pos
    partner = net.lane_partner[jnp.asarray(lanes)][r]
    foe_is_ring = jnp.any(partner[:, None] == net.through_lane[None, :], axis=1)
    foe_tc = link.to_crossing[r]  # (M_i, M_j)
    nearer = (foe_tc < to_crossing[:, None]) | (
        (foe_tc == to_crossing[:, None]) & foe_is_ring[:, None]
    )
    m = pos.shape[0]
    others = jnp.arange(m)[None, :] != jnp.arange(m)[:, None]
    ok = link.valid[r] & nearer & others
    d, slot = first_min(jnp.where(ok, -link.back_dist[r], jnp.inf), 1)
    return CurrentLink(slot=slot, found=(row >= 0) & active & jnp.isfinite(d))


class LinkLeader(NamedTuple):
    """The nearest link leader of each vehicle at one merge. (M,).

    Attributes:
        has: bool, there is one.
        slot: int, its slot (0 for none).
        gap: float, SUMO's gap after minGap to the crossing point (may be
            negative; meaningless without a leader).
        front_on: bool, the leader's front is still on the partner lane.
        to_link: float, distance to the start of the vehicle's merging lane
            (negative once on it).
        to_end: float, distance to the end of the merging lane (the link
            after it).
    """

    has: jax.Array
    slot: jax.Array
    gap: jax.Array
    front_on: jax.Array
    to_link: jax.Array
    to_end: jax.Array


def link_leader(
    net: NetArrays,
    tables: NeighbourTables,
    route: jax.Array,
    pos: jax.Array,
    active: jax.Array,
    min_gap: jax.Array,
    km_fixed: int | jax.Array | None = None,
) -> LinkLeader:
    """The nearest vehicle on the lane that merges with each vehicle's next
    merging lane (SUMO's MSLink::getLeaderInfo, the nearest of them).

    Every vehicle with any part on the merge partner of the next internal
    lane of i's route that merges into a shared lane leads it, with the gap
    measured to the crossing point where the two lanes come within 2.5 m.
    Once i is on its merging lane, only those nearer the crossing lead it
    (the ring's through lane wins a tie): two never wait for each other.

    Args:
        km_fixed: the route lane index of the merge; default the next merge.
    """
    return link_leader_of(
        net, tables.link, tables.link_cur, route, pos, active, min_gap, km_fixed
    )


def link_leader_of(
    net: NetArrays,
    link: LinkTable,
    link_cur: CurrentLink | None,
    route: jax.Array,
    pos: jax.Array,
    active: jax.Array,
    min_gap: jax.Array,
    km_fixed: int | jax.Array | None = None,
) -> LinkLeader:
    """`link_leader` from the link tables; ``link_cur`` None for a vehicle
    looking at a route it would change onto: every vehicle on the partner
    lane leads it, on its merging lane too ("in the context of
    lane-changing, all candidates are leaders", `MSLane::
    getLeaderOnConsecutive`)."""
    k, _, _ = locate(net, route, pos)
    km = jnp.take_along_axis(net.merge_index[route], k[:, None], axis=1)[:, 0]  # (M,)
    if km_fixed is not None:  # the merge at route lane km_fixed, if it merges
        kf = jnp.full_like(km, km_fixed)
        lane_f = jnp.take_along_axis(net.route_lanes[route], kf[:, None], axis=1)[:, 0]
        ok_f = (lane_f >= 0) & (net.lane_partner[jnp.maximum(lane_f, 0)] >= 0)
        km = jnp.where(ok_f & (kf >= k), kf, -1)
    has_merge = km >= 0
    km = jnp.maximum(km, 0)
    mine = jnp.take_along_axis(net.route_lanes[route], km[:, None], axis=1)[:, 0]
    start = jnp.take_along_axis(net.route_lane_start[route], km[:, None], axis=1)[:, 0]
    to_crossing = start + net.lane_length[mine] - net.lane_converge[mine] - pos  # (M,)
    _, row_of = merging_lanes(net)
    row = jnp.maximum(jnp.asarray(row_of)[mine], 0)
    me = jnp.arange(pos.shape[0])
    slot, found = first_other(link.best_slot[row], link.best_ok[row], me)
    if link_cur is not None:
        # on its merging lane (then it is the lane the vehicle is on, km ==
        # k): only the leaders nearer the crossing
        on_junction = start - pos <= 0
        slot = jnp.where(on_junction, link_cur.slot, slot)
        found = jnp.where(on_junction, link_cur.found, found)
    has = has_merge & active & found
    slot = jnp.where(has, slot, 0)
    back_dist = link.back_dist[row, slot]
    return LinkLeader(
        has=has,
        slot=slot,
        gap=to_crossing - min_gap - back_dist,
        front_on=link.front_on[row, slot],
        to_link=start - pos,
        to_end=start + net.lane_length[mine] - pos,
    )
