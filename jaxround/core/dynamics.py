"""One simulation step of the roundabout as pure functions over vehicle slots.

Shapes: M vehicle slots, N scheduled vehicles, R routes, L lanes, K lanes per
route, G legs. The order of a step follows SUMO's ``MSNet::simulationStep``:
every vehicle plans its speed from the state at the start of the step (leader,
speed limits ahead, the entry's right of way), all move at once (Euler),
arrivals leave, then waiting vehicles are inserted at the start of their
approach.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core import command as traci
from jaxround.core import finalize, idm
from jaxround.core.geometry import NetArrays, leaders, locate
from jaxround.core.insertion import STOP_OFFSET
from jaxround.core.junction import (
    brake_gap,
    entry_approach,
    entry_blocked,
    entry_blocked_weight,
    entry_candidates,
    register,
)
from jaxround.core.link_leaders import link_leader
from jaxround.core.neighbours import (
    NeighbourTables,
    build_tables,
    on_entry_lane,
    on_through_lanes,
    rearmost_on_lanes,
)
from jaxround.core.params import CarFollowing
from jaxround.core.relax import blend, soft_or
from jaxround.core.state import Registrations

#: Speed below which SUMO counts a vehicle as waiting / halting (m/s).
HALTING_SPEED = 0.1
#: Vehicles per leg whose entry is tested each step (the nearest to the line).
ENTRY_CANDIDATES = 2
#: departPos="base": the front starts this far beyond the vehicle length (m).
DEPART_OFFSET = 0.1
#: A vehicle arrives when its front is this close to the end of its route (m).
ARRIVAL_EPS = 0.1


def link_leader_speed(
    net: NetArrays,
    params: CarFollowing,
    route: jax.Array,
    pos: jax.Array,
    speed: jax.Array,
    v_lane: jax.Array,
    active: jax.Array,
    may_drive_to_line: jax.Array,
    v_wait: jax.Array,
    dt: float,
    n_substeps: int,
    action_step: float,
    km_fixed: int | jax.Array | None = None,
    *,
    tables: NeighbourTables,
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
        tables: the step's `NeighbourTables`.

    Returns:
        (v, to_link): float (M,) the allowed speed (inf without link leader),
        float (M,) distance to the start of the merging lane.
    """
    p = params
    lead = link_leader(net, tables, route, pos, active, p.min_gap, km_fixed=km_fixed)
    has, nearest, front_on_q, to_link = lead.has, lead.slot, lead.front_on, lead.to_link
    gap = jnp.where(has, lead.gap, 0.0)
    v = idm.idm_follow_speed(
        speed, speed[nearest], gap + p.min_gap, v_lane, p.accel, p.decel, p.tau,
        p.min_gap, p.delta, dt, n_substeps,
    )  # fmt: skip
    v_stop = idm.idm_stop_speed(
        speed, to_link - STOP_OFFSET, v_lane, p.accel, p.decel, p.tau, p.delta, dt,
        n_substeps, action_step,
    )  # fmt: skip
    v = jnp.where(gap >= 0, v, jnp.where(to_link > 0, v_stop, 0.0))
    v = jnp.where(may_drive_to_line & front_on_q, jnp.maximum(v, v_wait), v)
    return jnp.where(has, v, jnp.inf), to_link


def planned_speed(
    net: NetArrays,
    params: CarFollowing,
    route: jax.Array,
    pos: jax.Array,
    speed: jax.Array,
    speed_factor: jax.Array,
    active: jax.Array,
    waiting_s: jax.Array,
    prev_regs: Registrations,
    t: jax.Array,
    dt: float,
    n_substeps: int,
    action_step: float,
    debug: bool = False,
    command: jax.Array | None = None,
) -> tuple[jax.Array, Registrations, jax.Array, jax.Array, jax.Array]:
    """Every vehicle's speed at the end of the step, as SUMO's IDM plans it.

    Args:
        route, pos, speed, speed_factor, waiting_s: (M,) state at time `t`.
        active: bool (M,).
        prev_regs: the registrations of the previous step.
        t: time at the start of the step.
        command: (M,) a TraCI speed command per vehicle for this step (NaN:
            none), applied where SUMO applies it (`jaxround.core.command`).

    Returns:
        (v_next, regs, blocked, leader, gap): float (M,), this step's
        registrations, bool (M,) held at the yield line, int (M,) the slot
        ahead on the vehicle's lanes (-1 for none), float (M,) the gap to it.
    """
    p = params
    k, lane, pos_on_lane = locate(net, route, pos)
    v_lane = jnp.minimum(net.lane_speed[lane] * speed_factor, p.max_speed)  # (M,)
    # planMoveInternal's initial v; a speed command replaces it here, so every
    # look-ahead speed below (registrations, the entry's arrival) starts from it
    v_max_next = traci.max_next_speed(speed, p, dt)
    v_min_next = traci.min_next_speed(speed, p, dt)
    v_start = jnp.minimum(speed + p.accel * dt, v_lane)
    if command is not None:
        v_start = traci.influence_speed(
            command, v_start, v_safe=v_start, v_max=v_max_next, v_min=v_min_next
        )

    # 1. the leader on the vehicle's own lanes (any part of it ahead), and
    #    the link leaders merging in at the next merge
    tables = build_tables(net, route, pos, active, p.length)  # (R, M) and more
    leader, gap = leaders((tables.back + p.length)[route], pos, active, p.length)
    v_leader = jnp.where(leader >= 0, speed[jnp.maximum(leader, 0)], 0.0)
    v_follow = idm.idm_follow_speed(
        speed, v_leader, gap, v_lane, p.accel, p.decel, p.tau, p.min_gap, p.delta,
        dt, n_substeps,
    )  # fmt: skip
    v_follow_own = v_follow

    # 2. speed limits of the lanes ahead (and the free road on this one)
    starts = net.route_lane_start[route]  # (M, K)
    lanes_ahead = net.route_lanes[route]  # (M, K)
    limit_ahead = jnp.minimum(
        net.lane_speed[jnp.maximum(lanes_ahead, 0)] * speed_factor[:, None], p.max_speed
    )
    seen = starts - pos[:, None]
    later = (jnp.arange(starts.shape[1])[None, :] > k[:, None]) & (lanes_ahead >= 0)
    p_columns = p.columns()  # per-vehicle numbers against (M, K) arrays
    v_limits = idm.idm_free_speed_ahead(
        speed[:, None], seen, limit_ahead, v_lane[:, None], p_columns.accel, p.decel,
        p_columns.tau, p.delta, dt, n_substeps,
    )  # fmt: skip
    v_limits = jnp.maximum(v_limits, speed[:, None] - p.decel * dt)
    v_limits_k = jnp.where(later, v_limits, jnp.inf)  # (M, K)
    v_limits = jnp.min(v_limits_k, axis=1)
    to_end = net.route_length[route] - pos
    v_free = idm.idm_free_speed(
        speed, v_lane, p.accel, p.decel, p.tau, p.min_gap, p.delta, dt, n_substeps,
        seen=to_end,
    )  # fmt: skip

    # 3. the entry's right of way: beyond the visibility distance a vehicle
    #    always plans to stop at its yield line; within it, only if blocked
    leg = net.route_origin[route]
    seen = net.yield_offset[route] - pos
    v_wait = idm.idm_stop_speed(
        speed, seen - STOP_OFFSET, v_lane, p.accel, p.decel, p.tau, p.delta, dt,
        n_substeps, action_step,
    )  # fmt: skip
    v_wait = jnp.where(seen > 0, v_wait, 0.0)
    # link leaders at the next merge; the entry's leave speed is capped by them
    v_link, to_link = link_leader_speed(
        net, p, route, pos, speed, v_lane, active, seen > 0, v_wait, dt,
        n_substeps, action_step, tables=tables,
    )  # fmt: skip
    leave_cap = jnp.where(seen > 0, v_link, jnp.inf)
    v_follow = jnp.minimum(v_follow, v_link)
    can_brake = (seen > brake_gap(speed, p.decel, 0.0, dt)) | (speed < p.decel * dt)
    before_line = active & (seen > 0)
    impatience = jnp.clip(p.impatience + waiting_s / p.time_to_impatience, 0.0, 1.0)
    step_label = t + dt
    # planMove: a vehicle that could still stop and would find its entry
    # closed (judged on the previous step's registrations) withdraws its
    # requests on later links; so does one still beyond the visibility point
    leader_back = jnp.where(
        leader >= 0, tables.back[route, jnp.maximum(leader, 0)], jnp.inf
    )

    def follow_from(v: jax.Array, v_l: jax.Array, gap: jax.Array) -> jax.Array:
        """SUMO's futureVSafe: followSpeed from the leave speed, (M,) or (M, G)."""
        numbers = p_columns if v.ndim == 2 else p
        return idm.idm_follow_speed(
            v, v_l, gap, v_lane[:, None] if v.ndim == 2 else v_lane, numbers.accel,
            p.decel, numbers.tau, p.min_gap, p.delta, dt, n_substeps,
        )  # fmt: skip

    # leaders on the approach cap the entry's arrival speed (adaptToLeader)
    appr_cap = jnp.where(leader_back < net.yield_offset[route], v_follow_own, jnp.inf)
    # every lane of the look-ahead: its rearmost vehicle (SUMO's
    # planMoveInternal loop); the entry's internal lane is one of them
    look_ahead = rearmost_on_lanes(net, tables, route, pos, active)  # (M, K)
    entry_has, entry_slot, entry_gap = on_entry_lane(net, look_ahead)
    entry_follow = (
        entry_has[:, 0],
        speed[entry_slot[:, 0]],
        entry_gap[:, 0],
        follow_from,
    )
    plan = entry_approach(net, p, route, pos, speed, speed_factor, v_lane,
                          jnp.inf, t, dt, appr_cap, v_start=v_start)  # fmt: skip
    plan = plan._replace(leave_speed=plan.arrival_speed)
    plan = plan._replace(
        leave=plan.arrival
        + (net.entry_internal_length[leg] + p.length)
        / jnp.maximum(plan.arrival_speed, 1e-3)
    )
    # only the vehicles nearest to each line can be within its visibility
    cand, cand_ok = entry_candidates(net, route, pos, active, ENTRY_CANDIDATES)
    pick = lambda x: x[cand]  # noqa: E731
    m = pos.shape[0]

    def per_slot(flags: jax.Array) -> jax.Array:
        return jnp.zeros(m, bool).at[cand].max(flags & cand_ok)

    closed_plan = per_slot(
        entry_blocked(
            net, p, route[cand], jax.tree.map(pick, plan), prev_regs, impatience[cand],
            step_label, dt, ego_slot=cand,
        )
    )  # fmt: skip
    beyond_vis = seen > net.entry_visibility[leg]
    slowed = (
        before_line
        & (brake_gap(speed, p.decel, 0.0, dt) < seen)
        & (beyond_vis | closed_plan)
    )
    v_chain = jnp.minimum(v_start, v_follow)
    v_chain = jnp.minimum(v_chain, jnp.minimum(v_limits, v_free))
    conflict_offset = net.conflict_offset[route]  # (M, G)
    before = later[:, :, None] & (starts[:, :, None] < conflict_offset[:, None, :])
    lim_before = jnp.min(jnp.where(before, v_limits_k[:, :, None], jnp.inf), axis=1)
    merge_start = pos + to_link
    link_before = merge_start[:, None] < conflict_offset
    v_pre = jnp.minimum(v_start[:, None], lim_before)
    v_pre = jnp.where(link_before, jnp.minimum(v_pre, v_link[:, None]), v_pre)
    prev_start = conflict_offset - net.prev_lane_length[route]
    lead_early = leader_back[:, None] < prev_start
    lead_ring = ~lead_early & (leader_back[:, None] < conflict_offset)
    v_pre = jnp.where(lead_early, jnp.minimum(v_pre, v_follow_own[:, None]), v_pre)
    ring_cap = jnp.where(lead_ring, v_follow_own[:, None], jnp.inf)
    # every lane of the look-ahead: its rearmost vehicle, and the link
    # leaders where it merges (SUMO's planMoveInternal loop)
    lanes_k = net.route_lanes[route]
    lens_k = net.lane_length[jnp.maximum(lanes_k, 0)]
    ends_k = starts + lens_k  # (M, K), inf padded
    ahead_has, ahead_slot, ahead_gap = look_ahead
    v_follow_k = idm.idm_follow_speed(
        speed[:, None], speed[ahead_slot], ahead_gap, v_lane[:, None],
        p_columns.accel, p.decel, p_columns.tau, p.min_gap, p.delta, dt, n_substeps,
    )  # fmt: skip
    mine = (jnp.arange(starts.shape[1])[None, :] >= k[:, None]) & (lanes_k >= 0)
    v_follow_k = jnp.where(ahead_has & mine, v_follow_k, jnp.inf)
    ends_g = ends_k[:, :, None]
    conflict_g = conflict_offset[:, None, :]
    early = ends_g < conflict_g - net.prev_lane_length[route][:, None, :] + 1e-3
    prev_l = jnp.abs(ends_g - conflict_g) < 1e-3
    v_pre = jnp.minimum(
        v_pre, jnp.min(jnp.where(early, v_follow_k[:, :, None], jnp.inf), 1)
    )
    ring_cap = jnp.minimum(
        ring_cap, jnp.min(jnp.where(prev_l, v_follow_k[:, :, None], jnp.inf), 1)
    )

    def link_leaders_at(
        merge_k: jax.Array,
    ) -> jax.Array:  # the merge at route lane merge_k
        v, _ = link_leader_speed(
            net, p, route, pos, speed, v_lane, active, (seen > 0) & (merge_k == 1),
            v_wait, dt, n_substeps, action_step, km_fixed=merge_k, tables=tables,
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
    # v_link_k (M, K): the link leaders' speed where lane k merges
    m_before = starts[:, :, None] < conflict_g - 1e-3
    v_pre = jnp.minimum(
        v_pre, jnp.min(jnp.where(m_before, v_link_k[:, :, None], jnp.inf), 1)
    )
    via_k = jnp.abs(starts[:, :, None] - conflict_g) < 1e-3
    via_cap = jnp.min(jnp.where(via_k, v_link_k[:, :, None], jnp.inf), 1)
    reg_kw = dict(v_pre=v_pre, ring_cap=ring_cap)
    through_has, through_slot, through_gap = on_through_lanes(
        net, look_ahead, route
    )  # (M, G)
    reg_kw["leave_follow"] = (
        through_has,
        speed[through_slot],
        through_gap,
        follow_from,
    )
    # link leaders at the exit of the via lane lower its leave speed
    reg_kw["leave_cap"] = via_cap
    regs = register(net, p, route, pos, speed, speed_factor, v_chain, v_follow,
                    leader_back, active, slowed, t, dt, **reg_kw)  # fmt: skip
    # link leaders at every merge of the look-ahead, not only the next one
    v_follow = jnp.minimum(v_follow, jnp.min(v_link_k, axis=1))
    # executeMove: the entry is tested against this step's registrations
    ego = entry_approach(net, p, route, pos, speed, speed_factor, v_lane,
                         leave_cap, t, dt, appr_cap,
                         entry_follow, v_start=v_start)  # fmt: skip
    impatience_now = jnp.where(can_brake, impatience, 1.0)
    # a weight, exactly 0/1 unless the dynamics are relaxed (jaxround.core.relax)
    blocked_w = jnp.zeros(m).at[cand].max(
        entry_blocked_weight(
            net, p, route[cand], jax.tree.map(pick, ego), regs, impatience_now[cand],
            step_label, dt, ego_slot=cand,
        ) * cand_ok
    ) * before_line  # fmt: skip
    blocked = blocked_w > 0.5
    if debug:
        return {k: v for k, v in locals().items() if isinstance(v, jax.Array)}
    too_late = ~can_brake & (seen < brake_gap(speed, p.emergency_decel, 0.0, dt))
    far = beyond_vis & can_brake
    must_stop_w = (seen > 0) * soft_or(blocked_w * ~too_late, far.astype(jnp.float32))
    # a vehicle that must stop at its line plans only up to it: leaders and
    # lane limits beyond the line do not count (SUMO's vSafe = vWait)
    leader_before_line = leader_back < net.yield_offset[route]
    v_before_line = jnp.minimum(
        jnp.minimum(jnp.minimum(v_wait, v_free), v_limits),
        jnp.where(leader_before_line, v_follow_own, jnp.inf),
    )
    v_safe = jnp.minimum(jnp.minimum(v_follow, v_limits), v_free)
    v_safe = blend(must_stop_w, v_before_line, v_safe)
    v_next = finalize.next_speed(
        speed, v_safe, v_lane, p.accel, p.decel, p.emergency_decel, dt, action_step
    )
    if command is not None:  # executeMove -> processTraCISpeedControl
        v_next = traci.influence_speed(
            command, v_next, v_safe=v_safe, v_max=v_max_next, v_min=v_min_next
        )
        v_next = finalize.snap_speed(v_next, dt)
    return jnp.where(active, v_next, 0.0), regs, blocked, leader, gap
