"""The phases of a vehicle's speed planning, after SUMO's methods.

`jaxround.core.dynamics.planned_speed` runs them in SUMO's order, each a
function of the state at the start of the step with a NamedTuple result:

1. `start_speeds`: the initial ``v`` of ``MSVehicle::planMoveInternal``, a
   TraCI speed command applied (``MSVehicle::Influencer::influenceSpeed``);
2. `own_leader`: the leader on the vehicle's own lanes and the IDM's follow
   speed (``MSLane::getLeader``, ``MSCFModel_IDM::followSpeed``);
3. `lane_limits`: the speed limits of the lanes ahead and the free road
   (``MSCFModel_IDM::freeSpeed`` in the look-ahead loop of planMoveInternal);
4. `yield_line`: the stop at the yield line and the link leaders at the next
   merge (``vWait``, ``MSLink::getLeaderInfo`` / ``checkLinkLeader``);
5. `look_ahead`: every lane of the look-ahead, its rearmost vehicle and the
   link leaders where it merges, as speed caps on each registration;
6. `registrations`: ``MSVehicle::setApproachingForAllLinks`` (in
   `jaxround.core.junction.register`), after the entry is judged on the
   previous step's registrations;
7. `entry_test`: ``MSLink::opened`` in ``MSVehicle::executeMove``, against
   this step's registrations;
8. `final_speed` in `dynamics`: ``MSCFModel::finalizeSpeed`` and
   ``processTraCISpeedControl``.

Shapes: M vehicle slots, K lanes per route, G legs (one merge each).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxround.core import command as traci
from jaxround.core import idm
from jaxround.core.crossing_leaders import crossing_leader_speed
from jaxround.core.geometry import NetArrays, leaders, locate, past_the_parting
from jaxround.core.insertion import STOP_OFFSET
from jaxround.core.junction import brake_gap
from jaxround.core.link_leaders import link_leader
from jaxround.core.neighbours import NeighbourTables
from jaxround.core.params import CarFollowing

#: Vehicles per leg whose entry is tested each step (the nearest to the line).
ENTRY_CANDIDATES = 2


class Vehicles(NamedTuple):
    """The state the planning reads, (M,) each, at time `t` of the step;
    clock and vid only where internal lanes cross (`crossing_leader_speed`'s)."""

    route: jax.Array
    pos: jax.Array
    speed: jax.Array
    speed_factor: jax.Array
    active: jax.Array
    waiting_s: jax.Array
    clock: jax.Array | None = None
    vid: jax.Array | None = None


class Stepping(NamedTuple):
    """Static settings: dt (s), the IDM's sub-steps, the action step (s)."""

    dt: float
    n_substeps: int
    action_step: float


class StartSpeeds(NamedTuple):
    """`start_speeds`: lane_index int (M,) the route lane each front is on;
    v_lane (M,) the desired speed there; v_start (M,) the speed planning
    starts from; v_max_next, v_min_next (M,) the bounds of the next speed;
    reached bool (M, K) the route lanes SUMO's look-ahead walks onto
    (`look_ahead_reach`): only their leaders, limits and link leaders count."""

    lane_index: jax.Array
    v_lane: jax.Array
    v_start: jax.Array
    v_max_next: jax.Array
    v_min_next: jax.Array
    reached: jax.Array


def start_speeds(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    *,
    step: Stepping,
    command: jax.Array | None,
) -> StartSpeeds:
    """planMoveInternal's initial v; a speed command (M,) (NaN: none)
    replaces it, so every look-ahead speed (registrations, the entry's
    arrival) starts from it."""
    k, lane, _ = locate(net, veh.route, veh.pos)
    v_lane = jnp.minimum(net.lane_speed[lane] * veh.speed_factor, car.max_speed)
    v_max_next = traci.max_next_speed(veh.speed, car, step.dt)
    v_min_next = traci.min_next_speed(veh.speed, car, step.dt)
    v_start = jnp.minimum(veh.speed + car.accel * step.dt, v_lane)
    if command is not None:
        v_start = traci.influence_speed(
            command, v_start, v_safe=v_start, v_max=v_max_next, v_min=v_min_next
        )
    reached = look_ahead_reach(net, car, veh, k, step=step)
    return StartSpeeds(k, v_lane, v_start, v_max_next, v_min_next, reached)


class OwnLeader(NamedTuple):
    """`own_leader`: slot int (M,) the vehicle ahead on the own lanes (-1 for
    none); gap (M,) bumper to bumper; back (M,) its back along the follower's
    route (inf for none); v_follow (M,) the speed the IDM allows behind it."""

    slot: jax.Array
    gap: jax.Array
    back: jax.Array
    v_follow: jax.Array


def own_leader(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    start: StartSpeeds,
    tables: NeighbourTables,
    *,
    step: Stepping,
) -> OwnLeader:
    """The leader with any part ahead on the vehicle's lanes, and the IDM's
    follow speed behind it (SUMO's getLeader, then followSpeed): no follow
    speed behind a leader whose back is on a lane the look-ahead does not
    reach (planMoveInternal meets a lane's last vehicle only on its lanes)."""
    route, pos, speed = veh.route, veh.pos, veh.speed
    fronts = (tables.back + car.length)[route]  # (M, M) along each route
    fronts = jnp.where(past_the_parting(net, route, pos, car.length), jnp.nan, fronts)
    leader, gap = leaders(fronts, pos, veh.active, car.length)
    v_leader = jnp.where(leader >= 0, speed[jnp.maximum(leader, 0)], 0.0)
    v_follow = idm.idm_follow_speed(
        speed, v_leader, gap, start.v_lane, vtype=car.idm, dt=step.dt,
        n_substeps=step.n_substeps,
    )  # fmt: skip
    back = jnp.where(leader >= 0, tables.back[route, jnp.maximum(leader, 0)], jnp.inf)
    back_lane, _, _ = locate(net, route, back)
    seen = jnp.take_along_axis(start.reached, back_lane[:, None], axis=1)[:, 0]
    v_follow = jnp.where(seen | (leader < 0), v_follow, jnp.inf)
    return OwnLeader(leader, gap, back, v_follow)


class LaneLimits(NamedTuple):
    """`lane_limits`: per_lane (M, K) the speed each later lane's limit
    allows (inf on the others); later bool (M, K) the lanes beyond the
    current one; v_limits (M,) their minimum; v_free (M,) the free road up to
    the route's end."""

    per_lane: jax.Array
    later: jax.Array
    v_limits: jax.Array
    v_free: jax.Array


def lane_limits(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    start: StartSpeeds,
    *,
    step: Stepping,
) -> LaneLimits:
    """freeSpeed towards every lower limit ahead, and towards the arrival."""
    route, pos, speed = veh.route, veh.pos, veh.speed
    dt = step.dt
    starts = net.route_lane_start[route]  # (M, K)
    lanes_ahead = net.route_lanes[route]  # (M, K)
    limit_ahead = jnp.minimum(
        net.lane_speed[jnp.maximum(lanes_ahead, 0)] * veh.speed_factor[:, None],
        car.max_speed,
    )
    seen = starts - pos[:, None]
    k = start.lane_index
    later = (jnp.arange(starts.shape[1])[None, :] > k[:, None]) & (lanes_ahead >= 0)
    later = later & start.reached
    columns = car.columns()  # per-vehicle numbers against (M, K) arrays
    v_limits = idm.idm_free_speed_ahead(
        speed[:, None], seen, limit_ahead, start.v_lane[:, None],
        vtype=columns.idm, dt=dt, n_substeps=step.n_substeps,
    )  # fmt: skip
    v_limits = jnp.maximum(v_limits, speed[:, None] - car.decel * dt)
    per_lane = jnp.where(later, v_limits, jnp.inf)  # (M, K)
    to_end = net.route_length[route] - pos
    v_free = idm.idm_free_speed(
        speed, start.v_lane, vtype=car.idm, dt=dt, n_substeps=step.n_substeps,
        seen=to_end,
    )  # fmt: skip
    if not net.all_arrive:  # a lane path that ends on the ring: stop at its end
        # planMoveInternal's dead end: stopSpeed(seen), no offset (libsumo's
        # getStopSpeed at the seen distance gives SUMO's speed to 1e-9)
        v_end = idm.idm_stop_speed(
            speed, to_end, start.v_lane, vtype=car.idm, dt=dt,
            n_substeps=step.n_substeps, action_step=step.action_step,
        )  # fmt: skip
        stops = ~net.route_arrives[route] & start.reached[:, -1]
        v_free = jnp.where(stops, jnp.minimum(v_free, v_end), v_free)
    return LaneLimits(per_lane, later, jnp.min(per_lane, axis=1), v_free)


#: SUMO's CRLL_LOOK_AHEAD (MSVehicle.cpp): vehicle lengths of normal lanes a
#: vehicle looks ahead past its braking distance.
LOOK_AHEAD_LENGTHS = 5.0


def look_ahead_reach(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    lane_index: jax.Array,
    *,
    step: Stepping,
) -> jax.Array:
    """bool (M, K): the route lanes SUMO's look-ahead walks onto; the last
    column reached: the route's end is a dead end to stop at.
    ``MSVehicle::planMoveInternal`` walks the lanes ahead link by link and
    stops after a link once it has seen past its braking distance
    (``dist``), passed a link onto a normal lane, and seen more normal
    metres than ``max(5 * length, length + internal metres)`` (the current
    lane's rest counted as internal if it is one): on a junction's internal
    lane the walk stops sooner than just before it. The lane after that
    link is not walked onto: its last vehicle, its limit and its exit
    link's leaders are not seen. (A planned speed of 0 or a withdrawn
    request, which end the walk too, are left out.)"""
    route, pos = veh.route, veh.pos
    starts = net.route_lane_start[route]  # (M, K)
    lanes = net.route_lanes[route]  # (M, K)
    n_k = starts.shape[1]
    k = lane_index
    nxt = jnp.minimum(k + 1, n_k - 1)[:, None]
    pick = lambda x: jnp.take_along_axis(x, nxt, axis=1)  # noqa: E731  (M, 1)
    ahead = (jnp.arange(n_k)[None, :] > k[:, None]) & (lanes >= 0)
    own_internal = net.lane_internal[jnp.take_along_axis(lanes, k[:, None], axis=1)]
    rest = pick(starts) - pos[:, None]  # the current lane's rest (M, 1)
    normal_seen = net.normal_cum[route] - pick(net.normal_cum[route])  # (M, K)
    internal_seen = net.internal_cum[route] - pick(net.internal_cum[route])
    internal_seen = internal_seen + jnp.where(own_internal, rest, 0.0)
    onto_normal = ~net.lane_internal[jnp.maximum(lanes, 0)] | (normal_seen > 0)
    max_v = jnp.minimum(veh.speed + car.accel * step.dt, car.max_speed)
    dist = max_v * step.dt + brake_gap(max_v, car.decel, car.tau, step.dt)
    length = car.length
    stops_walk = (
        ahead
        & (starts - pos[:, None] > dist[:, None])
        & onto_normal
        & (
            normal_seen
            > jnp.maximum(LOOK_AHEAD_LENGTHS * length, length + internal_seen)
        )
    )
    return jnp.cumsum(stops_walk, axis=1) == 0


def link_leader_speed(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    v_lane: jax.Array,
    may_drive_to_line: jax.Array,
    v_wait: jax.Array,
    *,
    step: Stepping,
    tables: NeighbourTables,
    km_fixed: int | jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """The speed the link leaders at one merge allow (SUMO's checkLinkLeader).

    The nearest link leader binds (IDM's speed falls with the gap); a negative
    gap means "stop before the merging lane"; where `may_drive_to_line`, a
    vehicle may always drive up to its yield line (`v_wait`) while the
    leader's front is still on the merging lane.

    Args:
        may_drive_to_line: bool (M,) the vehicle is before its yield line and
            this is its entry's merge.
        km_fixed: the route lane index of the merge; default the next merge.

    Returns:
        (v, to_link): float (M,) the allowed speed (inf without link leader),
        float (M,) distance to the start of the merging lane.
    """
    speed = veh.speed
    lead = link_leader(
        net, tables, veh.route, veh.pos, veh.active, car.min_gap, km_fixed=km_fixed
    )
    has, nearest, front_on_q, to_link = lead.has, lead.slot, lead.front_on, lead.to_link
    gap = jnp.where(has, lead.gap, 0.0)
    stepping = {"vtype": car.idm, "dt": step.dt, "n_substeps": step.n_substeps}
    v = idm.idm_follow_speed(
        speed, speed[nearest], gap + car.min_gap, v_lane, **stepping
    )
    v_stop = idm.idm_stop_speed(
        speed, to_link - STOP_OFFSET, v_lane, **stepping, action_step=step.action_step
    )
    v = jnp.where(gap >= 0, v, jnp.where(to_link > 0, v_stop, 0.0))
    v = jnp.where(may_drive_to_line & front_on_q, jnp.maximum(v, v_wait), v)
    return jnp.where(has, v, jnp.inf), to_link


class YieldLine(NamedTuple):
    """`yield_line`, (M,) each: to_line the distance to the yield line
    (negative past it); v_wait the speed that stops there; v_link, to_link
    the link leaders' speed at the next merge and the distance to it;
    leave_cap v_link and v_cross before the line (inf after); can_brake the
    vehicle can still stop before the line; before_line active and before
    it; impatience SUMO's getImpatience (grows with the waiting time);
    v_cross the link leaders' speed where the next internal lane crosses
    another (inf without one): SUMO meets them at the exit link, after the
    entry link's arrival and pass speed are set (``planMoveInternal``), so
    they cap the entry's leave speed (``adaptLeaveSpeed``) and the final
    speed, not the entry's approach."""

    to_line: jax.Array
    v_wait: jax.Array
    v_link: jax.Array
    to_link: jax.Array
    leave_cap: jax.Array
    can_brake: jax.Array
    before_line: jax.Array
    impatience: jax.Array
    v_cross: jax.Array


def impatience_after(car: CarFollowing, waiting_s: jax.Array) -> jax.Array:
    """`MSBaseVehicle::getImpatience`: the vType's impatience grown by the
    time waited, over time-to-impatience, within [0, 1]. (M,)."""
    return jnp.clip(car.impatience + waiting_s / car.time_to_impatience, 0.0, 1.0)


def yield_line(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    start: StartSpeeds,
    tables: NeighbourTables,
    *,
    step: Stepping,
) -> YieldLine:
    """The entry's right of way: beyond the visibility distance a vehicle
    always plans to stop at its yield line; within it, only if blocked. The
    link leaders at the next merge cap the entry's leave speed."""
    speed, dt = veh.speed, step.dt
    to_line = net.yield_offset[veh.route] - veh.pos
    v_wait = idm.idm_stop_speed(
        speed, to_line - STOP_OFFSET, start.v_lane, vtype=car.idm, dt=dt,
        n_substeps=step.n_substeps, action_step=step.action_step,
    )  # fmt: skip
    v_wait = jnp.where(to_line > 0, v_wait, 0.0)
    v_link, to_link = link_leader_speed(
        net, car, veh, start.v_lane, to_line > 0, v_wait, step=step, tables=tables
    )
    v_cross = jnp.full_like(v_link, jnp.inf)
    if net.crossing is not None:  # the link leaders on crossing internal lanes
        v_cross = crossing_leader_speed(
            net, car, veh.route, start.lane_index, veh.pos, speed, veh.active,
            start.v_lane, veh.clock, veh.vid,
            dt=dt, n_substeps=step.n_substeps, action_step=step.action_step,
        )  # fmt: skip
    leave_cap = jnp.where(to_line > 0, jnp.minimum(v_link, v_cross), jnp.inf)
    can_brake = (to_line > brake_gap(speed, car.decel, 0.0, dt)) | (
        speed < car.decel * dt
    )
    before_line = veh.active & (to_line > 0)
    impatience = impatience_after(car, veh.waiting_s)
    return YieldLine(
        to_line,
        v_wait,
        v_link,
        to_link,
        leave_cap,
        can_brake,
        before_line,
        impatience,
        v_cross,
    )


def follow_from(
    v: jax.Array,
    v_leader: jax.Array,
    gap: jax.Array,
    *,
    car: CarFollowing,
    v_lane: jax.Array,
    step: Stepping,
) -> jax.Array:
    """SUMO's futureVSafe: followSpeed from a leave speed, (M,) or (M, G)."""
    numbers = car.columns() if v.ndim == 2 else car
    return idm.idm_follow_speed(
        v, v_leader, gap, v_lane[:, None] if v.ndim == 2 else v_lane,
        vtype=numbers.idm, dt=step.dt, n_substeps=step.n_substeps,
    )  # fmt: skip
