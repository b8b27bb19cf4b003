"""One simulation step of the roundabout as pure functions over vehicle slots.

Shapes: M vehicle slots, N scheduled vehicles, R routes, L lanes, K lanes per
route, G legs. The order of a step follows SUMO's ``MSNet::simulationStep``:
every vehicle plans its speed from the state at the start of the step
(`planned_speed`: the phases of `jaxround.core.planning` and
`jaxround.core.right_of_way`, then `final_speed`), all move at once (Euler),
arrivals leave, then waiting vehicles are inserted at the start of their
approach.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxround.core import command as traci
from jaxround.core import finalize, idm, planning, right_of_way
from jaxround.core.geometry import NetArrays
from jaxround.core.insertion import STOP_OFFSET
from jaxround.core.junction import Approach, brake_gap
from jaxround.core.neighbours import build_tables
from jaxround.core.params import CarFollowing
from jaxround.core.planning import (
    LaneLimits,
    OwnLeader,
    StartSpeeds,
    Stepping,
    Vehicles,
    YieldLine,
)
from jaxround.core.relax import blend, soft_or
from jaxround.core.right_of_way import Requests
from jaxround.core.state import Registrations

__all__ = [
    "ARRIVAL_EPS", "DEPART_OFFSET", "HALTING_SPEED", "final_speed", "planned_speed",
]  # fmt: skip

#: ``patch(v_min, v_max) -> v_next``, float (M,) each: a lane-change model's
#: say in the next speed within finalizeSpeed's bounds.
SpeedPatch = Callable[[jax.Array, jax.Array], jax.Array]

#: Speed below which SUMO counts a vehicle as waiting / halting (m/s).
HALTING_SPEED = 0.1
#: departPos="base": the front starts this far beyond the vehicle length (m).
DEPART_OFFSET = 0.1
#: A vehicle arrives when its front is this close to the end of its route (m).
ARRIVAL_EPS = 0.1


class Planned(NamedTuple):
    """`planned_speed`'s outcome. (M,) each unless said.

    Attributes:
        v_next: the speed at the end of the step (m/s).
        regs: this step's registrations, (M, G).
        blocked: bool, held at the yield line.
        leader, gap: the slot ahead on the vehicle's lanes (-1 for none), and
            the gap to it (m).
        own_entry: every vehicle's approach to its own entry link, the drive
            item it registered and tested (times absolute; meaningful before
            its yield line).
    """

    v_next: jax.Array
    regs: Registrations
    blocked: jax.Array
    leader: jax.Array
    gap: jax.Array
    own_entry: Approach


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
    command: jax.Array | None = None,
    patch: SpeedPatch | None = None,
    junction_order: tuple[jax.Array, jax.Array] | None = None,
) -> Planned:
    """Every vehicle's speed at the end of the step, as SUMO's IDM plans it:
    the phases of `jaxround.core.planning` and `jaxround.core.right_of_way`
    in SUMO's order.

    Args:
        params: each vehicle's car-following numbers (`EnvParams.for_vehicles`).
        route, pos, speed, speed_factor, waiting_s: (M,) state at time `t`.
        active: bool (M,).
        prev_regs: the registrations of the previous step.
        t: time at the start of the step.
        dt, n_substeps, action_step: the step (s), the IDM's sub-steps, the
            action step length (s).
        command: (M,) a TraCI speed command per vehicle for this step (NaN:
            none), applied where SUMO applies it (`jaxround.core.command`).
        patch: the lane-change model's ``patchSpeed`` on finalizeSpeed's
            bounds (two-lane roads: `jaxround.envs.lane_changes`); None: none.
        junction_order: where internal lanes cross (``net.crossing``), who
            came first: (clock, vid), float and int (M,), the time each
            front entered its conflict area (`crossing_leaders.conflict_clock`)
            and each slot's schedule index.

    Returns:
        `Planned`.
    """
    car = params
    if net.crossing is not None and junction_order is None:
        raise ValueError("net.crossing needs junction_order=(clock, vid)")
    clock, vid = (None, None) if junction_order is None else junction_order
    veh = Vehicles(route, pos, speed, speed_factor, active, waiting_s, clock, vid)
    step = Stepping(dt, n_substeps, action_step)
    # each phase in its own named scope: `jaxround bench --profile` reads
    # them back from the compiled program (`jaxround.apps.bench.profile`)
    with jax.named_scope("start_speeds"):
        start = planning.start_speeds(net, car, veh, step=step, command=command)
    with jax.named_scope("neighbour_tables"):
        tables = build_tables(net, route, pos, active, car.length)  # (R, M) ...
    with jax.named_scope("own_leader"):
        leader = planning.own_leader(net, car, veh, start, tables, step=step)
    with jax.named_scope("lane_limits"):
        limits = planning.lane_limits(net, car, veh, start, step=step)
    with jax.named_scope("yield_line"):
        line = planning.yield_line(net, car, veh, start, tables, step=step)
        # the link leaders at the next merge
        v_follow = jnp.minimum(leader.v_follow, line.v_link)
    with jax.named_scope("look_ahead"):
        ahead = right_of_way.look_ahead(
            net, car, veh, start, leader, limits, line, tables, step=step
        )
    with jax.named_scope("registrations"):
        requests = right_of_way.registrations(
            net, car, veh, start, leader, limits, line, ahead, prev_regs, t,
            v_follow=v_follow, step=step,
        )  # fmt: skip
    # link leaders at every merge of the look-ahead, not only the next one,
    # and where the next internal lane crosses another
    v_follow = jnp.minimum(v_follow, jnp.min(ahead.v_link_k, axis=1))
    v_follow = jnp.minimum(v_follow, line.v_cross)
    with jax.named_scope("entry_test"):
        blocked_w, own_entry = right_of_way.entry_test(
            net, car, veh, start, line, ahead, requests, t, step=step
        )
        v_hold = right_of_way.next_link_wait(
            net, car, veh, start, leader, limits, line, ahead, step=step
        )
    with jax.named_scope("final_speed"):
        v_next = final_speed(
            net, car, veh, start, leader, limits, line, requests,
            v_follow=v_follow, v_hold=v_hold, blocked_w=blocked_w, step=step,
            command=command, patch=patch,
        )  # fmt: skip
    return Planned(v_next, requests.regs, blocked_w > 0.5, leader.slot, leader.gap,
                   own_entry)  # fmt: skip


def final_speed(
    net: NetArrays,
    car: CarFollowing,
    veh: Vehicles,
    start: StartSpeeds,
    leader: OwnLeader,
    limits: LaneLimits,
    line: YieldLine,
    requests: Requests,
    *,
    v_follow: jax.Array,
    v_hold: jax.Array,
    blocked_w: jax.Array,
    step: Stepping,
    command: jax.Array | None,
    patch: SpeedPatch | None = None,
) -> jax.Array:
    """The speed at the end of the step, float (M,) (0 for empty slots):
    the safe speed, stopping at the yield line where the entry is blocked or
    still out of sight, held before the ring's next link after an entry the
    vehicle slowed down for, bounded by MSCFModel::finalizeSpeed; a TraCI command
    then applied as executeMove's processTraCISpeedControl does.

    Args:
        v_hold: (M,) `right_of_way.next_link_wait`, the speed of a vehicle
            that could still brake for its open entry.
    """
    speed, dt = veh.speed, step.dt
    seen = line.to_line
    too_late = ~line.can_brake & (seen < brake_gap(speed, car.emergency_decel, 0.0, dt))
    far = requests.beyond_visibility & line.can_brake
    must_stop_w = (seen > 0) * soft_or(blocked_w * ~too_late, far.astype(jnp.float32))
    # a vehicle that must stop at its line plans only up to it: leaders and
    # lane limits beyond the line do not count (SUMO's vSafe = vWait)
    leader_before_line = leader.back < net.yield_offset[veh.route]
    v_before_line = jnp.minimum(
        jnp.minimum(jnp.minimum(line.v_wait, limits.v_free), limits.v_limits),
        jnp.where(leader_before_line, leader.v_follow, jnp.inf),
    )
    v_safe = jnp.minimum(jnp.minimum(v_follow, limits.v_limits), limits.v_free)
    # an open entry it could still brake for: no request for the links after
    # it, so it plans to be able to stop before the ring's next link
    v_safe = jnp.where(requests.slowed, v_hold, v_safe)
    v_safe, v_safe_min = cross_or_stop(
        car, veh, start, line, requests, v_safe, step=step
    )
    v_safe = blend(must_stop_w, v_before_line, v_safe)
    if patch is None:
        v_next = finalize.next_speed(
            speed, v_safe, start.v_lane, accel=car.accel, decel=car.decel,
            emergency_decel=car.emergency_decel, dt=dt, action_step=step.action_step,
        )  # fmt: skip
    else:  # MSCFModel::finalizeSpeed hands its bounds to patchSpeed
        v_min, v_max = finalize.speed_bounds(
            speed, v_safe, start.v_lane, accel=car.accel, decel=car.decel,
            emergency_decel=car.emergency_decel, dt=dt, action_step=step.action_step,
        )  # fmt: skip
        v_next = patch(v_min, jnp.maximum(v_min, v_max))
        # executeMove: vNext = max(finalizeSpeed(vSafe), vSafeMin), the speed
        # that crosses an opened entry in time (a cooperative wish's slowdown
        # does not hold a vehicle back there)
        opened = (blocked_w < 0.5) & (must_stop_w < 0.5)
        v_next = finalize.snap_speed(
            jnp.maximum(v_next, jnp.where(opened, v_safe_min, 0.0)), dt
        )
    if command is not None:  # executeMove -> processTraCISpeedControl
        v_next = traci.influence_speed(
            command, v_next, v_safe=v_safe, v_max=start.v_max_next,
            v_min=start.v_min_next,
        )  # fmt: skip
        v_next = finalize.snap_speed(v_next, dt)
    return jnp.where(veh.active, v_next, 0.0)


def cross_or_stop(
    car: CarFollowing,
    veh: Vehicles,
    start: StartSpeeds,
    line: YieldLine,
    requests: Requests,
    v_safe: jax.Array,
    *,
    step: Stepping,
) -> tuple[jax.Array, jax.Array]:
    """processLinkApproaches' vSafeMin before an open entry within sight:
    a vehicle that plans to slow below its speed and below what crossing
    the entry needs (``vSafeMin``: the distance in one step, the entry's
    vLinkPass, the fastest next speed) while it could still stop there,
    stops before the entry instead ("cannot drive across a link so we need
    to stop before it": at most decel, down to the stop speed).

    Returns:
        (v_safe, v_safe_min): float (M,) each, the safe speed and the
        vSafeMin that still holds, at most the safe speed (0 where none: no
        open entry in sight, or the vehicle stops before it)."""
    speed, dt = veh.speed, step.dt
    seen = line.to_line
    open_in_sight = line.before_line & ~requests.beyond_visibility
    # the entry's vLinkPass: its drive item is set before the exit link's
    # link leaders (the merge's, the crossing's) are met in planMoveInternal
    v_pass = jnp.minimum(start.v_start, requests.approach_cap)
    v_safe_min = jnp.minimum(
        jnp.minimum((seen + STOP_OFFSET) / dt, v_pass), start.v_max_next
    )
    cannot_cross = (
        open_in_sight & line.can_brake & (v_safe + 1e-6 < v_safe_min) & (v_safe < speed)
    )
    v_stop = idm.idm_stop_speed(
        speed, seen, start.v_lane, vtype=car.idm, dt=dt,
        n_substeps=step.n_substeps, action_step=step.action_step,
    )  # fmt: skip
    braked = jnp.maximum(jnp.maximum(speed - car.decel * dt, 0.0), v_stop)
    # not above the safe speed: SUMO 1.28 drives on at its vSafe where that
    # is below vSafeMin and the vehicle speeds up (two_lane at 50% AVs,
    # 13.5 s: 5.4678 m/s, where vSafeMin reads 5.4798)
    kept_min = jnp.where(
        open_in_sight & ~cannot_cross, jnp.minimum(v_safe_min, v_safe), 0.0
    )
    return jnp.where(cannot_cross, jnp.minimum(v_safe, braked), v_safe), kept_min
