"""The changer's last check before an entry: a change onto the other entry
lane is held back while that lane's entry link would not be open to the
vehicle.

SUMO 1.28's `MSLaneChanger::checkChange`, as its compiled code in the
eclipse-sumo 1.28.0 wheel shows (`_libsumo.so` keeps its symbols; no 1.28
source was at hand: docs/lc2013-map.md section 12, "What holds it back"),
ends a wanted change that nothing blocked with two tests:

- `MSVehicle::unsafeLinkAhead(targetLane, zipperDist)`: the minor links
  ahead on the target lane within the vehicle's braking distance (at
  headway 0; at least the edge's zipper distance, 0 without zipper links)
  tested with `MSLink::hasApproachingFoe` at the times of the vehicle's own
  drive item. Not ported (tried once: docs/lc2013-map.md section 12).
- new in 1.28 (apparently SUMO issue 17411, "a neighboring lane has additional foe
  links to consider"), on an edge whose lanes' links differ in their foes
  (`postloadInitLC`): for a vehicle on a normal lane whose link to its best
  continuation is an entry link, that link's parallel link on the target
  side (`MSLink::getParallelLink`) must be `opened` to the vehicle's own
  registration on its link (`getApproachingPtr`: arrival time and speed,
  leave speed), with its length, impatience and decel; a closed link sets
  every `LCA_BLOCKED` bit (`jaxround.lanes.actions.HELD`, as
  `libsumo.vehicle.getLaneChangeState` shows). No distance limit: a vehicle
  registers on its entry from anywhere on the lane, and whether a foe is in
  the way depends on when the vehicle would arrive.

`held_by_parallel_link` is the second, the step's hold by default
(`LaneChanger(hold_entries="parallel")`): the target lane's entry tested as
`jaxround.core.junction.entry_blocked` tests a vehicle's own entry, with
the approach the step registered and tested for it (`jaxround.core.dynamics.
Planned.own_entry`). On two_lane.yaml, human drivers, it holds 1,693
vehicle-steps in the first 600 s of schedule seeds 0-2 where SUMO holds
1,673 (`tests/sumo/test_lane_hold_probe.py`; 839 against 848 in the first
900 s of seed 0 before the roundabout bonus followed 1.28).

Two earlier readings, measured in the step before 1.28's code was read and
kept for comparison (``hold_entries="occupied"`` and ``"approaching"``):

- `held_by_approaching`, `hasApproachingFoe`'s half that tests a foe link's
  registered vehicles (`MSLink::blockedByFoe` over the step's registrations
  on the link's foe through links, with `MSLink`'s 1 s look-ahead, no
  impatience, and the vehicle's approach planned from where the move left
  it), at any distance, with the occupied lanes below: 7,419 held
  vehicle-steps in the first 900 s where SUMO held 848; crossing times 51%
  over SUMO's.
- `held_by_occupied`, the other half (a foe link's internal lane with a
  vehicle on it, `getVehicleNumberWithPartials`): 1,090 held; against SUMO
  at 0 / 50 / 100% uncontrolled AVs crossing time +1.2 / -1.7 / -0.5% and
  CO2 -0.0 / -2.2 / -1.4%, but the held-out five-leg roundabout +8.3% and
  +5.0%, and decision by decision (`jaxround.apps.ring_lane_replay`, 600 s)
  312 of SUMO's 414 changes made in the same step against 384 without it.

Shapes: M vehicle slots, G entries.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core.geometry import NetArrays
from jaxround.core.junction import Approach, entry_approach, entry_blocked
from jaxround.core.params import CarFollowing
from jaxround.core.planning import impatience_after
from jaxround.core.state import Registrations
from jaxround.lanes.ring_changer import locate
from jaxround.lanes.ring_neighbours import RingArrays

#: `MSLink::myLookaheadTime`: the time gap of `blockedByFoe` without an ego (s).
LINK_LOOKAHEAD_S = 1.0


def occupied_through_lanes(
    net: NetArrays, route: jax.Array, pos: jax.Array, length: jax.Array,
    active: jax.Array,
) -> jax.Array:  # fmt: skip
    """bool (G,): some vehicle's front or back is on entry g's ring through
    lane (`MSLane::getVehicleNumberWithPartials` of a foe link's lane)."""
    start = net.conflict_offset[route]  # (M, G), nan where not passed
    end = start + net.through_length[None, :]
    back = pos - jnp.broadcast_to(length, pos.shape)
    on = (pos[:, None] > start) & (back[:, None] < end)
    return jnp.any(on & active[:, None] & ~jnp.isnan(start), axis=0)


def targets(
    net: NetArrays, arrays: RingArrays, route: jax.Array, pos: jax.Array,
    active: jax.Array,
) -> tuple[jax.Array, jax.Array]:  # fmt: skip
    """The lane path a change right / left would take, int (M, 2) (-1: no
    change there or the vehicle is past its yield line), and the entry each
    leads to, int (M, 2)."""
    k, _, _ = locate(arrays, route, pos)
    before_line = active & (net.yield_offset[route] - pos > 0)
    path = jnp.where(before_line[:, None], arrays.change_path[route, k], -1)
    return path, net.route_origin[jnp.maximum(path, 0)]


def held_by_occupied(
    net: NetArrays, arrays: RingArrays, route: jax.Array, pos: jax.Array,
    length: jax.Array | float, active: jax.Array,
) -> jax.Array:  # fmt: skip
    """bool (M, 2): a change right / left would be held back because a foe
    link of the target lane's entry has a vehicle on its internal lane
    (`hasApproachingFoe`'s second half). ``length``: (M,) or a scalar."""
    path, entry = targets(net, arrays, route, pos, active)
    occupied = occupied_through_lanes(net, route, pos, length, active)
    crossed = net.entry_crossing[entry]
    foe = occupied[entry] | ((crossed >= 0) & occupied[jnp.maximum(crossed, 0)])
    return (path >= 0) & foe


def held_by_approaching(
    net: NetArrays,
    arrays: RingArrays,
    car: CarFollowing,
    route: jax.Array,
    pos: jax.Array,
    speed: jax.Array,
    speed_factor: jax.Array,
    active: jax.Array,
    regs: Registrations,
    t: jax.Array,
    dt: float,
) -> jax.Array:
    """bool (M, 2): a change right / left would be held back because a foe
    registered on a foe link of the target lane's entry would be in the way
    (`hasApproachingFoe`'s first half at any distance; an earlier reading,
    see the module's docstring).

    Args:
        car: each vehicle's car-following numbers, (M,) or scalars.
        route, pos, speed, speed_factor, active: the vehicles after the move.
        regs: the registrations of the step just moved (times absolute).
        t: the time after the move (s).
    """
    m = route.shape[0]
    path, _ = targets(net, arrays, route, pos, active)
    lane = net.route_lanes[route, 0]
    v_lane = jnp.minimum(net.lane_speed[lane] * speed_factor, car.max_speed)
    foe_car = car.replace(jm_timegap_minor=LINK_LOOKAHEAD_S)
    held = []
    for side in (0, 1):
        to = jnp.maximum(path[:, side], 0)
        ego = entry_approach(
            net, car, to, pos, speed, speed_factor, v_lane, jnp.inf, t, dt
        )
        held.append(
            entry_blocked(net, foe_car, to, ego, regs, jnp.zeros(m), t + dt, dt)
        )
    return (path >= 0) & jnp.stack(held, axis=1)


def held_by_parallel_link(
    net: NetArrays,
    arrays: RingArrays,
    car: CarFollowing,
    route: jax.Array,
    pos: jax.Array,
    active: jax.Array,
    waiting_s: jax.Array,
    regs: Registrations,
    own_entry: Approach,
    t: jax.Array,
    dt: float,
) -> jax.Array:
    """bool (M, 2): SUMO 1.28's hold of a change right / left before an
    entry (the module's docstring): the target lane's entry link, tested
    with the vehicle's own approach, is closed. Every edge with an entry
    counts as one whose links differ in their foes (a left entry lane's link
    crosses the outer ring lane, the right one's does not); `MSLink::opened`'s
    distance argument is not read, as in the step's own entry test.

    Args:
        car: each vehicle's car-following numbers, (M,) or scalars.
        route, pos, active, waiting_s: the vehicles after the move.
        regs: the registrations of the step just moved (times absolute).
        own_entry: each vehicle's approach to its own entry link as the step
            registered it (`jaxround.core.dynamics.Planned.own_entry`).
        t: the time at the start of the step just moved (s).
    """
    path, entry = targets(net, arrays, route, pos, active)
    impatience = impatience_after(car, waiting_s)  # the waiting time after the move
    # roads have one or two lanes (`jaxround.scenario.roads.LANE_COUNTS`), so
    # a vehicle has a lane beside it on one side at most: one test per vehicle
    side = (path[:, 1] >= 0).astype(jnp.int32)
    to = jnp.maximum(jnp.take_along_axis(path, side[:, None], axis=1)[:, 0], 0)
    target_entry = jnp.take_along_axis(entry, side[:, None], axis=1)[:, 0]
    # MSLink::getLeaveTime over the parallel link's own internal lane
    speed = 0.5 * (own_entry.arrival_speed + own_entry.leave_speed)
    leave = own_entry.arrival + (
        net.entry_internal_length[target_entry] + car.length
    ) / jnp.maximum(speed, 1e-3)
    ego = own_entry._replace(leave=leave)
    held = entry_blocked(net, car, to, ego, regs, impatience, t + dt, dt)
    return (path >= 0) & held[:, None]
