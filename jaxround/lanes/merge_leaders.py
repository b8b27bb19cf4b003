"""The vehicles about to merge ahead on a change's target lane, as SUMO's
lane changer finds them: link leaders at the merge.

Two internal lanes of a junction merge into one ring lane (the ring's
through lane and the entry's). SUMO's changer meets the vehicles on the
other lane of a merge twice in `MSLaneChanger::checkChange`:

- as the target lane's leader (`getRealLeader`): with no vehicle ahead on
  the target lane, `MSLane::getLeaderOnConsecutive` walks the lanes ahead
  (when the vehicle is on an internal lane, or its lane ends within
  ``brakeGap(v) + minGap``; through every internal lane once on the walk)
  and returns at the first link with link leaders (`MSLink::getLeaderInfo`)
  the one of smallest gap plus braking distance, before the vehicles on
  the next lane. "In the context of lane-changing, all candidates are
  leaders": the changer takes them whoever entered the junction first. The
  gap then blocks the change as any leader's does (below 0, or below the
  secure gap times ``1 / lcAssertive``).
- as a critical leader (`MSLane::getCriticalLeader`): when the target lane
  has a leader ahead of the merge and the change is wanted and not
  blocked, the link leaders on the walk are tested against the secure gap
  once more; one that is not that leader and is too near blocks the
  change by the leader.

Without them the JAX step let a ring vehicle near the end of the outer
through lane change onto the inner one 0.5 m before its merge, in front of
an entering vehicle already past the crossing point (two collisions in 30
simulated minutes of two_lane.yaml at 100% AVs, schedule seed 1, with the
entry's pass speed of `jaxround.core.dynamics.cross_or_stop`).

Here, for each side: the merge link leader of the target path at the same
place on the target lane (`jaxround.core.link_leaders`: the nearest
vehicle on the merge partner lane, with SUMO's gap to the crossing point),
within reach as above. Left out: the links' `opened` test on the walk (an
entry link closed to the vehicle holds the change back anyway:
`jaxround.lanes.entry_hold`), link leaders of links that cross rather than
merge, and the braking distance in the choice among several leaders (one
merge partner lane, its nearest vehicle).

Shapes: M vehicle slots.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxround.core.geometry import NetArrays, locate
from jaxround.core.junction import brake_gap
from jaxround.core.link_leaders import link_leader_of, link_table
from jaxround.core.params import CarFollowing
from jaxround.lanes.ring_neighbours import RingArrays


class MergeLeaders(NamedTuple):
    """The merge link leader on each side's target lane. (M, 2) each, right
    then left.

    Attributes:
        slot: int, the leader's slot (-1: none within reach).
        gap: float, SUMO's gap after minGap to the crossing point (m, may be
            negative).
        link_at: float, from the vehicle's front to the merge's link (the
            end of the merging lane) along the target lane (m): a leader on
            the target lane whose back is nearer is found first.
        critical: bool, `getCriticalLeader`'s walk reaches the merge (it
            stops at ``brakeGap(v) + minGap``, internal lanes or not).
    """

    slot: jax.Array
    gap: jax.Array
    link_at: jax.Array
    critical: jax.Array


def merge_leaders(
    net: NetArrays,
    arrays: RingArrays,
    car: CarFollowing,
    route: jax.Array,
    pos: jax.Array,
    speed: jax.Array,
    active: jax.Array,
    dt: float,
) -> MergeLeaders:
    """The `MergeLeaders` of each vehicle, from the state after the move
    (before any change of the step).

    Args:
        net: the step's network (routes are the lane paths).
        arrays: the changer's arrays of the same network.
        car: each vehicle's car-following numbers.
        route, pos, speed, active: (M,) after the move.
        dt: the step (s).
    """
    k, own, on_lane = locate(net, route, pos)
    seen = net.lane_length[own] - on_lane
    reach = brake_gap(speed, car.decel, car.tau, dt) + car.min_gap
    looks = active & (arrays.lane_internal[own] | (seen <= reach))
    link = link_table(net, route, pos, active, car.length)
    own_start = jnp.take_along_axis(net.lane_offset[route], own[:, None], 1)[:, 0]
    sides = []
    for side in (0, 1):
        target_path = arrays.change_path[route, k, side]
        target_lane = arrays.lane_side[own, side]
        can = looks & (target_path >= 0) & (target_lane >= 0)
        path = jnp.where(can, target_path, route)
        lane = jnp.where(can, target_lane, own)
        start = jnp.take_along_axis(net.lane_offset[path], lane[:, None], 1)[:, 0]
        there = jnp.where(can, pos - own_start + start, pos)
        # the next merge of the target path; every vehicle on its partner
        # lane leads a changing vehicle, not only those nearer the crossing
        leader = link_leader_of(net, link, None, path, there, can, car.min_gap)
        sides.append(
            MergeLeaders(
                slot=jnp.where(leader.has, leader.slot, -1),
                gap=leader.gap,
                link_at=leader.to_end,
                critical=leader.to_link <= reach,
            )
        )
    return jax.tree.map(lambda right, left: jnp.stack([right, left], axis=1), *sides)
