"""One simulation step of the roundabout as pure functions over vehicle slots.

Shapes: M vehicle slots, N scheduled vehicles, R routes, L lanes, K lanes per
route, G legs. The order of a step follows SUMO's ``MSNet::simulationStep``:
every vehicle plans its speed from the state at the start of the step (leader,
speed limits ahead, the entry's right of way), all move at once (Euler),
arrivals leave, then waiting vehicles are inserted at the start of their
approach.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxround import idm
from jaxround.network import CompiledNetwork
from jaxround.state import EnvParams

#: Speed below which SUMO counts a vehicle as waiting / halting (m/s).
HALTING_SPEED = 0.1
#: A blocked vehicle stops this far before its stop line (m).
STOP_OFFSET = 0.1
#: departPos="base": the front starts this far beyond the vehicle length (m).
DEPART_OFFSET = 0.1
#: A vehicle arrives when its front is this close to the end of its route (m).
ARRIVAL_EPS = 0.1
#: Far away (m).
FAR = 1e6


@dataclass(frozen=True)
class NetArrays:
    """`CompiledNetwork` as device arrays (static for a jitted step)."""

    lane_length: jax.Array  # (L,)
    lane_speed: jax.Array  # (L,)
    lane_next: jax.Array  # (L,)
    lane_sibling: jax.Array  # (L,)
    lane_diverge: jax.Array  # (L,)
    lane_partner: jax.Array  # (L,)
    lane_converge: jax.Array  # (L,)
    route_lanes: jax.Array  # (R, K)
    route_lane_start: jax.Array  # (R, K), +inf padded
    route_length: jax.Array  # (R,)
    route_origin: jax.Array  # (R,)
    lane_offset: jax.Array  # (R, L), nan where off-route
    yield_offset: jax.Array  # (R,)
    conflict_offset: jax.Array  # (R, G), nan where the route does not pass
    through_length: jax.Array  # (G,)
    entry_internal_length: jax.Array  # (G,)
    entry_visibility: jax.Array  # (G,)
    entry_lane: jax.Array  # (G,)
    through_lane: jax.Array  # (G,) the ring's through lane at each entry
    lane_internal: jax.Array  # (L,) bool
    normal_cum: jax.Array  # (R, K) metres of normal lanes before lane k
    internal_cum: jax.Array  # (R, K) metres of internal lanes before lane k
    conflict_index: jax.Array  # (R, G) route index k of the through lane at leg g
    prev_lane_length: jax.Array  # (R, G) length of the lane before it
    normal_before: jax.Array  # (R, G) normal metres up to the link before it
    internal_before: jax.Array  # (R, G) internal metres up to the link before it

    @classmethod
    def from_network(cls, net: CompiledNetwork) -> NetArrays:
        f = jnp.float32
        start = np.where(np.isnan(net.route_lane_start), np.inf, net.route_lane_start)
        internal = np.array([lid.startswith(":") for lid in net.lane_ids])
        r_n, k_n = net.route_lanes.shape
        lanes = np.maximum(net.route_lanes, 0)
        seg = np.where(net.route_lanes >= 0, net.lane_length[lanes], 0.0)  # (R, K)
        is_int = internal[lanes] & (net.route_lanes >= 0)
        normal_cum = np.concatenate(
            [np.zeros((r_n, 1)), np.cumsum(np.where(is_int, 0.0, seg), 1)[:, :-1]], 1
        )
        internal_cum = np.concatenate(
            [np.zeros((r_n, 1)), np.cumsum(np.where(is_int, seg, 0.0), 1)[:, :-1]], 1
        )
        g_n = net.n_legs
        conflict_index = np.zeros((r_n, g_n), np.int32)
        for r in range(r_n):
            for g in range(g_n):
                hit = np.nonzero(net.route_lanes[r] == net.ring_through[g])[0]
                conflict_index[r, g] = hit[0] if hit.size else 2
        rows = np.arange(r_n)[:, None]
        prev_lane = net.route_lanes[rows, conflict_index - 1]
        return cls(
            lane_length=jnp.asarray(net.lane_length, f),
            lane_speed=jnp.asarray(net.lane_speed, f),
            lane_next=jnp.asarray(net.lane_next),
            lane_sibling=jnp.asarray(net.lane_sibling),
            lane_diverge=jnp.asarray(net.lane_diverge, f),
            lane_partner=jnp.asarray(net.lane_partner),
            lane_converge=jnp.asarray(net.lane_converge, f),
            route_lanes=jnp.asarray(net.route_lanes),
            route_lane_start=jnp.asarray(start, f),
            route_length=jnp.asarray(net.route_length, f),
            route_origin=jnp.asarray(net.route_od[:, 0]),
            lane_offset=jnp.asarray(net.lane_offset, f),
            yield_offset=jnp.asarray(net.yield_offset, f),
            conflict_offset=jnp.asarray(net.conflict_offset, f),
            through_length=jnp.asarray(net.lane_length[net.ring_through], f),
            entry_internal_length=jnp.asarray(net.lane_length[net.entry_internal], f),
            entry_visibility=jnp.asarray(net.entry_visibility, f),
            entry_lane=jnp.asarray(net.entry_lane),
            through_lane=jnp.asarray(net.ring_through),
            lane_internal=jnp.asarray(internal),
            normal_cum=jnp.asarray(normal_cum, f),
            internal_cum=jnp.asarray(internal_cum, f),
            conflict_index=jnp.asarray(conflict_index),
            prev_lane_length=jnp.asarray(net.lane_length[prev_lane], f),
            normal_before=jnp.asarray(normal_cum[rows, conflict_index - 1], f),
            internal_before=jnp.asarray(internal_cum[rows, conflict_index - 1], f),
        )


def locate(net: NetArrays, route: jax.Array, pos: jax.Array) -> tuple[jax.Array, ...]:
    """Lane of each vehicle from its route position.

    Args:
        route: int (M,); pos: float (M,) front position along the route.

    Returns:
        (k, lane, pos_on_lane): int (M,) index in the route, int (M,) lane,
        float (M,) position on that lane.
    """
    starts = net.route_lane_start[route]  # (M, K)
    k = jnp.clip(jnp.sum(starts <= pos[:, None], axis=1) - 1, 0, starts.shape[1] - 1)
    lane = jnp.take_along_axis(net.route_lanes[route], k[:, None], axis=1)[:, 0]
    pos_on_lane = pos - jnp.take_along_axis(starts, k[:, None], axis=1)[:, 0]
    return k, lane, pos_on_lane


def project(
    net: NetArrays, route: jax.Array, lane: jax.Array, pos_on_lane: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Position of every vehicle j along the route of every vehicle i.

    A vehicle on a lane of i's route is at that lane's offset plus its lane
    position. A vehicle on an internal lane merging into a lane of i's route
    is placed by its distance to the merge (SUMO's link leaders: both lanes
    are aligned where they come within 2.5 m of each other). A vehicle on the
    sibling of a lane of i's route (exit vs through) that has not yet diverged
    from it is placed on that lane. Others are nan.

    Returns:
        (proj, via_link): float (M_i, M_j) positions, bool (M_i, M_j) placed
        through a merge or a divergence rather than on i's own lanes.
    """
    lane_offset = net.lane_offset[route]  # (M_i, L)
    offset = lane_offset[:, lane]  # (M, M): lane of j on route of i
    direct = offset + pos_on_lane[None, :]
    # merge: align at the convergence points of the two internal lanes
    nxt = net.lane_next[lane]  # (M,)
    partner = net.lane_partner[lane]  # (M,)
    nxt_offset = lane_offset[:, jnp.maximum(nxt, 0)]  # (M, M)
    to_conv = net.lane_length[lane] - net.lane_converge[lane] - pos_on_lane  # (M,)
    mine_conv = jnp.where(partner >= 0, net.lane_converge[jnp.maximum(partner, 0)], 0.0)
    via_merge = nxt_offset - mine_conv[None, :] - to_conv[None, :]
    via_merge = jnp.where(nxt[None, :] >= 0, via_merge, jnp.nan)
    # divergence: still beside the sibling lane of i's route
    sib = net.lane_sibling[lane]  # (M,)
    sib_offset = lane_offset[:, jnp.maximum(sib, 0)]  # (M, M)
    not_apart = (sib >= 0) & (pos_on_lane < net.lane_diverge[lane])
    via_sibling = jnp.where(
        not_apart[None, :], sib_offset + pos_on_lane[None, :], jnp.nan
    )
    linked = jnp.where(jnp.isnan(via_merge), via_sibling, via_merge)
    on_route = ~jnp.isnan(offset)
    proj = jnp.where(on_route, direct, linked)
    return proj, ~on_route & ~jnp.isnan(linked)


def back_projection(
    net: NetArrays, route: jax.Array, pos: jax.Array, length: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Where each vehicle's back lies along each vehicle's route, (M_i, M_j).

    SUMO follows a leader as long as any part of it occupies a lane ahead on
    the follower's route: a vehicle turning off still leads until its back
    has left the shared lane.
    """
    _, lane, pos_on_lane = locate(net, route, jnp.maximum(pos - length, 0.0))
    return project(net, route, lane, pos_on_lane)


def leaders(
    proj: jax.Array, pos: jax.Array, active: jax.Array, length: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Nearest vehicle ahead along each vehicle's route (masked argmin).

    Args:
        proj: (M, M) from `project`; pos: (M,); active: bool (M,).
        length: vehicle length (scalar).

    Returns:
        (leader, gap): int (M,) slot of the leader (-1 for none) and float (M,)
        bumper-to-bumper gap (FAR for none).
    """
    m = pos.shape[0]
    ahead = proj - pos[:, None]  # (M, M)
    eye = jnp.eye(m, dtype=bool)
    # equal positions: the lower slot counts as ahead, so two never both lead
    slot_order = jnp.arange(m)[None, :] < jnp.arange(m)[:, None]
    ok = (
        active[None, :]
        & active[:, None]
        & ~eye
        & ~jnp.isnan(ahead)
        & ((ahead > 0) | ((ahead == 0) & slot_order))
    )
    dist = jnp.where(ok, ahead, jnp.inf)
    leader = jnp.argmin(dist, axis=1)
    has = jnp.isfinite(jnp.min(dist, axis=1))
    gap = jnp.where(has, jnp.min(dist, axis=1) - length, FAR)
    return jnp.where(has, leader, -1), gap


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
    active: jax.Array,
    waiting_s: jax.Array,
    dt: float,
) -> jax.Array:
    """SUMO's gap acceptance at the entry (MSLink::opened / blockedAtTime).

    The ego is a vehicle before its yield line; its foes are the vehicles that
    have registered their approach on the ring's through link at that entry:
    they will drive it, have not yet reached it, move, are not held back
    further upstream by their own entry, and are within their look-ahead.

    Args:
        route, pos, speed, speed_factor, waiting_s: float/int (M,) state.
        active: bool (M,).

    Returns:
        bool (M,): the entry is closed for the vehicle.
    """
    p = params
    a, b, length = p.accel, p.decel, p.length
    m = pos.shape[0]
    leg = net.route_origin[route]  # (M,)

    # 1. the ego's own approach (arrival at the yield line, leave past the merge)
    seen = net.yield_offset[route] - pos  # (M,)
    link_len = net.entry_internal_length[leg]
    v_link = jnp.minimum(
        net.lane_speed[net.route_lanes[route, 1]] * speed_factor, p.max_speed
    )
    a_s = jnp.minimum(jnp.sqrt(2 * a * jnp.maximum(seen, 0) + speed**2), v_link)
    l_s = jnp.minimum(v_link, jnp.sqrt(2 * a * link_len + a_s**2))
    a_t = minimal_arrival_time(jnp.maximum(seen, 0), speed, a_s, a, b)
    l_t = a_t + (link_len + length) / jnp.maximum(0.5 * (a_s + l_s), 1e-3)

    # 2. the foes' registrations on the through link of the ego's leg
    c_off = net.conflict_offset[route][:, leg].T  # (M_ego, M_foe)
    d_foe = c_off - pos[None, :]  # distance of each foe to that link
    through = net.through_length[leg][:, None]  # (M_ego, 1)
    v_thr = jnp.minimum(
        net.lane_speed[net.through_lane[leg]][:, None] * speed_factor[None, :],
        p.max_speed,
    )  # (M_ego, M_foe)
    vf = speed[None, :]
    f_as = jnp.minimum(jnp.sqrt(2 * a * jnp.maximum(d_foe, 0) + vf**2), v_thr)
    f_ls = jnp.minimum(v_thr, jnp.sqrt(2 * a * through + f_as**2))
    f_at = minimal_arrival_time(jnp.maximum(d_foe, 0), vf, f_as, a, b)
    f_lt = f_at + (through + length) / jnp.maximum(0.5 * (f_as + f_ls), 1e-3)
    f_asb = jnp.where(
        d_foe >= vf * (p.tau + vf / (2 * b)),
        0.0,
        jnp.sqrt(jnp.maximum(vf**2 - 2 * b * (d_foe - vf * p.tau), 0.0)),
    )
    # look-ahead: SUMO stops registering after a link once it has seen past
    # its braking distance and 5 vehicle lengths of normal lanes
    max_v = jnp.minimum(speed + a * dt, p.max_speed)
    reach = max_v * dt + brake_gap(max_v, b, p.tau, dt)  # (M,)
    k_link = net.conflict_index[route][:, leg].T  # (M_ego, M_foe) lane index of link
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
    # a vehicle held before its own entry (beyond the visibility distance)
    # withdraws its request on later links
    own_seen = net.yield_offset[route] - pos
    own_vis = net.entry_visibility[leg]
    held_back = own_seen > own_vis
    will_pass = active & (speed > 1e-3) & ~held_back  # (M,)
    foe = (
        will_pass[None, :]
        & ~jnp.isnan(c_off)
        & (d_foe > 0)
        & registered
        & (jnp.arange(m)[None, :] != jnp.arange(m)[:, None])
    )

    # 3. impatience: the foe may brake for the ego if the ego arrives first
    imp = jnp.clip(p.impatience + waiting_s / p.time_to_impatience, 0.0, 1.0)[:, None]
    mdec = jnp.maximum(imp * b, 1e-6)
    can_stop = vf**2 / (2 * mdec) <= d_foe
    disc = jnp.maximum(vf**2 - 2 * mdec * d_foe, 0.0)
    t_brake = jnp.where(can_stop, f_at + 30.0, (vf - jnp.sqrt(disc)) / mdec)
    asb_brake = jnp.where(can_stop, 0.0, jnp.sqrt(disc))
    use_imp = (imp > 0) & (a_t[:, None] < f_at)
    f_at_imp = jnp.where(use_imp, (1 - imp) * f_at + imp * t_brake, f_at)
    f_asb = jnp.where(use_imp, asb_brake, f_asb)

    # 4. MSLink::blockedByFoe with equal decelerations (unsafeMerge <=)
    tg = p.jm_timegap_minor
    behind = f_lt < a_t[:, None]
    blocked_behind = (a_t[:, None] - f_lt < tg) | (f_ls <= a_s[:, None])
    ahead = f_at_imp > l_t[:, None] + tg
    blocked_ahead = l_s[:, None] <= f_asb
    blocked = jnp.where(behind, blocked_behind, jnp.where(ahead, blocked_ahead, True))
    return active & (seen > 0) & jnp.any(foe & blocked, axis=1)


def normal_done(net: NetArrays, route: jax.Array, pos: jax.Array) -> jax.Array:
    """Metres of normal (non-internal) lanes driven so far along the route, (M,)."""
    k, lane, pos_on_lane = locate(net, route, pos)
    before = jnp.take_along_axis(net.normal_cum[route], k[:, None], axis=1)[:, 0]
    return before + jnp.where(net.lane_internal[lane], 0.0, pos_on_lane)


def internal_done(net: NetArrays, route: jax.Array, pos: jax.Array) -> jax.Array:
    """Metres of internal lanes driven so far along the route, (M,)."""
    k, lane, pos_on_lane = locate(net, route, pos)
    before = jnp.take_along_axis(net.internal_cum[route], k[:, None], axis=1)[:, 0]
    return before + jnp.where(net.lane_internal[lane], pos_on_lane, 0.0)


def planned_speed(
    net: NetArrays,
    params: EnvParams,
    route: jax.Array,
    pos: jax.Array,
    speed: jax.Array,
    speed_factor: jax.Array,
    active: jax.Array,
    waiting_s: jax.Array,
    dt: float,
    n_substeps: int,
    action_step: float,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Every vehicle's speed at the end of the step, as SUMO's IDM plans it.

    Returns:
        (v_next, leader, blocked): float (M,), int (M,) leader slot or -1,
        bool (M,) held at the yield line.
    """
    p = params
    k, lane, pos_on_lane = locate(net, route, pos)
    v_lane = jnp.minimum(net.lane_speed[lane] * speed_factor, p.max_speed)  # (M,)

    # 1. leader along the route, across lanes and merges
    back, via_link = back_projection(net, route, pos, p.length)  # (M, M)
    leader, gap = leaders(back + p.length, pos, active, p.length)
    v_leader = jnp.where(leader >= 0, speed[jnp.maximum(leader, 0)], 0.0)
    v_follow = idm.idm_follow_speed(
        speed, v_leader, gap, v_lane, p.accel, p.decel, p.tau, p.min_gap, p.delta,
        dt, n_substeps,
    )  # fmt: skip

    # 2. speed limits of the lanes ahead (and the free road on this one)
    starts = net.route_lane_start[route]  # (M, K)
    lanes_ahead = net.route_lanes[route]  # (M, K)
    limit_ahead = jnp.minimum(
        net.lane_speed[jnp.maximum(lanes_ahead, 0)] * speed_factor[:, None], p.max_speed
    )
    seen = starts - pos[:, None]
    later = (jnp.arange(starts.shape[1])[None, :] > k[:, None]) & (lanes_ahead >= 0)
    v_limits = idm.idm_free_speed_ahead(
        speed[:, None], seen, limit_ahead, v_lane[:, None], p.accel, p.decel, p.tau,
        p.delta, dt, n_substeps,
    )  # fmt: skip
    v_limits = jnp.maximum(v_limits, speed[:, None] - p.decel * dt)
    v_limits = jnp.min(jnp.where(later, v_limits, jnp.inf), axis=1)
    to_end = net.route_length[route] - pos
    v_free = idm.idm_free_speed(
        speed, v_lane, p.accel, p.decel, p.tau, p.min_gap, p.delta, dt, n_substeps,
        seen=to_end,
    )  # fmt: skip

    # 3. the entry's right of way: beyond the visibility distance a vehicle
    #    always plans to stop at its yield line; within it, only if blocked
    leg = net.route_origin[route]
    seen = net.yield_offset[route] - pos
    blocked = yield_blocked(
        net, p, route, pos, speed, speed_factor, active, waiting_s, dt
    )
    far = (seen > net.entry_visibility[leg]) & (
        brake_gap(speed, p.decel, 0.0, dt) < seen
    )
    must_stop = (seen > 0) & (blocked | far)
    v_stop = idm.idm_stop_speed(
        speed, seen - STOP_OFFSET, v_lane, p.accel, p.decel, p.tau, p.delta, dt,
        n_substeps, action_step,
    )  # fmt: skip
    v_wait = jnp.where(seen > 0, v_stop, 0.0)
    v_stop = jnp.where(must_stop, v_stop, jnp.inf)
    # a link leader (on the merging or diverging lane) never keeps a vehicle
    # from driving up to its own yield line
    leader_via_link = jnp.take_along_axis(
        via_link, jnp.maximum(leader, 0)[:, None], axis=1
    )[:, 0] & (leader >= 0)
    v_follow = jnp.where(leader_via_link, jnp.maximum(v_follow, v_wait), v_follow)

    v_safe = jnp.minimum(jnp.minimum(v_follow, v_limits), jnp.minimum(v_free, v_stop))
    v_next = idm.next_speed(
        speed, v_safe, v_lane, p.accel, p.decel, p.emergency_decel, dt, action_step
    )
    return jnp.where(active, v_next, 0.0), leader, blocked


def insertion_speed(
    v: jax.Array,
    v0: jax.Array,
    v_leader: jax.Array,
    gap: jax.Array,
    params: EnvParams,
    dt: float,
    n_substeps: int,
    iterations: int = 12,
) -> jax.Array:
    """SUMO's MSCFModel_IDM::insertionFollowSpeed, its recursion unrolled.

    Args:
        v: (G,) the speed to start from.
        v0: (G,) desired speed (lane limit * speed factor).
        v_leader: (G,) speed of the vehicle ahead.
        gap: (G,) gap to it after minGap (SUMO's gap2pred), >= 0.

    Returns:
        (G,) the speed the vehicle is inserted with.
    """
    p = params
    two_sqrt_ab = 2.0 * jnp.sqrt(p.accel * p.decel)

    def follow(speed: jax.Array) -> jax.Array:
        return idm.idm_follow_speed(
            speed, v_leader, gap + p.min_gap, v0, p.accel, p.decel, p.tau,
            p.min_gap, p.delta, dt, n_substeps,
        )  # fmt: skip

    speed, done = v, jnp.zeros_like(v, dtype=bool)
    for _ in range(iterations):
        s_star = jnp.maximum(
            0.0, speed * p.tau + speed * (speed - v_leader) / two_sqrt_ab
        )
        ok = gap >= s_star
        s2 = follow(speed)
        s3 = follow(s2)
        settle = s2 - s3 < dt
        speed = jnp.where(done | ok, speed, s2)
        done = done | ok | settle
    return speed


def insertion_stop_speed(
    v: jax.Array,
    v0: jax.Array,
    seen: jax.Array,
    params: EnvParams,
    dt: float,
    n_substeps: int,
    iterations: int = 12,
) -> jax.Array:
    """Insertion speed before the yield line `seen` metres ahead (SUMO, measured).

    While the line lies within the vehicle's braking distance plus minGap
    (SUMO's insertion look-ahead), the speed is lowered to the IDM stop speed
    for the line, the lane's speed `v0` staying the desired speed.

    Args:
        v: (G,) the speed to start from; v0: (G,) the desired speed;
        seen: (G,) distance from the front to the yield line.

    Returns:
        (G,) speed.
    """
    p = params
    speed = v
    for _ in range(iterations):
        reach = brake_gap(speed, p.decel, p.tau, dt) + p.min_gap
        too_fast = reach > seen - STOP_OFFSET
        s2 = idm.idm_v(
            speed, 0.0, seen, v0, p.accel, p.decel, p.tau, 0.0, p.delta, dt, n_substeps
        )
        speed = jnp.where(too_fast, jnp.minimum(s2, speed), speed)
    return speed
