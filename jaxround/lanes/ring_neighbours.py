"""Who a vehicle sees when it considers a lane change on a roundabout's lane
paths, and the roundabout bonus: the geometry half of
`jaxround.lanes.ring_changer`.

SUMO's rules as read in docs/lc2013-map.md section 2, and as SUMO 1.28 was
measured to apply them in section 12 there:

- `leader_on` (`MSLaneChanger::getRealLeader`): the nearest vehicle ahead
  on the lane, as the vehicles ahead of the candidate left it; failing
  that, one whose back is still on the lane (it came through the lane:
  not the other lane of a merge); failing that, if the lane ends
  within ``brakeGap(v) + minGap`` (or the candidate is on an internal lane),
  the nearest vehicle on the lanes the path goes on to that begin within
  that distance (`MSLane::getLeaderOnConsecutive`), or on an internal lane
  that leaves the same lane as one of them, not yet past where the two
  part (`MSLink::getLeaderInfo`'s same-source link leaders; the sagitta of
  curved links left out; the merges' link leaders are
  `jaxround.lanes.merge_leaders`').
- `follower_on` (`MSLaneChanger::getRealFollower`): the nearest vehicle
  behind on the lane that has not had its turn; failing that, among the
  vehicles on the lanes upstream (`MSLane::getFollowersOnConsecutive`), the
  one whose secure gap is most violated, one coming over a minor link with
  its gap floored at 0, or one turning off onto the other internal lane
  that leaves the lane before the target, its back still on that lane
  (a partial occupant there). The search examines the lanes leading into the
  target lane, and goes on upstream of a lane only where the distance to
  that lane's start is below the target lane's braking distance at the
  largest speed factor of the vehicles departed so far
  (``MSLane::getMaximumBrakeDist``, ``MSVehicleControl::vehicleDeparted``)
  less the candidate's back position on it, plus its minGap: measured on
  SUMO 1.28 with libsumo's ``getRightFollowers`` (docs/two_lane.md).
- `roundabout_bonus` (`MSLCHelper::getRoundaboutDistBonus`), on the tables
  of `jaxround.lanes.ring_tables`.

Shapes: M vehicle slots, L lanes, P paths, K path positions, Z lanes of an
edge, C, U as in `jaxround.lanes.ring_tables`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core.reductions import first_min
from jaxround.lanes import follow
from jaxround.lanes.follow import Driver
from jaxround.lanes.ring_tables import BONUS_LOOK_AHEAD_M, RingLanes

#: `getRoundaboutDistBonus`: metres of bonus per roundabout junction ahead.
BONUS_PER_JUNCTION_M = 7.5


class RingArrays(NamedTuple):
    """`RingLanes` as device arrays (see there; nan offsets stay nan), the
    upstream lanes as (L, L) tables: a vehicle's lookups read one entry per
    other vehicle instead of matching each against U upstream lanes."""

    lane_length: jax.Array
    lane_speed: jax.Array
    lane_internal: jax.Array
    lane_index: jax.Array
    lane_side: jax.Array  # (L, 2) right and left neighbour
    lane_order: jax.Array  # (L,) scan order of each lane's edge
    path_lanes: jax.Array
    path_lane_start: jax.Array  # +inf padded
    lane_offset: jax.Array
    change_path: jax.Array
    edge_lanes: jax.Array
    laneq_length: jax.Array
    laneq_offset: jax.Array
    laneq_ends: jax.Array
    laneq_next: jax.Array
    bonus_junctions: jax.Array
    bonus_seen: jax.Array
    bonus_distance: jax.Array
    bonus_unjammed: jax.Array
    bonus_outer: jax.Array
    bonus_inner: jax.Array
    bonus_outer_here: jax.Array
    bonus_inner_here: jax.Array
    upstream_m: jax.Array  # (L, L) [x, y]: y's start to x's start, inf: not upstream
    upstream_minor: jax.Array  # (L, L) [x, y]: a minor link between y and x
    follower_brake: jax.Array  # (L,) `MSLane::getMaximumBrakeDist` at a
    # speed factor of 1, for the followers' search
    lane_sibling: jax.Array  # (L,) the internal lane leaving the same lane, -1
    lane_diverge: jax.Array  # (L,) where the two part, from the lane's start

    @classmethod
    def from_tables(cls, tables: RingLanes, min_decel: float) -> RingArrays:
        """Args: the tables; SUMO's smallest decel of the vehicles
        (`MSVehicleControl::getMinDeceleration`), for the followers' search."""
        paths = tables.paths
        f = jnp.result_type(float)
        edge_of = [lid.rsplit("_", 1)[0] for lid in paths.lane_ids]
        edge_rank = {e: r for r, e in enumerate(dict.fromkeys(edge_of))}
        brake = tables.lane_speed**2 * 0.5 / min_decel
        start = np.where(np.isnan(paths.path_lane_start), np.inf, paths.path_lane_start)
        n_lanes = len(paths.lane_ids)
        both_sides = (paths.lane_right >= 0) & (paths.lane_left >= 0)
        if both_sides.any():
            lane = paths.lane_ids[int(np.argmax(both_sides))]
            raise ValueError(
                f"lane {lane} has lanes on both sides: the roundabout's lane "
                "changer takes roads of one or two lanes (one look per turn)"
            )
        upstream_m = np.full((n_lanes, n_lanes), np.inf, np.dtype(f))
        upstream_minor = np.zeros((n_lanes, n_lanes), bool)
        for x, ups in enumerate(tables.upstream_lane):
            for u, y in enumerate(ups):
                if y >= 0:
                    upstream_m[x, y] = tables.upstream_dist[x, u]
                    upstream_minor[x, y] = tables.upstream_minor[x, u]
        return cls(
            lane_length=jnp.asarray(paths.lane_length, f),
            lane_speed=jnp.asarray(tables.lane_speed, f),
            lane_internal=jnp.asarray(paths.lane_internal),
            lane_index=jnp.asarray(paths.lane_index),
            lane_side=jnp.asarray(np.stack([paths.lane_right, paths.lane_left], 1)),
            lane_order=jnp.asarray([edge_rank[e] for e in edge_of]),
            path_lanes=jnp.asarray(paths.path_lanes),
            path_lane_start=jnp.asarray(start, f),
            lane_offset=jnp.asarray(paths.lane_offset, f),
            change_path=jnp.asarray(paths.change_path),
            edge_lanes=jnp.asarray(tables.edge_lanes),
            laneq_length=jnp.asarray(tables.laneq_length, f),
            laneq_offset=jnp.asarray(tables.laneq_offset),
            laneq_ends=jnp.asarray(tables.laneq_ends_in_links),
            laneq_next=jnp.asarray(tables.laneq_next),
            bonus_junctions=jnp.asarray(tables.bonus_junctions),
            bonus_seen=jnp.asarray(tables.bonus_seen, f),
            bonus_distance=jnp.asarray(tables.bonus_distance, f),
            bonus_unjammed=jnp.asarray(tables.bonus_unjammed),
            bonus_outer=jnp.asarray(tables.bonus_outer),
            bonus_inner=jnp.asarray(tables.bonus_inner),
            bonus_outer_here=jnp.asarray(tables.bonus_outer_here),
            bonus_inner_here=jnp.asarray(tables.bonus_inner_here),
            upstream_m=jnp.asarray(upstream_m, f),
            upstream_minor=jnp.asarray(upstream_minor),
            follower_brake=jnp.asarray(brake, f),
            lane_sibling=jnp.asarray(tables.lane_sibling, jnp.int32),
            lane_diverge=jnp.asarray(tables.lane_diverge, f),
        )


class Scene(NamedTuple):
    """The vehicles as a candidate sees them at its turn. (M,) each.

    Attributes:
        lane: lanes, as the vehicles ahead of the candidate left them.
        on_lane: front position on the lane (m).
        speed: m/s; driver: `Driver` of (M,) arrays.
        others: active and not the candidate.
        done: had its turn this step.
        fastest_departed: float () the largest speed factor of the vehicles
            departed so far, at least 1 (``MSVehicleControl::getMaxSpeedFactor``).
        path: int (M,) each vehicle's lane path before the step's changes,
            for the lane its back came through (None: any lane upstream).
    """

    lane: jax.Array
    on_lane: jax.Array
    speed: jax.Array
    driver: Driver
    others: jax.Array
    done: jax.Array
    fastest_departed: jax.Array | float = 1.0
    path: jax.Array | None = None


def leader_on(
    net: RingArrays,
    scene: Scene,
    i: jax.Array,
    path: jax.Array,
    target: jax.Array,
    own: jax.Array,
    dt: float,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Vehicle ``i``'s leader on lane ``target`` of ``path`` (its own lane
    ``own`` or a neighbour): (slot, exists, gap net of its minGap)."""
    lane, on_lane, driver = scene.lane, scene.on_lane, scene.driver
    pos_i, min_gap_i = on_lane[i], driver.min_gap[i]
    me = jax.tree.map(lambda x: x[i], driver)
    front = net.lane_offset[path, lane] + on_lane  # along the path, nan: off it
    back = front - driver.length
    me_at = net.lane_offset[path, target] + pos_i
    lane_end = net.lane_offset[path, target] + net.lane_length[target]
    ahead_on_lane = (on_lane > pos_i) | ((on_lane == pos_i) & scene.done)
    same = scene.others & (lane == target) & ahead_on_lane
    # partly on the target: the front on a lane the target leads to (on
    # this path or not: MSLane's partial occupators), the back on the target
    to_start = net.upstream_m[lane, target]  # (M,) inf: target not upstream
    back_on_target = to_start + on_lane - driver.length  # along the target lane
    partly = (
        scene.others & (lane != target) & jnp.isfinite(to_start)
        & (back_on_target < net.lane_length[target])
    )  # fmt: skip
    if scene.path is not None:
        # only on the lane it came through (not the other of a merge): the
        # target on its path, or its lane off it (changed this step)
        partly = partly & (
            jnp.isfinite(net.lane_offset[scene.path, target])
            | jnp.isnan(net.lane_offset[scene.path, lane])
        )
    dist = follow.brake_gap(me, scene.speed[i], dt) + min_gap_i
    lane_start_j = net.lane_offset[path, lane]
    reach = ((lane_end - me_at <= dist) & (lane_start_j - me_at <= dist)) | (
        net.lane_internal[own]
    )
    # on the path after the target: compared by where the lanes start (in
    # float32 a start and the target's offset + length can round apart)
    target_start = net.lane_offset[path, target]
    later = scene.others & (lane != target) & (lane_start_j > target_start) & reach
    gap = back - me_at - min_gap_i
    # on the internal lane that leaves the same lane as one of the path's
    # from the target on, its back not yet past where the two part: a
    # same-source link leader, its back as far before that lane's parting
    # point as before its own; none once i is its length past that point
    parts_from = jnp.maximum(net.lane_sibling[lane], 0)  # (M,)
    its_start = net.lane_offset[path, parts_from]  # nan: not on the path
    parting = its_start + net.lane_diverge[parts_from]
    back_to_parting = on_lane - driver.length - net.lane_diverge[lane]
    diverging = (
        scene.others & (net.lane_sibling[lane] >= 0) & (back_to_parting < 0.0)
        & (its_start >= target_start) & (me_at - parting <= driver.length[i])
        & (((lane_end - me_at <= dist) & (its_start - me_at <= dist))
           | net.lane_internal[own])
    )  # fmt: skip
    later = later | diverging
    gap = jnp.where(diverging, parting + back_to_parting - me_at - min_gap_i, gap)

    def within(mask: jax.Array, gaps: jax.Array = gap) -> jax.Array:
        return jnp.where(mask, gaps, jnp.inf)

    partly_gap = back_on_target - pos_i - min_gap_i
    first = jnp.where(
        jnp.any(same), within(same),
        jnp.where(jnp.any(partly), within(partly, partly_gap), within(later)),
    )  # fmt: skip
    gap_to, slot = first_min(first)
    return slot, jnp.isfinite(gap_to), gap_to


def follower_on(
    net: RingArrays, scene: Scene, i: jax.Array, target: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Vehicle ``i``'s follower on lane ``target``: (slot, exists, gap net of
    the follower's minGap)."""
    lane, on_lane, driver = scene.lane, scene.on_lane, scene.driver
    back_i = on_lane[i] - driver.length[i]
    same = scene.others & ~scene.done & (lane == target) & (on_lane <= on_lane[i])
    d_same = jnp.where(same, back_i - on_lane - driver.min_gap, jnp.inf)
    search = (
        net.follower_brake[target] * jnp.square(scene.fastest_departed)
        - back_i + driver.min_gap[i]
    )  # fmt: skip
    # vehicle j on a lane upstream of the target: the lanes into the target
    # are examined, the lanes before a lane only within the search
    up_dist = net.upstream_m[target, lane]  # (M,) inf: not upstream
    before = up_dist - net.lane_length[lane]  # to the start of the lane after
    reached = (before <= 0.0) | (before < search)
    agap = up_dist - on_lane + back_i - driver.min_gap
    agap = jnp.where(net.upstream_minor[target, lane], jnp.maximum(agap, 0.0), agap)
    ok = jnp.isfinite(up_dist) & reached & scene.others
    # turning off onto the other internal lane that leaves the target's lane,
    # its back still on that lane: a partial occupant the search meets there
    beside = (
        scene.others & (net.lane_sibling[lane] == target) & (on_lane < driver.length)
    )
    agap_j = jnp.where(  # (M,)
        ok, agap, jnp.where(beside, back_i - on_lane - driver.min_gap, jnp.inf)
    )
    missing = follow.secure_gap(driver, scene.speed, scene.speed[i]) - agap_j
    _, up_slot = first_min(jnp.where(jnp.isfinite(agap_j), -missing, jnp.inf))
    has_up = jnp.isfinite(agap_j[up_slot])
    same_gap, same_slot = first_min(d_same)
    has_same = jnp.isfinite(same_gap)
    slot = jnp.where(has_same, same_slot, up_slot)
    gap = jnp.where(has_same, same_gap, agap_j[up_slot])
    return slot, has_same | has_up, gap


def roundabout_bonus(
    net: RingArrays,
    occupied: jax.Array,
    at: tuple[jax.Array, ...],
    own: jax.Array,
    pos: jax.Array,
    cooperative: jax.Array,
) -> jax.Array:
    """`getRoundaboutDistBonus` (m) for the look tabled at ``at`` = (path,
    position, own lane index, side), with the lanes' summed lengths with gap
    ``occupied`` (L,), the vehicle on lane ``own`` at ``pos``."""
    junctions = net.bonus_junctions[at]
    length = net.lane_length[own]

    def occupancy(lanes: jax.Array, here: jax.Array) -> jax.Array:
        weight = jnp.where(here, (length - pos) / length, 1.0)
        load = occupied[jnp.maximum(lanes, 0)] * weight
        return jnp.sum(jnp.where(lanes >= 0, load, 0.0))

    outer = occupancy(net.bonus_outer[at], net.bonus_outer_here[at])
    inner = occupancy(net.bonus_inner[at], net.bonus_inner_here[at])
    most = jnp.maximum(outer, inner)
    extra = BONUS_PER_JUNCTION_M * junctions
    jam = jnp.maximum(0.0, (outer - inner + extra) / jnp.maximum(most + extra, 1e-9))
    # 1.28: the jam factor only where the vehicle is off the roundabout or
    # looks left, and an empty roundabout's bonus is not left out
    jam = jnp.where(net.bonus_unjammed[at], 1.0, jam)
    value = net.bonus_distance[at] * jam * cooperative * 9.0
    applies = (junctions >= 2) & (net.bonus_seen[at] - pos <= BONUS_LOOK_AHEAD_M)
    return jnp.where(applies, value, 0.0)
