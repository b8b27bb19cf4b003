"""The changer's last check before an entry: a foe at the target lane's
entry link holds the change back.

SUMO's `MSLaneChanger::checkChange` ends a wanted, unblocked change with
`MSVehicle::unsafeLinkAhead(targetLane)`: the minor links ahead on the
target lane are tested with `MSLink::hasApproachingFoe` at the times of the
vehicle's own approach (its drive item), and a foe that would be in the
way, or a vehicle on a foe link's internal lane, blocks the change. On a
roundabout the only minor links are the entries, so the test is the one
entry of the target lane, for a vehicle still before its yield line; a left
entry lane's link has one foe more than the right one's (the outer ring
lane's through link, which it crosses), so a change to it can be held where
staying is not.

`MSLink::hasApproachingFoe` has two halves: a foe link's registered
vehicles whose times would conflict (`MSLink::blockedAtTime`), and a foe
link's internal lane with a vehicle on it, partly or whole
(`getVehicleNumberWithPartials`). `held_by_occupied` is the second,
`held_by_approaching` the first (`MSLink::blockedByFoe` over the step's
registrations on the link's foe through links, as `jaxround.core.junction`
tests an entry, with `MSLink`'s 1 s look-ahead, no impatience, and the
vehicle's approach planned from where the move left it). SUMO 1.28 holds
changes at any distance from the line (the 2024 source only within the
vehicle's braking distance), with every `LCA_BLOCKED` bit set
(`jaxround.lanes.actions.HELD`, measured with
`libsumo.vehicle.getLaneChangeState`), by a condition not in any source
read here (docs/lc2013-map.md section 12, "What holds it back"). Both
halves applied at any distance were measured in the step
(`LaneChanger(hold_entries=...)`, 2026-11-27) and neither is SUMO's rule,
so the step does not hold by default:

- both: 7,419 held vehicle-steps in the first 900 s of two_lane.yaml
  where SUMO held 848; crossing times 51% over SUMO's (61.6 s against
  40.7 s, human drivers, schedule seeds 0-2).
- the occupied lanes alone: 1,090 held; against SUMO at 0 / 50 / 100%
  uncontrolled AVs crossing time +1.2 / -1.7 / -0.5% and CO2 -0.0 / -2.2
  / -1.4% (without the hold -1.6 / -3.4 / -1.8% and -3.3 / -4.7 /
  -3.8%), but on the held-out five-leg roundabout +8.3% and +5.0%
  (without: +4.2%, +1.6%), and decision by decision (the replay of
  `jaxround.apps.ring_lane_replay`, 600 s) 312 of SUMO's 414 changes
  made in the same step against 384 without it: it holds changes SUMO
  makes.

Shapes: M vehicle slots, G entries.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core.geometry import NetArrays
from jaxround.core.junction import entry_approach, entry_blocked
from jaxround.core.params import CarFollowing
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
    (`hasApproachingFoe`'s first half; not used by the step, see the
    module's docstring).

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
