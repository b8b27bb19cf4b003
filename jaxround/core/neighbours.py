"""Who is near whom: tables of the vehicle slots, built once per step.

The planning step asks questions about lanes: which vehicle is the rearmost
with any part on a lane of a route (SUMO's ``MSLane::getLastVehicleInformation``
as ``MSVehicle::planMoveInternal`` walks the lanes ahead), which vehicles on the
partner lane of a merge lead a vehicle there (``MSLink::getLeaderInfo``).
Asked of every pair of slots for every lane these cost (M, M, K); here they
are answered from tables:

- every vehicle's front and back projected onto every route, (R, M)
  (`geometry.project` onto all R routes at once: a vehicle's position along a
  route does not depend on who asks);
- for every lane k of every route r, the rearmost vehicle with any part on
  it, (R, K), from one masked minimum over the slots;
- for every merging lane, the two nearest vehicles on its partner lane, (Lm,)
  (`jaxround.core.link_leaders`).

What depends on the asking vehicle's own position (the vehicles ahead of it on
its own lane; the link leaders nearer the crossing once it is on its merging
lane) is one masked minimum over the slots, (M, M), per question, without a
lane axis.

Each function returns what the all-pairs search it replaces returned (the
tests keep those in ``tests/unit/allpairs.py`` and compare), with one reservation:
where two candidates at *different* positions give the same rounded float
distance, the all-pairs search took the lower slot and these take the nearer
one (the distance itself is the same).

Shapes: M vehicle slots, R routes, K lanes per route, S segments, Lm merging
lanes, G legs.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core.geometry import NetArrays, locate, nearer_back, project
from jaxround.core.link_leaders import (
    CurrentLink,
    LinkTable,
    current_link,
    first_other,
    link_table,
)
from jaxround.core.reductions import first_min, two_smallest


class NeighbourTables(NamedTuple):
    """What every route sees of every vehicle, and the per-vehicle look ahead.

    Attributes:
        front: float (R, M) where vehicle j's front lies along route r, nan
            where j is off r (`geometry.project`).
        back: float (R, M) where j's back lies along r; where the back is off
            r but the front is on it (j merging in), ``front - length``.
        ahead_back: float (M,) the smallest `back` along vehicle i's route of
            the active vehicles j != i whose front is ahead of i's front
            (inf for none).
        ahead_slot: int (M,) that vehicle's slot (0 for none).
        link: the merging lanes' tables (`LinkTable`).
        link_cur: the link leader nearer the crossing for a vehicle on a
            merging lane (`CurrentLink`).
    """

    front: jax.Array
    back: jax.Array
    ahead_back: jax.Array
    ahead_slot: jax.Array
    link: LinkTable
    link_cur: CurrentLink


def route_projections(
    net: NetArrays, route: jax.Array, pos: jax.Array, length: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Every vehicle's front and back along every route, (R, M) each.

    ``front[r, j]`` is `geometry.project` of j onto route r; ``back[r, j]``
    that of j's back (as `geometry.back_projection`), ``front - length``
    where the back is off r but the front is on it.
    """
    routes = jnp.arange(net.route_length.shape[0])
    _, lane, pos_on_lane = locate(net, route, pos)
    front = project(net, routes, lane, pos_on_lane)  # (R, M)
    _, back_lane, back_on_lane = locate(net, route, jnp.maximum(pos - length, 0.0))
    back = project(net, routes, back_lane, back_on_lane)  # (R, M)
    # a vehicle turning off leads as a same-source link leader too
    back = nearer_back(net, routes, lane, front, back, length)
    return front, jnp.where(jnp.isnan(back), front - length, back)


def build_tables(
    net: NetArrays,
    route: jax.Array,
    pos: jax.Array,
    active: jax.Array,
    length: jax.Array,
) -> NeighbourTables:
    """The tables of one step's state.

    Args:
        route, pos: int (M,), float (M,) each slot's route and front position.
        active: bool (M,).
        length: vehicle length (scalar).
    """
    front, back = route_projections(net, route, pos, length)
    m = pos.shape[0]
    others = jnp.arange(m)[None, :] != jnp.arange(m)[:, None]
    # the vehicles j ahead of each vehicle i along i's route: (M_i, M_j), no
    # lane axis (nan is never ahead)
    ahead = active[None, :] & others & (front[route] > pos[:, None])
    ahead_back, ahead_slot = first_min(jnp.where(ahead, back[route], jnp.inf), 1)
    link = link_table(net, route, pos, active, length)
    return NeighbourTables(
        front=front,
        back=back,
        ahead_back=ahead_back,
        ahead_slot=ahead_slot,
        link=link,
        link_cur=current_link(net, link, route, pos, active),
    )


def rearmost_on(
    tables: NeighbourTables,
    route: jax.Array,
    pos: jax.Array,
    active: jax.Array,
    seg_start: jax.Array,
    seg_end: jax.Array,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The rearmost vehicle with any part on [seg_start, seg_end) of each
    vehicle's route, ahead of it (SUMO's MSLane::getLastVehicleInformation).

    A vehicle j counts for vehicle i if it is active, not i, its front lies
    along i's route beyond both i's front and the segment's start, and its
    back before the segment's end. A segment starting ahead of i is looked
    up in a per-route table; one starting at or behind i takes the vehicles
    ahead of i (`NeighbourTables.ahead_back`).

    Args:
        seg_start, seg_end: float (R, S) the segments of each route (nan or
            +inf: none).

    Returns:
        (has, j, gap): bool (M, S), int (M, S) slot (0 for none), float
        (M, S) from i's front to j's back (inf for none).
    """
    front, back = tables.front[:, None, :], tables.back[:, None, :]  # (R, 1, M)
    counts = active & ~jnp.isnan(front)
    touch = counts & (front > seg_start[..., None]) & (back < seg_end[..., None])
    # the table serves segments that start ahead of the asking vehicle, and a
    # vehicle's own front along its own route is its position, rounded at
    # most onto the next lane's start, never past it: it never counts for
    # itself there, and one vehicle per segment is enough
    t_back, t_slot = first_min(jnp.where(touch, back, jnp.inf), 2)  # (R, S)
    start = seg_start[route]  # (M, S)
    t_slot, t_ok = t_slot[route], jnp.isfinite(t_back[route])
    # the vehicles ahead of i: the rearmost of them, if its back is on the segment
    c_ok = jnp.isfinite(tables.ahead_back)[:, None] & (
        tables.ahead_back[:, None] < seg_end[route]
    )
    from_table = start > pos[:, None]
    slot = jnp.where(from_table, t_slot, tables.ahead_slot[:, None])
    has = jnp.where(from_table, t_ok, c_ok) & active[:, None] & ~jnp.isnan(start)
    slot = jnp.where(has, slot, 0)
    b = tables.back[route[:, None], slot]  # (M, S)
    return has, slot, jnp.where(has, b - pos[:, None], jnp.inf)


def rearmost_on_lanes(
    net: NetArrays,
    tables: NeighbourTables,
    route: jax.Array,
    pos: jax.Array,
    active: jax.Array,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """`rearmost_on` every lane of each vehicle's route, (M, K) each: the
    look-ahead of SUMO's planMoveInternal, lane by lane."""
    start = net.route_lane_start  # (R, K), +inf padded
    end = start + net.lane_length[jnp.maximum(net.route_lanes, 0)]
    return rearmost_on(tables, route, pos, active, start, end)


def on_entry_lane(
    net: NetArrays, lanes: tuple[jax.Array, jax.Array, jax.Array]
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The rearmost vehicle on each vehicle's entry (its route's internal lane
    onto the ring, route lane 1), (M, 1) each, from `rearmost_on_lanes`."""
    start = np.asarray(net.route_lane_start)
    length = np.asarray(net.lane_length)[np.asarray(net.route_lanes)[:, 1]]
    entry = np.asarray(net.entry_internal_length)[np.asarray(net.route_origin)]
    if not (
        np.array_equal(start[:, 1], np.asarray(net.yield_offset))
        and np.array_equal(length, entry)
    ):
        raise ValueError("network: a route's lane 1 is not its entry's internal lane")
    has, slot, gap = lanes
    return has[:, 1:2], slot[:, 1:2], gap[:, 1:2]


def on_through_lanes(
    net: NetArrays, lanes: tuple[jax.Array, jax.Array, jax.Array], route: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The rearmost vehicle on the ring's through lane at every leg, (M, G)
    each (none where the route does not pass it), from `rearmost_on_lanes`."""
    index = np.asarray(net.conflict_index)  # (R, G)
    rows = np.arange(index.shape[0])[:, None]
    offset = np.asarray(net.conflict_offset)
    passes = ~np.isnan(offset)
    lane = np.asarray(net.route_lanes)[rows, index]
    same = (np.asarray(net.route_lane_start)[rows, index] == offset) & (
        np.asarray(net.lane_length)[lane] == np.asarray(net.through_length)[None, :]
    )
    if not np.all(same[passes]):
        raise ValueError("network: a route's conflict offset is not a lane start")
    k = net.conflict_index[route]  # (M, G)
    has, slot, gap = (jnp.take_along_axis(x, k, axis=1) for x in lanes)
    has = has & jnp.asarray(passes)[route]
    return has, jnp.where(has, slot, 0), jnp.where(has, gap, jnp.inf)


def soonest_ring_arrival(
    net: NetArrays, route: jax.Array, pos: jax.Array, speed: jax.Array,
    active: jax.Array, leg: jax.Array,
) -> jax.Array:  # fmt: skip
    """How soon the first other vehicle reaches the ring point level with the
    entry of `leg`: its distance there over its speed (at least 1 m/s), float
    (M,) for vehicle i and its leg[i] (inf for none). One (G, M) table."""
    dist = net.conflict_offset[route].T - pos[None, :]  # (G, M)
    coming = active[None, :] & ~jnp.isnan(dist) & (dist > 0)
    # dist is nan off the route: divide only where coming (finite gradients)
    dist = jnp.where(coming, dist, 0.0)
    eta = jnp.where(coming, dist / jnp.maximum(speed[None, :], 1.0), jnp.inf)
    best, value = two_smallest(eta, axis=1)  # (G, 2)
    slot, ok = first_other(
        best[leg], jnp.isfinite(value[leg]), jnp.arange(pos.shape[0])
    )
    return jnp.where(ok, eta[leg, slot], jnp.inf)
