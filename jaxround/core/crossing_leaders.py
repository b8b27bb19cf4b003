"""Link leaders on crossing internal lanes (SUMO's ``MSLink::getLeaderInfo``
for a foe lane that crosses, ``MSVehicle::checkLinkLeader``,
``MSVehicle::isLeader`` and ``MSVehicle::adaptToJunctionLeader``).

A vehicle whose route takes an internal lane that crosses another (the left
entry lane's link across the outer ring lane's, `jaxround.core.crossing_tables`)
is led by every vehicle touching the foe lane that has not passed the
conflict area, as SUMO 1.28 does:

- skipped once the vehicle is past the area (``distToCrossing + conflictSize
  < 0``), and a foe past it (``leaderBackDist + foeConflictSize < 0``);
  after the vehicle entered the area, only foes in the way (entered the area,
  not past it) count;
- before the junction every such foe leads (``MSVehicle::isLeader``); on
  the junction a foe leads if it is only partly on it (its front beyond the
  foe lane) or if it came first: the yielding link's vehicle (the entry's)
  compares the time it entered the conflict area with the time the foe
  entered the junction, the ring's vehicle its own junction entry with the
  foe's conflict entry (`conflict_clock`: the same instant where no
  internal junction splits a link, as in every scenario here); at the same
  time the faster leads, then the smaller id (``v00012`` before
  ``v00013``: the schedule's order);
- the gap is ``distToCrossing - minGap - leaderBackDist - foeConflictSize``:
  the IDM follows a foe at a non-negative gap, a negative one stops the
  vehicle at the start of its lane; then, as the foe moves off the crossing,
  the vehicle may still reach the conflict area as the foe leaves it (the
  speed ``v2`` of ``adaptToJunctionLeader``, at most the speed that stops
  minGap before the area); before the junction the vehicle may always drive
  up to its link (``lastLink->myVLinkWait``: 1 m before a major link, 0.1 m
  before a minor one, `jaxround.core.insertion.link_stop_distance`).

Not ported: the sagitta of curved links (``myRadius``: 0 here), foes that
will not pass (every foe on an internal lane does here), the bicycle and
pedestrian cases, a vehicle giving up its entry time when it withdraws its
request on the junction (``MSVehicle::processLinkApproaches``: only behind a
foe waiting over 5 s, ``JUNCTION_BLOCKAGE_TIME``).

Shapes: M vehicle slots.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core import idm
from jaxround.core.geometry import NetArrays, locate
from jaxround.core.insertion import link_stop_distance
from jaxround.core.params import CarFollowing

#: SUMO's ``POSITION_EPS`` (m).
POSITION_EPS = 0.1
#: SUMO's ``SUMO_const_haltingSpeed`` (m/s).
HALTING_SPEED = 0.1


def conflict_clock(
    net: NetArrays,
    route: jax.Array,
    pos: jax.Array,
    active: jax.Array,
    clock: jax.Array,
    t: jax.Array,
) -> jax.Array:
    """When each vehicle's front entered the internal lane that leaves its
    junction, float (M,) (+inf while elsewhere): SUMO's
    ``myJunctionConflictEntryTime``, set in ``MSVehicle::enterLaneAtMove``
    at a link that enters the conflict area (``MSLink::isConflictEntryLink``),
    cleared at the exit link. Called after the move of the step that began
    at `t`, with the previous step's `clock`; route, pos, active (M,)."""
    k, lane, _ = locate(net, route, pos)
    k_next = jnp.minimum(k + 1, net.route_lanes.shape[1] - 1)
    lane_next = jnp.take_along_axis(net.route_lanes[route], k_next[:, None], axis=1)
    last_internal = net.lane_internal[lane] & ~net.lane_internal[lane_next[:, 0]]
    inside = active & last_internal
    return jnp.where(inside, jnp.minimum(clock, t), jnp.inf)


def crossing_leader_speed(
    net: NetArrays,
    car: CarFollowing,
    route: jax.Array,
    lane_index: jax.Array,
    pos: jax.Array,
    speed: jax.Array,
    active: jax.Array,
    v_lane: jax.Array,
    clock: jax.Array,
    vid: jax.Array,
    *,
    dt: float,
    n_substeps: int,
    action_step: float,
) -> jax.Array:
    """The speed the link leaders on each vehicle's next crossing allow,
    float (M,) (inf without one). route, lane_index (the route lane of each
    front, `planning.StartSpeeds`), pos, speed, active: (M,) each; v_lane
    (M,) the desired speed."""
    cx = net.crossing
    m = pos.shape[0]
    k = lane_index[:, None]
    row = jnp.take_along_axis(cx.next_row[route], k, axis=1)[:, 0]
    kc = jnp.take_along_axis(cx.next_index[route], k, axis=1)[:, 0]
    has = (row >= 0) & active
    row = jnp.maximum(row, 0)
    lane = cx.lane[row]
    start = jnp.take_along_axis(net.route_lane_start[route], kc[:, None], axis=1)[:, 0]
    to_link = start - pos  # to the start of the crossing lane (its entry link)
    to_cross = to_link + net.lane_length[lane] - cx.behind[row]  # distToCrossing
    has = has & (to_cross + cx.size[row] >= 0)
    on_junction = to_link <= 0

    # every vehicle j touching the foe lane of i's crossing, (M_i, M_j)
    foe = cx.foe[row]
    length = jnp.broadcast_to(car.length, (m,))
    off = net.lane_offset[route[None, :], foe[:, None]]  # where it starts for j
    on_route = ~jnp.isnan(off)
    off = jnp.where(on_route, off, 0.0)  # no nan in the step (nor its gradient)
    back_on = pos[None, :] - length[None, :] - off
    foe_len = net.lane_length[foe][:, None]
    others = jnp.arange(m)[None, :] != jnp.arange(m)[:, None]
    touches = (pos[None, :] - off > 0) & (back_on < foe_len) & on_route
    touches = touches & active[None, :] & others
    back_dist = foe_len - cx.foe_behind[row][:, None] - back_on  # leaderBackDist
    foe_size = cx.foe_size[row][:, None]
    past = back_dist + foe_size < 0
    in_way = ~past & (to_cross[:, None] > 0) & (back_dist < length[None, :])
    entered_area = to_cross[:, None] < -POSITION_EPS
    leads = touches & ~past & (in_way | ~entered_area)
    # isLeader: who came first (a vehicle with its front on the foe lane is
    # on the junction; one touching it from beyond only partly)
    ego_time, foe_time = clock[:, None], clock[None, :]
    foe_front_on = pos[None, :] - off <= foe_len
    tie = (ego_time == foe_time) & (
        (speed[:, None] < speed[None, :])
        | ((speed[:, None] == speed[None, :]) & (vid[:, None] < vid[None, :]))
    )
    first = ~foe_front_on | (ego_time > foe_time) | tie
    leads = leads & (~on_junction[:, None] | first | in_way)

    min_gap = jnp.broadcast_to(car.min_gap, (m,))[:, None]
    gap = to_cross[:, None] - min_gap - back_dist - foe_size
    cols = car.columns()
    stepping = {"vtype": cols.idm, "dt": dt, "n_substeps": n_substeps}
    v = speed[:, None]
    v_follow = idm.idm_follow_speed(
        v, speed[None, :], gap + min_gap, v_lane[:, None], **stepping
    )
    # the stop before the crossing lane's own link (``myVLinkWait``): 1 m
    # before the ring's through link, 0.1 m before an entry's
    link_stop = link_stop_distance(to_link, speed, car.decel, dt, ~cx.minor[row])
    v_stop_link = idm.idm_stop_speed(
        speed, link_stop, v_lane, vtype=car.idm, dt=dt,
        n_substeps=n_substeps, action_step=action_step,
    )  # fmt: skip
    v_stop_link = jnp.where(to_link > 0, v_stop_link, 0.0)
    v_safe = jnp.where(gap >= 0, v_follow, v_stop_link[:, None])
    # the foe may leave the area before the vehicle reaches it
    v_stop_area = idm.idm_stop_speed(
        speed, to_cross - min_gap[:, 0], v_lane, vtype=car.idm, dt=dt,
        n_substeps=n_substeps, action_step=action_step,
    )[:, None]  # fmt: skip
    leader_to_cross = jnp.maximum(to_cross[:, None] - gap, POSITION_EPS)  # > 0 if led
    past_cp_s = leader_to_cross / jnp.maximum(speed[None, :], HALTING_SPEED)
    v_final = jnp.maximum(v, 2 * (to_cross[:, None] - min_gap) / past_cp_s - v)
    v_reach = v + (v_final - v) / past_cp_s * dt
    v_safe = jnp.where(
        to_cross[:, None] >= 0,
        jnp.maximum(v_safe, jnp.minimum(v_reach, v_stop_area)),
        v_safe,
    )
    v_cross = jnp.min(jnp.where(leads, v_safe, jnp.inf), axis=1)
    led = has & jnp.any(leads, axis=1)
    # before the junction the vehicle may still drive up to its link
    v_cross = jnp.where(~on_junction, jnp.maximum(v_cross, v_stop_link), v_cross)
    return jnp.where(led, v_cross, jnp.inf)
