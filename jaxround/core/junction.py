"""The roundabout entry's right of way: SUMO's gap acceptance at a minor link.

Shapes: M vehicle slots, G legs.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxround.core.geometry import NetArrays, internal_done, locate, normal_done
from jaxround.core.params import CarFollowing
from jaxround.core.relax import blend, soft_any, soft_or, soft_step
from jaxround.core.safe_math import finite_or, safe_sqrt
from jaxround.core.state import Registrations


def minimal_arrival_time(
    dist: jax.Array,
    v: jax.Array,
    v_arrive: jax.Array,
    accel: jax.Array,
    decel: jax.Array,
) -> jax.Array:
    """SUMO's MSCFModel::getMinimalArrivalTime: reach `v_arrive`, then keep it.

    Accelerates at `accel` (or brakes at `decel`) from `v` to `v_arrive` and
    covers the rest of `dist` at constant speed.
    """
    up = v_arrive >= v
    acc = jnp.where(up, accel, -decel)
    t_a = (v_arrive - v) / acc
    w_a = t_a * (v_arrive + v) / 2.0
    rest = t_a + (dist - w_a) / jnp.maximum(jnp.maximum(v, v_arrive), 0.1)
    root = safe_sqrt(v * v + 2.0 * acc * dist)
    return jnp.where(dist >= w_a, rest, (v - root) * (-1.0 / acc))


def brake_gap(v: jax.Array, decel: jax.Array, tau: jax.Array, dt: float) -> jax.Array:
    """SUMO's MSCFModel::brakeGap for the Euler update: stepwise braking + v*tau."""
    dv = decel * dt
    n = jnp.floor(v / dv)
    return dt * (n * v - dv * n * (n + 1) / 2.0) + v * tau


class Approach(NamedTuple):
    """A vehicle's own approach to its entry link. (M,), times absolute."""

    seen: jax.Array
    arrival: jax.Array
    leave: jax.Array
    arrival_speed: jax.Array
    leave_speed: jax.Array


def entry_approach(
    net: NetArrays,
    params: CarFollowing,
    route: jax.Array,
    pos: jax.Array,
    speed: jax.Array,
    speed_factor: jax.Array,
    v_lane: jax.Array,
    leave_cap: jax.Array,
    t: jax.Array,
    dt: float,
    v_cap: jax.Array | float = jnp.inf,
    leave_follow: tuple | None = None,
    v_start: jax.Array | None = None,
) -> Approach:
    """Arrival at the yield line and leave past the entry, as SUMO registers it.

    Args:
        t: time at the start of the step (the state's time).
        leave_cap: (M,) cap on the leave speed from link leaders (inf if none).
        v_start: (M,) the speed planning starts from (SUMO's initial ``v`` of
            ``MSVehicle::planMoveInternal``, a TraCI speed command already
            applied); default ``min(speed + accel*dt, v_lane)``.
    """
    p = params
    a, b = p.accel, p.decel
    leg = net.route_origin[route]
    # Euler plans with the next speed
    v_pre = jnp.minimum(speed + a * dt, v_lane) if v_start is None else v_start
    seen = net.yield_offset[route] - pos
    link_len = net.entry_internal_length[leg]
    v_link = jnp.minimum(
        net.lane_speed[net.route_lanes[route, 1]] * speed_factor, p.max_speed
    )
    # vLinkPass: accelerate over the approach (capped at the approach lane's
    # limit), then lowered by the leaders on the approach (adaptToLeader)
    a_s = jnp.minimum(safe_sqrt(2 * a * jnp.maximum(seen, 0) + v_pre**2), v_lane)
    a_s = jnp.minimum(a_s, v_cap)
    v_plan = jnp.minimum(v_pre, v_cap)
    l_s = jnp.minimum(
        jnp.minimum(v_link, safe_sqrt(2 * a * link_len + a_s**2)), leave_cap
    )
    if leave_follow is not None:  # futureVSafe of a leader on the entry lane
        has, v_l, gap, fol = leave_follow
        l_s = jnp.where(has, jnp.minimum(l_s, fol(l_s, v_l, gap)), l_s)
    a_t = t + minimal_arrival_time(jnp.maximum(seen, 0), v_plan, a_s, a, b)
    l_t = a_t + (link_len + p.length) / jnp.maximum(0.5 * (a_s + l_s), 1e-3)
    return Approach(seen, a_t, l_t, a_s, l_s)


def register(
    net: NetArrays,
    params: CarFollowing,
    route: jax.Array,
    pos: jax.Array,
    speed: jax.Array,
    speed_factor: jax.Array,
    v_plan: jax.Array,
    leader_cap: jax.Array,
    leader_back: jax.Array,
    active: jax.Array,
    slowed: jax.Array,
    t: jax.Array,
    dt: float,
    v_pre: jax.Array | None = None,
    ring_cap: jax.Array | None = None,
    leave_cap: jax.Array | None = None,
    leave_follow: tuple | None = None,
) -> Registrations:
    """Every vehicle's registration on the through link of every leg (SUMO's
    MSVehicle::setApproachingForAllLinks), for the step starting at `t`.

    Args:
        v_plan: (M,) the speed each vehicle plans for this step before any
            junction (accelerating within its lane limit, behind its leaders):
            SUMO's running look-ahead speed.
        leader_cap: (M,) the speed each vehicle's leader allows it.
        leader_back: (M,) where that leader's back lies along the vehicle's
            route (inf if none): a leader before the link caps the arrival
            speed there too.
        slowed: bool (M,) the vehicle is held back before its own entry and
            withdraws its request on later links.
    """
    p = params
    pc = p.columns()  # per-vehicle numbers against (M, G) arrays
    a, b, length, tau = pc.accel, p.decel, p.length, pc.tau
    g = net.through_length.shape[0]
    c_off = net.conflict_offset[route]  # (M, G), nan where the route passes none
    dist = finite_or(c_off, 0.0) - pos[:, None]
    through = net.through_length[None, :]  # (1, G)
    v_thr = jnp.minimum(
        net.lane_speed[net.through_lane][None, :] * speed_factor[:, None], p.max_speed
    )  # (M, G)
    d_pos = jnp.maximum(dist, 0.0)
    # the arrival speed accelerates over the lane before the link only
    on_last_lane = jnp.minimum(d_pos, net.prev_lane_length[route])
    if v_pre is None:
        v_plan = v_plan[:, None]  # (M, 1)
        a_s = jnp.minimum(safe_sqrt(2 * a * on_last_lane + v_plan**2), v_thr)
        leader_first = leader_back[:, None] < c_off
        a_s = jnp.where(leader_first, jnp.minimum(a_s, leader_cap[:, None]), a_s)
    else:
        # SUMO's running look-ahead speed at each link: only constraints
        # before the link; leaders on the lane before it cap vLinkPass
        a_s = jnp.minimum(safe_sqrt(2 * a * on_last_lane + v_pre**2), v_thr)
        a_s = jnp.minimum(a_s, ring_cap)
        v_plan = jnp.minimum(v_pre, ring_cap)
    l_s = jnp.minimum(v_thr, safe_sqrt(2 * a * through + a_s**2))
    if leave_cap is not None:
        l_s = jnp.minimum(l_s, leave_cap)
    if leave_follow is not None:  # futureVSafe of leaders on the via lane
        has, v_l, gap, fol = leave_follow
        l_s = jnp.where(has, jnp.minimum(l_s, fol(l_s, v_l, gap)), l_s)
    a_t = t + minimal_arrival_time(d_pos, v_plan, a_s, a, b)
    l_t = a_t + (through + length) / jnp.maximum(0.5 * (a_s + l_s), 1e-3)
    # arrival speed if it brakes (MSCFModel::getMinimalArrivalSpeedEuler)
    disc = v_plan**2 - 2 * b * (dist - v_plan * tau)
    brk = jnp.where(
        dist < v_plan, jnp.inf, jnp.where(disc >= 0, safe_sqrt(jnp.abs(disc)), b)
    )
    braking = jnp.where(
        dist >= brake_gap(v_plan, b, tau, dt), 0.0, jnp.minimum(brk, a_s)
    )
    # look-ahead: SUMO stops registering after a link once it has seen past
    # its braking distance and 5 vehicle lengths of normal lanes
    max_v = jnp.minimum(speed[:, None] + a * dt, p.max_speed)  # (M, 1)
    reach = max_v * dt + brake_gap(max_v, b, tau, dt)  # (M, 1)
    prev_seen = dist - net.prev_lane_length[route]
    prev_normal = net.normal_before[route] - normal_done(net, route, pos)[:, None]
    prev_internal = net.internal_before[route] - internal_done(net, route, pos)[:, None]
    stop_before = (prev_seen > reach) & (
        prev_normal > jnp.maximum(5 * length, length + prev_internal)
    )
    k_now, _, _ = locate(net, route, pos)
    in_reach = (net.conflict_index[route] - 1 <= k_now[:, None]) | ~stop_before
    ok = (
        (active[:, None] & (v_plan > 5e-5) & ~slowed[:, None])
        & ~jnp.isnan(c_off)
        & (dist > 0)
        & in_reach
    )
    del g
    fields = (dist, a_t, l_t, a_s, l_s, braking)
    # keep the state finite where nothing is registered
    return Registrations(ok, *(jnp.where(ok, x, 0.0) for x in fields))


def entry_blocked(
    net: NetArrays,
    params: CarFollowing,
    route: jax.Array,
    ego: Approach,
    regs: Registrations,
    imp: jax.Array,
    step_label: jax.Array,
    dt: float,
    ego_slot: jax.Array | None = None,
    debug: bool = False,
) -> jax.Array:
    """MSLink::opened for the entry links of E egos against registrations.

    Args:
        route: (E,) the egos' routes.
        ego: the egos' own approaches, (E,).
        regs: the registrations to test against, (M, G) (this step's, or the
            previous step's when a vehicle plans whether to request later
            links).
        imp: (E,) the egos' impatience, 0..1.
        step_label: SUMO's time label of the step being computed (t + dt).
        ego_slot: (E,) the egos' slots (a vehicle is no foe of itself);
            default: the egos are all M slots in order.

    Returns:
        bool (E,): some registered foe blocks the ego's entry.
    """
    weight = entry_blocked_weight(
        net, params, route, ego, regs, imp, step_label, dt, ego_slot, debug
    )
    return weight if debug else weight > 0.5


def entry_blocked_weight(
    net: NetArrays,
    params: CarFollowing,
    route: jax.Array,
    ego: Approach,
    regs: Registrations,
    imp: jax.Array,
    step_label: jax.Array,
    dt: float,
    ego_slot: jax.Array | None = None,
    debug: bool = False,
) -> jax.Array:
    """`entry_blocked` as a weight: float (E,) in [0, 1], exactly 0 or 1 at
    ``params.relax_temperature == 0``; above it the two time-gap tests
    (the foe passed long enough ago, the foe arrives late enough) are smooth
    in their margins (s), so the decision has a gradient in jm_timegap_minor,
    the arrival and leave times, and through them every driver parameter."""
    ego_slot = jnp.arange(route.shape[0]) if ego_slot is None else ego_slot
    leg = net.route_origin[route]  # (E,)
    weight = _foe_link_weight(
        params, leg, ego, regs, imp, step_label, dt, ego_slot,
        same_target=True, debug=debug,
    )  # fmt: skip
    if debug or not net.has_crossings:
        return weight
    # a left entry lane's link also crosses the outer ring lane's through
    # link (MSLink::opened tests every foe link; blockedByFoe's time gaps
    # apply only to a foe with the same target lane)
    crossed = net.entry_crossing[leg]  # (E,) -1: none
    cross = _foe_link_weight(
        params, jnp.maximum(crossed, 0), ego, regs, imp, step_label, dt,
        ego_slot, same_target=False,
    )  # fmt: skip
    return soft_or(weight, jnp.where(crossed >= 0, cross, 0.0))


def _foe_link_weight(
    params: CarFollowing,
    leg: jax.Array,
    ego: Approach,
    regs: Registrations,
    imp: jax.Array,
    step_label: jax.Array,
    dt: float,
    ego_slot: jax.Array,
    *,
    same_target: bool,
    debug: bool = False,
) -> jax.Array:
    """`entry_blocked_weight` against the registrations on one foe link per
    ego: column ``leg`` (E,) of `regs` (SUMO's MSLink::blockedByFoe)."""
    p = params
    b = p.decel
    m = regs.ok.shape[0]
    take = lambda x: x[:, leg].T  # noqa: E731  (E, M) on the ego's leg
    ok, dist = take(regs.ok), take(regs.dist)
    f_at, f_lt = take(regs.arrival), take(regs.leave)
    f_ls, f_asb = take(regs.leave_speed), take(regs.braking_speed)
    a_t, l_t = ego.arrival[:, None], ego.leave[:, None]
    a_s, l_s = ego.arrival_speed[:, None], ego.leave_speed[:, None]
    imp = imp[:, None]

    # impatience: the foe may brake at imp * decel when the ego arrives first
    # (MSLink::computeFoeArrivalTimeBraking; the ego's arrival rounded up)
    a_t_up = jnp.ceil(a_t / dt - 1e-6) * dt
    mdec = jnp.maximum(imp * b, 1e-6)
    gap_t = f_at - a_t_up
    dv = gap_t * mdec
    area = gap_t * dv / 2
    v_foe = dist / jnp.maximum(f_at - step_label + dt, 1e-3)
    dist2 = dist - v_foe * (a_t_up - step_label)
    foe_can_stop = v_foe**2 / (2 * mdec) <= dist2
    root = safe_sqrt(4 * (v_foe - dv) ** 2 - 8 * mdec * area)
    x = (v_foe - dv - root / 2) / mdec
    same_step = jnp.floor(a_t / dt + 1e-6) == jnp.floor(f_at / dt + 1e-6)
    f_at_brake = jnp.where(foe_can_stop, f_at + 30.0, f_at + x)
    asb_brake = jnp.where(foe_can_stop, 0.0, v_foe - (gap_t + x) * mdec)
    use_imp = (imp > 0) & (a_t < f_at) & ~same_step
    f_at_imp = jnp.where(use_imp, (1 - imp) * f_at + imp * f_at_brake, f_at)
    f_asb = jnp.where(use_imp, asb_brake, f_asb)

    # MSLink::blockedByFoe with equal decelerations (unsafeMerge is <=)
    tg = p.jm_timegap_minor  # the ego's own
    if jnp.ndim(tg):
        tg = tg[ego_slot][:, None]
    temp = p.relax_temperature
    behind = soft_step(a_t - f_lt, temp)
    ahead = soft_step(f_at_imp - (l_t + tg), temp)
    if same_target:
        blocked_behind = soft_or(
            soft_step(tg - (a_t - f_lt), temp), (f_ls**2 <= a_s**2).astype(jnp.float32)
        )
        blocked_ahead = (l_s**2 <= f_asb**2).astype(jnp.float32)
    else:  # a crossing: blocked only while the two links' times overlap
        blocked_behind = blocked_ahead = jnp.zeros_like(behind)
    blocked = blend(behind, blocked_behind, blend(ahead, blocked_ahead, 1.0))
    others = jnp.arange(m)[None, :] != ego_slot[:, None]
    if debug:  # every intermediate, for tracing a decision
        return {k: v for k, v in locals().items() if isinstance(v, jax.Array)}
    return soft_any(jnp.where(ok & others, blocked, 0.0), axis=1)


def entry_candidates(
    net: NetArrays, route: jax.Array, pos: jax.Array, active: jax.Array, per_leg: int
) -> tuple[jax.Array, jax.Array]:
    """The vehicles nearest to each yield line, the only ones whose entry test
    can matter (vehicles keep 7.5 m apart; the visibility distance is 9 m).

    Returns:
        (slots, valid): int (G * per_leg,), bool (G * per_leg,).
    """
    g = net.through_length.shape[0]
    seen = net.yield_offset[route] - pos  # (M,)
    mine = (
        active[None, :]
        & (seen > 0)[None, :]
        & (net.route_origin[route][None, :] == jnp.arange(g)[:, None])
    )  # (G, M)
    score = jnp.where(mine, -seen[None, :], -jnp.inf)
    top, slots = jax.lax.top_k(score, per_leg)  # (G, per_leg)
    return slots.reshape(-1), jnp.isfinite(top).reshape(-1)
