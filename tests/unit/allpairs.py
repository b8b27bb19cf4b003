"""The all-pairs neighbour searches the step used before `jaxround.core.neighbours`.

Kept as they were at commit b6603e8, for the tests to compare the tables
with: every pair of slots, and for the rearmost vehicle every pair for every
segment, (M, M) and (M, M, S) masks reduced by `jnp.argmin`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core import idm
from jaxround.core.geometry import FAR, NetArrays, locate, project
from jaxround.core.insertion import STOP_OFFSET
from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs.observe import DISTANCE_SCALE, MISSING, RING_HORIZON_S, SPEED_SCALE


def rearmost_on(
    front: jax.Array,
    back: jax.Array,
    pos: jax.Array,
    active: jax.Array,
    seg_start: jax.Array,
    seg_end: jax.Array,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The rearmost vehicle with any part on [seg_start, seg_end) of each
    vehicle's route, ahead of it (SUMO's getLastVehicleInformation of a lane).

    Args: front, back (M_i, M_j) projections; seg_start, seg_end (M_i, S).
    Returns: (has, j, gap) (M_i, S): gap bumper to bumper.
    """
    m = pos.shape[0]
    others = jnp.arange(m)[None, :] != jnp.arange(m)[:, None]
    ok = active[None, :] & active[:, None] & others & (front > pos[:, None])
    ok = ok & ~jnp.isnan(front)
    touch = (
        ok[:, :, None]
        & (front[:, :, None] > seg_start[:, None, :])
        & (back[:, :, None] < seg_end[:, None, :])
    )  # (M_i, M_j, S)
    b = jnp.where(touch, back[:, :, None], jnp.inf)
    j = jnp.argmin(b, axis=1)
    bmin = jnp.min(b, axis=1)
    return jnp.isfinite(bmin), j, bmin - pos[:, None]


def link_leaders(
    net: NetArrays,
    route: jax.Array,
    pos: jax.Array,
    active: jax.Array,
    length: jax.Array,
    min_gap: jax.Array,
    km_fixed: int | jax.Array | None = None,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Vehicles on the lane that merges with each vehicle's next merging lane.

    SUMO's link leaders (MSLink::getLeaderInfo): every vehicle with any part
    on the merge partner of the next internal lane of i's route that merges
    into a shared lane, with the gap measured to the crossing point where the
    two lanes come within 2.5 m. The gap may be negative (the leader is
    already level with or beside the crossing).

    Returns:
        (is_link, gap, front_on_partner, to_link): bool (M_i, M_j), float
        (M_i, M_j) SUMO's gap after minGap, bool (M_i, M_j) the leader's front
        is still on the partner lane, float (M_i,) distance to the start of
        i's merging lane (negative once on it).
    """
    k, _, _ = locate(net, route, pos)
    km = jnp.take_along_axis(net.merge_index[route], k[:, None], axis=1)[:, 0]  # (M,)
    if km_fixed is not None:  # the merge at route lane km_fixed, if it merges
        kf = jnp.full_like(km, km_fixed)
        lane_f = jnp.take_along_axis(net.route_lanes[route], kf[:, None], axis=1)[:, 0]
        ok_f = (lane_f >= 0) & (net.lane_partner[jnp.maximum(lane_f, 0)] >= 0)
        km = jnp.where(ok_f & (kf >= k), kf, -1)
    has_merge = km >= 0
    km = jnp.maximum(km, 0)
    mine = jnp.take_along_axis(net.route_lanes[route], km[:, None], axis=1)[:, 0]
    start = jnp.take_along_axis(net.route_lane_start[route], km[:, None], axis=1)[:, 0]
    partner = jnp.maximum(net.lane_partner[mine], 0)  # (M,)
    to_crossing = start + net.lane_length[mine] - net.lane_converge[mine] - pos  # (M,)
    # where the partner lane starts along each j's route (nan if j avoids it)
    q_off = net.lane_offset[route][:, partner].T  # (M_i, M_j)
    q_len = net.lane_length[partner][:, None]
    back_on_q = pos[None, :] - length - q_off  # j's back along the partner lane
    front_on_q = pos[None, :] - q_off
    touches = (front_on_q > 0) & (back_on_q < q_len)
    back_dist = q_len - net.lane_converge[partner][:, None] - back_on_q
    extra = jnp.maximum(0.0, net.lane_converge[partner] - net.lane_converge[mine])[
        :, None
    ]
    back_dist = jnp.where(back_dist < 0, back_dist + extra, back_dist)
    gap = to_crossing[:, None] - min_gap - back_dist
    # once both are on their merging lanes, only the one nearer the crossing
    # leads (the ring's through lane wins a tie): two never wait for each other
    on_junction = (start - pos <= 0)[:, None]
    foe_to_crossing = q_len - net.lane_converge[partner][:, None] - front_on_q
    foe_is_ring = jnp.any(partner[:, None] == net.through_lane[None, :], axis=1)
    nearer = (foe_to_crossing < to_crossing[:, None]) | (
        (foe_to_crossing == to_crossing[:, None]) & foe_is_ring[:, None]
    )
    m = pos.shape[0]
    is_link = (
        has_merge[:, None]
        & active[:, None]
        & active[None, :]
        & ~jnp.isnan(q_off)
        & touches
        & (~on_junction | nearer)
        & (jnp.arange(m)[None, :] != jnp.arange(m)[:, None])
    )
    return is_link, gap, front_on_q <= q_len, start - pos


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


def link_leader_speed(
    net: NetArrays,
    params: EnvParams,
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
    p = params
    is_link, gap, front_on_q, to_link = link_leaders(
        net, route, pos, active, p.length, p.min_gap, km_fixed=km_fixed
    )
    gap = jnp.where(is_link, gap, jnp.inf)
    nearest = jnp.argmin(gap, axis=1)  # (M,)
    has = jnp.isfinite(jnp.min(gap, axis=1))
    gap = jnp.where(has, jnp.min(gap, axis=1), 0.0)
    front_on_q = jnp.take_along_axis(front_on_q, nearest[:, None], 1)[:, 0]
    v = idm.idm_follow_speed(
        speed, speed[nearest], gap + p.min_gap, v_lane, vtype=p.idm, dt=dt,
        n_substeps=n_substeps,
    )  # fmt: skip
    v_stop = idm.idm_stop_speed(
        speed, to_link - STOP_OFFSET, v_lane, vtype=p.idm, dt=dt,
        n_substeps=n_substeps, action_step=action_step,
    )  # fmt: skip
    v = jnp.where(gap >= 0, v, jnp.where(to_link > 0, v_stop, 0.0))
    v = jnp.where(may_drive_to_line & front_on_q, jnp.maximum(v, v_wait), v)
    return jnp.where(has, v, jnp.inf), to_link


def paper_observation(
    net: NetArrays, state: EnvState, params: EnvParams
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Eq. 1 of the paper for every slot.

    Returns:
        (obs, leader, gap): float (M, 10); int (M,) slot ahead (-1 for none)
        and float (M,) bumper-to-bumper gap to it, for the rich observer.
    """
    x_max = jnp.max(net.route_length)
    a_max = params.av.accel
    _, lane, pos_on_lane = locate(net, state.route, state.pos)
    front = project(net, state.route, lane, pos_on_lane)  # (M, M)
    leader, gap = leaders(front, state.pos, state.active, params.vehicle.length)
    # the follower: the nearest front behind this vehicle's back on its route
    behind = state.pos[:, None] - params.vehicle.length - front  # (M, M)
    m = state.pos.shape[0]
    ok = (
        state.active[None, :]
        & state.active[:, None]
        & (jnp.arange(m)[None, :] != jnp.arange(m)[:, None])
        & ~jnp.isnan(behind)
        & (behind >= 0)
    )
    dist = jnp.where(ok, behind, jnp.inf)
    follower = jnp.argmin(dist, axis=1)
    has_follower = jnp.isfinite(jnp.min(dist, axis=1))
    has_leader = leader >= 0
    lead = jnp.maximum(leader, 0)
    a = state.accel
    x_front = jnp.where(has_leader, state.pos + gap + params.vehicle.length, 0.0)
    x_back = jnp.where(
        has_follower, state.pos - params.vehicle.length - jnp.min(dist, axis=1), 0.0
    )
    none = jnp.zeros(m)
    obs = jnp.stack(
        [
            state.pos / x_max,
            a / a_max,
            jnp.where(has_leader, x_front / x_max, MISSING),
            jnp.where(has_leader, (a[lead] - a) / a_max, 0.0),
            jnp.where(has_follower, x_back / x_max, MISSING),
            jnp.where(has_follower, (a[follower] - a) / a_max, 0.0),
            none + MISSING,  # left: single-lane roads have no neighbour beside
            none,
            none + MISSING,  # right
            none,
        ],
        axis=-1,
    )
    return jnp.where(state.active[:, None], obs, 0.0), leader, gap


def rich_observation(
    net: NetArrays,
    state: EnvState,
    params: EnvParams,
    route_destination: jax.Array,
) -> jax.Array:
    """The paper's 10 numbers and 7 more, float (M, 17).

    Args:
        route_destination: int (R,) exit leg of each route.
    """
    base, leader, gap = paper_observation(net, state, params)
    g = net.through_length.shape[0]
    lead = jnp.maximum(leader, 0)
    has_leader = leader >= 0
    origin = net.route_origin[state.route]  # (M,)
    to_line = net.yield_offset[state.route] - state.pos  # (M,)
    # how soon the ring traffic upstream reaches this vehicle's entry: each
    # vehicle's distance to the ring's point level with the entry over its
    # speed (at least 1 m/s); from positions only, so SUMO gives the same
    c_off = net.conflict_offset[state.route][:, origin].T  # (M_i, M_j)
    dist = c_off - state.pos[None, :]
    m = state.pos.shape[0]
    coming = (
        state.active[None, :]
        & ~jnp.isnan(dist)
        & (dist > 0)
        & (jnp.arange(m)[None, :] != jnp.arange(m)[:, None])
    )
    # dist is nan off the route: divide only where coming (finite gradients)
    dist = jnp.where(coming, dist, 0.0)
    eta = jnp.where(coming, dist / jnp.maximum(state.speed[None, :], 1.0), jnp.inf)
    soonest = jnp.min(eta, axis=1)
    legs_to_exit = (route_destination[state.route] - origin) % g
    extra = jnp.stack(
        [
            state.speed / SPEED_SCALE,
            jnp.where(has_leader, jnp.minimum(gap / DISTANCE_SCALE, 1.0), 1.0),
            jnp.where(has_leader, (state.speed[lead] - state.speed) / SPEED_SCALE, 0.0),
            jnp.clip(to_line / DISTANCE_SCALE, -1.0, 1.0),
            jnp.clip(soonest / RING_HORIZON_S, 0.0, 1.0),
            legs_to_exit / g,
            jnp.minimum(state.waiting_s / params.vehicle.time_to_impatience, 1.0),
        ],
        axis=-1,
    )
    obs = jnp.concatenate([base, extra], axis=-1)
    return jnp.where(state.active[:, None], obs, 0.0)
