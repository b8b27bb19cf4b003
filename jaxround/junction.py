"""The roundabout entry's right of way: SUMO's gap acceptance at a minor link.

Shapes: M vehicle slots, G legs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.geometry import NetArrays, internal_done, locate, normal_done
from jaxround.state import EnvParams


def minimal_arrival_time(
    dist: jax.Array,
    v: jax.Array,
    v_arrive: jax.Array,
    accel: jax.Array,
    decel: jax.Array,
) -> jax.Array:
    """SUMO's MSVehicle::getMinimalArrivalTime: reach `v_arrive`, then keep it.

    Accelerates at `accel` (or brakes at `decel`) from `v` to `v_arrive` and
    covers the rest of `dist` at constant speed.
    """
    up = v_arrive >= v
    acc = jnp.where(up, accel, -decel)
    t_a = (v_arrive - v) / acc
    w_a = t_a * (v_arrive + v) / 2.0
    rest = t_a + (dist - w_a) / jnp.maximum(jnp.maximum(v, v_arrive), 0.1)
    root = jnp.sqrt(jnp.maximum(v * v + 2.0 * acc * dist, 0.0))
    return jnp.where(dist >= w_a, rest, (v - root) * (-1.0 / acc))


def brake_gap(v: jax.Array, decel: jax.Array, tau: jax.Array, dt: float) -> jax.Array:
    """SUMO's MSCFModel::brakeGap for the Euler update: stepwise braking + v*tau."""
    dv = decel * dt
    n = jnp.floor(v / dv)
    return dt * (n * v - dv * n * (n + 1) / 2.0) + v * tau


def yield_blocked(
    net: NetArrays,
    params: EnvParams,
    route: jax.Array,
    pos: jax.Array,
    speed: jax.Array,
    speed_factor: jax.Array,
    v_lane: jax.Array,
    active: jax.Array,
    waiting_s: jax.Array,
    leave_cap: jax.Array,
    dt: float,
    debug: bool = False,
) -> jax.Array:
    """SUMO's gap acceptance at the entry (MSLink::opened / blockedByFoe).

    The ego is a vehicle before its yield line. Its foes are the vehicles that
    registered their approach on the ring's through link at that entry in this
    step: they will drive it, have not reached it yet, are not held back
    before their own entry, and the link lies within their look-ahead. A
    vehicle already on the through lane is no foe here; it acts as a link
    leader in the car following instead.

    Args:
        route, pos, speed, speed_factor, waiting_s: (M,) state.
        v_lane: (M,) desired speed on each vehicle's current lane.
        active: bool (M,).
        leave_cap: (M,) cap on the ego's speed leaving the entry (its link
            leader's follow speed), inf if none.

    Returns:
        bool (M,): the entry is closed for the vehicle.
    """
    p = params
    a, b, length = p.accel, p.decel, p.length
    m = pos.shape[0]
    leg = net.route_origin[route]  # (M,)
    v_plan = jnp.minimum(speed + a * dt, v_lane)  # (M,) Euler: planned, not current

    # 1. the ego's own approach: arrival at its yield line, leave past the merge
    seen = net.yield_offset[route] - pos  # (M,)
    link_len = net.entry_internal_length[leg]
    v_link = jnp.minimum(
        net.lane_speed[net.route_lanes[route, 1]] * speed_factor, p.max_speed
    )
    a_s = jnp.minimum(jnp.sqrt(2 * a * jnp.maximum(seen, 0) + v_plan**2), v_link)
    l_s = jnp.minimum(v_link, jnp.sqrt(2 * a * link_len + a_s**2))
    l_s = jnp.minimum(l_s, leave_cap)
    a_t = minimal_arrival_time(jnp.maximum(seen, 0), v_plan, a_s, a, b)
    l_t = a_t + (link_len + length) / jnp.maximum(0.5 * (a_s + l_s), 1e-3)

    # 2. the foes' registrations on the through link of the ego's leg
    c_off = net.conflict_offset[route][:, leg].T  # (M_ego, M_foe)
    d_foe = c_off - pos[None, :]  # distance of each foe to that link
    through = net.through_length[leg][:, None]  # (M_ego, 1)
    v_thr = jnp.minimum(
        net.lane_speed[net.through_lane[leg]][:, None] * speed_factor[None, :],
        p.max_speed,
    )  # (M_ego, M_foe)
    vf = v_plan[None, :]
    d_pos = jnp.maximum(d_foe, 0.0)
    f_as = jnp.minimum(jnp.sqrt(2 * a * d_pos + vf**2), v_thr)
    f_ls = jnp.minimum(v_thr, jnp.sqrt(2 * a * through + f_as**2))
    f_at = minimal_arrival_time(d_pos, vf, f_as, a, b)
    f_lt = f_at + (through + length) / jnp.maximum(0.5 * (f_as + f_ls), 1e-3)
    # arrival speed if the foe brakes (MSCFModel::getMinimalArrivalSpeedEuler)
    disc = vf**2 - 2 * b * (d_foe - vf * p.tau)
    asb = jnp.where(
        d_foe < vf, jnp.inf, jnp.where(disc >= 0, jnp.sqrt(jnp.abs(disc)), b)
    )
    f_asb = jnp.where(d_foe >= brake_gap(vf, b, p.tau, dt), 0.0, jnp.minimum(asb, f_as))
    # look-ahead: SUMO stops registering after a link once it has seen past
    # its braking distance and 5 vehicle lengths of normal lanes
    max_v = jnp.minimum(speed + a * dt, p.max_speed)
    reach = max_v * dt + brake_gap(max_v, b, p.tau, dt)  # (M,)
    k_link = net.conflict_index[route][:, leg].T  # (M_ego, M_foe)
    prev_seen = d_foe - net.prev_lane_length[route][:, leg].T
    prev_normal = (
        net.normal_before[route][:, leg].T - normal_done(net, route, pos)[None, :]
    )
    prev_internal = (
        net.internal_before[route][:, leg].T - internal_done(net, route, pos)[None, :]
    )
    stop_before = (prev_seen > reach[None, :]) & (
        prev_normal > jnp.maximum(5 * length, length + prev_internal)
    )
    k_now, _, _ = locate(net, route, pos)
    registered = (k_link - 1 <= k_now[None, :]) | ~stop_before
    # a vehicle still before its own yield line does not request later links
    # (measured: SUMO registers them with willPass=0 until it is about to go)
    held_back = seen > 0
    will_pass = active & (v_plan > 1e-3) & ~held_back  # (M,)
    foe = (
        will_pass[None, :]
        & ~jnp.isnan(c_off)
        & (d_foe > 0)
        & registered
        & (jnp.arange(m)[None, :] != jnp.arange(m)[:, None])
    )

    # 3. impatience: the foe may brake at imp * decel if the ego arrives first
    can_brake = (seen > brake_gap(speed, b, 0.0, dt)) | (speed < b * dt)
    imp = jnp.clip(p.impatience + waiting_s / p.time_to_impatience, 0.0, 1.0)
    imp = jnp.where(can_brake, imp, 1.0)[:, None]  # (M, 1)
    mdec = jnp.maximum(imp * b, 1e-6)
    gap_t = f_at - a_t[:, None]
    dv = gap_t * mdec
    area = gap_t * dv / 2
    v_foe = d_pos / jnp.maximum(f_at, 1e-3)
    dist2 = d_pos - v_foe * (a_t[:, None] - dt)
    foe_can_stop = v_foe**2 / (2 * mdec) <= dist2
    root = jnp.sqrt(jnp.maximum(4 * (v_foe - dv) ** 2 - 8 * mdec * area, 0.0))
    x = (v_foe - dv - root / 2) / mdec
    same_step = jnp.floor(a_t[:, None] / dt) == jnp.floor(f_at / dt)
    f_at_brake = jnp.where(foe_can_stop, f_at + 30.0, f_at + x)
    asb_brake = jnp.where(foe_can_stop, 0.0, v_foe - (gap_t + x) * mdec)
    use_imp = (imp > 0) & (a_t[:, None] < f_at) & ~same_step
    f_at_imp = jnp.where(use_imp, (1 - imp) * f_at + imp * f_at_brake, f_at)
    f_asb = jnp.where(use_imp, asb_brake, f_asb)

    # 4. MSLink::blockedByFoe with equal decelerations (unsafeMerge is <=)
    tg = p.jm_timegap_minor
    behind = f_lt < a_t[:, None]
    blocked_behind = (a_t[:, None] - f_lt < tg) | (f_ls**2 <= a_s[:, None] ** 2)
    ahead = f_at_imp > l_t[:, None] + tg
    blocked_ahead = l_s[:, None] ** 2 <= f_asb**2
    blocked = jnp.where(behind, blocked_behind, jnp.where(ahead, blocked_ahead, True))
    if debug:
        return {k: v for k, v in locals().items() if isinstance(v, jax.Array)}
    return active & (seen > 0) & jnp.any(foe & blocked, axis=1)
