"""The entry's right of way in a vehicle's planning: phases 5 to 7 of
`jaxround.core.planning` (the look-ahead, the registrations, the entry test).

Shapes: M vehicle slots, K lanes per route, G legs (one merge each), C the
entry candidates (`planning.ENTRY_CANDIDATES` per leg).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxround.core import idm
from jaxround.core.geometry import NetArrays
from jaxround.core.insertion import link_stop_distance
from jaxround.core.junction import (
    Approach,
    brake_gap,
    entry_approach,
    entry_blocked,
    entry_blocked_weight,
    entry_candidates,
    register,
)
from jaxround.core.merge_prefixes import at_lane, merge_prefixes, prefix_min
from jaxround.core.neighbours import (
    NeighbourTables,
    on_entry_lane,
    on_through_lanes,
    rearmost_on_lanes,
)
from jaxround.core.params import CarFollowing
from jaxround.core.planning import (
    ENTRY_CANDIDATES,
    LaneLimits,
    OwnLeader,
    StartSpeeds,
    Stepping,
    Vehicles,
    YieldLine,
    follow_from,
    link_leader_speed,
)
from jaxround.core.state import Registrations


class LookAhead(NamedTuple):
    """`look_ahead`: rearmost (has, slot, gap), the rearmost vehicle of every
    lane of the look-ahead, (M, K) each; v_link_k (M, K) the link leaders'
    speed where lane k merges (inf elsewhere); three caps on the
    registration at each leg's merge, (M, G): v_pre on the arrival speed
    (limits, leaders and link leaders before the merge), ring_cap on it from
    a leader on the lane into the merge, via_cap on the leave speed from
    link leaders past it."""

    rearmost: tuple[jax.Array, jax.Array, jax.Array]
    v_link_k: jax.Array
    v_pre: jax.Array
    ring_cap: jax.Array
    via_cap: jax.Array


def look_ahead(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    start: StartSpeeds,
    leader: OwnLeader,
    limits: LaneLimits,
    line: YieldLine,
    tables: NeighbourTables,
    *,
    step: Stepping,
) -> LookAhead:
    """Every lane of the look-ahead: its rearmost vehicle, and the link
    leaders where it merges (the loop of SUMO's planMoveInternal), as caps on
    the speeds each registration announces."""
    route, pos, speed = veh.route, veh.pos, veh.speed
    m = pos.shape[0]
    rearmost = rearmost_on_lanes(net, tables, route, pos, veh.active)  # (M, K)
    starts = net.route_lane_start[route]  # (M, K)
    conflict_offset = net.conflict_offset[route]  # (M, G)
    # the lanes before each merge: prefixes and single lanes of the route
    # (`jaxround.core.merge_prefixes`), read per vehicle, (M, G) each
    lanes_before = jax.tree.map(lambda table: jnp.asarray(table)[route],
                                merge_prefixes(net))  # fmt: skip
    lim_before = prefix_min(limits.per_lane, lanes_before.starts_before)
    merge_start = pos + line.to_link
    link_before = merge_start[:, None] < conflict_offset
    v_pre = jnp.minimum(start.v_start[:, None], lim_before)
    v_pre = jnp.where(link_before, jnp.minimum(v_pre, line.v_link[:, None]), v_pre)
    prev_start = conflict_offset - net.prev_lane_length[route]
    lead_early = leader.back[:, None] < prev_start
    lead_ring = ~lead_early & (leader.back[:, None] < conflict_offset)
    v_own = leader.v_follow[:, None]
    v_pre = jnp.where(lead_early, jnp.minimum(v_pre, v_own), v_pre)
    ring_cap = jnp.where(lead_ring, v_own, jnp.inf)
    lanes_k = net.route_lanes[route]
    columns = car.columns()
    ahead_has, ahead_slot, ahead_gap = rearmost
    v_follow_k = idm.idm_follow_speed(
        speed[:, None], speed[ahead_slot], ahead_gap, start.v_lane[:, None],
        vtype=columns.idm, dt=step.dt, n_substeps=step.n_substeps,
    )  # fmt: skip
    k = start.lane_index
    mine = (jnp.arange(starts.shape[1])[None, :] >= k[:, None]) & (lanes_k >= 0)
    v_follow_k = jnp.where(ahead_has & mine & start.reached, v_follow_k, jnp.inf)
    v_pre = jnp.minimum(v_pre, prefix_min(v_follow_k, lanes_before.ends_early))
    ring_cap = jnp.minimum(ring_cap, at_lane(v_follow_k, lanes_before.ends_at))

    def link_leaders_at(merge_k: jax.Array) -> jax.Array:
        """The link leaders' speed at the merge of route lane `merge_k`, (M,)."""
        v, _ = link_leader_speed(
            net, car, veh, start.v_lane, (line.to_line > 0) & (merge_k == 1),
            line.v_wait, step=step, tables=tables, km_fixed=merge_k,
        )  # fmt: skip
        return v

    # only lanes that merge can have link leaders; one vmapped program for
    # all of them (not one copy per merge: the step compiles faster)
    merges = jnp.asarray(net.merge_positions, jnp.int32)
    v_link_k = jnp.full((m, starts.shape[1]), jnp.inf)
    if merges.size:
        v_link_k = v_link_k.at[:, merges].set(
            jax.vmap(link_leaders_at, out_axes=1)(merges)
        )
    v_link_k = jnp.where(start.reached, v_link_k, jnp.inf)
    v_pre = jnp.minimum(v_pre, prefix_min(v_link_k, lanes_before.starts_clearly_before))
    via_cap = at_lane(v_link_k, lanes_before.starts_at)
    return LookAhead(rearmost, v_link_k, v_pre, ring_cap, via_cap)


class Requests(NamedTuple):
    """`registrations`: regs this step's `Registrations` (M, G); approach_cap
    (M,) the cap leaders on the approach put on the arrival speed;
    candidates int (C,) the slots whose entry is tested, candidate_ok bool
    (C,) a vehicle is there; beyond_visibility bool (M,) still too far from
    the line to see the ring; slowed bool (M,) could still brake for its
    entry, so it requests no later link (SUMO's slowedDownForMinor)."""

    regs: Registrations
    approach_cap: jax.Array
    candidates: jax.Array
    candidate_ok: jax.Array
    beyond_visibility: jax.Array
    slowed: jax.Array


def registrations(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    start: StartSpeeds,
    leader: OwnLeader,
    limits: LaneLimits,
    line: YieldLine,
    ahead: LookAhead,
    prev_regs: Registrations,
    t: jax.Array,
    *,
    v_follow: jax.Array,
    step: Stepping,
) -> Requests:
    """SUMO's setApproachingForAllLinks. A vehicle that could still brake
    for its entry and would find it closed (judged on the previous step's
    registrations) has slowed down for it (planMoveInternal's
    slowedDownForMinor) and requests no link after it; so does one still
    beyond the visibility point. Its speed then follows (`next_link_wait`).

    Args:
        v_follow: (M,) the follow speed, the link leaders at the next merge
            included.
        t: time at the start of the step.
    """
    route, pos, speed, dt = veh.route, veh.pos, veh.speed, step.dt
    leg = net.route_origin[route]
    # leaders on the approach cap the entry's arrival speed (adaptToLeader)
    approach_cap = jnp.where(
        leader.back < net.yield_offset[route], leader.v_follow, jnp.inf
    )
    plan = entry_approach(net, car, route, pos, speed, veh.speed_factor,
                          start.v_lane, jnp.inf, t, dt, approach_cap,
                          v_start=start.v_start)  # fmt: skip
    plan = plan._replace(leave_speed=plan.arrival_speed)
    plan = plan._replace(
        leave=plan.arrival
        + (net.entry_internal_length[leg] + car.length)
        / jnp.maximum(plan.arrival_speed, 1e-3)
    )
    # only the vehicles nearest to each line can be within its visibility
    cand, cand_ok = entry_candidates(net, route, pos, veh.active, ENTRY_CANDIDATES)
    closed = entry_blocked(
        net, car, route[cand], jax.tree.map(lambda x: x[cand], plan), prev_regs,
        line.impatience[cand], t + dt, dt, ego_slot=cand,
    )  # fmt: skip
    closed_plan = jnp.zeros(pos.shape[0], bool).at[cand].max(closed & cand_ok)
    beyond = line.to_line > net.entry_visibility[leg]
    slowed = (
        line.before_line
        & (brake_gap(speed, car.decel, 0.0, dt) < line.to_line)
        & (beyond | closed_plan)
    )
    v_chain = jnp.minimum(start.v_start, v_follow)
    v_chain = jnp.minimum(v_chain, jnp.minimum(limits.v_limits, limits.v_free))
    follow = partial(follow_from, car=car, v_lane=start.v_lane, step=step)
    through_has, through_slot, through_gap = on_through_lanes(
        net, ahead.rearmost, route
    )  # (M, G)
    regs = register(
        net, car, route, pos, speed, veh.speed_factor, v_chain, v_follow,
        leader.back, veh.active, slowed, t, dt, v_pre=ahead.v_pre,
        ring_cap=ahead.ring_cap,
        leave_follow=(through_has, speed[through_slot], through_gap, follow),
        leave_cap=ahead.via_cap,
    )  # fmt: skip
    return Requests(regs, approach_cap, cand, cand_ok, beyond, slowed)


def entry_test(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    start: StartSpeeds,
    line: YieldLine,
    ahead: LookAhead,
    requests: Requests,
    t: jax.Array,
    *,
    step: Stepping,
) -> tuple[jax.Array, Approach]:
    """MSLink::opened in executeMove: the entry tested against this step's
    registrations. Returns (weight, approach): float (M,), exactly 0 (open)
    or 1 (blocked) unless the dynamics are relaxed (`jaxround.core.relax`),
    0 for vehicles past their line; and every vehicle's approach to its own
    entry link, the drive item it registered and tested (the lane changer's
    hold reads it: `jaxround.lanes.entry_hold`)."""
    route, dt = veh.route, step.dt
    entry_has, entry_slot, entry_gap = on_entry_lane(net, ahead.rearmost)
    follow = partial(follow_from, car=car, v_lane=start.v_lane, step=step)
    entry_follow = (
        entry_has[:, 0], veh.speed[entry_slot[:, 0]], entry_gap[:, 0], follow,
    )  # fmt: skip
    ego = entry_approach(net, car, route, veh.pos, veh.speed, veh.speed_factor,
                         start.v_lane, line.leave_cap, t, dt, requests.approach_cap,
                         entry_follow, v_start=start.v_start)  # fmt: skip
    impatience_now = jnp.where(line.can_brake, line.impatience, 1.0)
    cand = requests.candidates
    weight = entry_blocked_weight(
        net, car, route[cand], jax.tree.map(lambda x: x[cand], ego), requests.regs,
        impatience_now[cand], t + dt, dt, ego_slot=cand,
    )  # fmt: skip
    blocked_w = jnp.zeros(veh.pos.shape[0]).at[cand].max(weight * requests.candidate_ok)
    return blocked_w * line.before_line, ego


def next_link_wait(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    start: StartSpeeds,
    leader: OwnLeader,
    limits: LaneLimits,
    line: YieldLine,
    ahead: LookAhead,
    *,
    step: Stepping,
) -> jax.Array:
    """vLinkWait of the first link after the entry that leaves a normal lane
    (into the ring's next junction), float (M,): the speed of a vehicle that
    slowed down for its entry (`Requests.slowed`). Its request for that link
    is withdrawn, so MSVehicle::processLinkApproaches ends there with
    ``vSafe = vLinkWait``: the running speed of planMoveInternal up to that
    link (the limits of the lanes before it, the own leader before it, the
    link leaders at the entry and at that link), and the stop before it
    (a major link: ``laneStopOffset = min(1 m, seen - brakeGap)``)."""
    route, pos, speed, dt = veh.route, veh.pos, veh.speed, step.dt
    k_next = net.next_link_index[route]  # (M,)
    link_at = net.next_link_offset[route]
    seen = link_at - pos
    stop_dist = link_stop_distance(seen, speed, car.decel, dt, major=True)
    v_stop = idm.idm_stop_speed(
        speed, stop_dist, start.v_lane, vtype=car.idm, dt=dt,
        n_substeps=step.n_substeps, action_step=step.action_step,
    )  # fmt: skip
    lanes_before = jnp.arange(limits.per_lane.shape[1])[None, :] < k_next[:, None]
    v_run = jnp.min(jnp.where(lanes_before, limits.per_lane, jnp.inf), axis=1)
    v_run = jnp.minimum(jnp.minimum(v_run, start.v_start), line.v_link)
    v_run = jnp.where(leader.back < link_at, jnp.minimum(v_run, leader.v_follow), v_run)
    at_next = jnp.take_along_axis(ahead.v_link_k, k_next[:, None], axis=1)[:, 0]
    return jnp.minimum(jnp.minimum(v_run, at_next), v_stop)
