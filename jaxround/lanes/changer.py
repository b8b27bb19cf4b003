"""The lane changes of one multi-lane edge in a step: `MSLaneChanger::laneChange`.

SUMO decides one vehicle at a time, front to back over all lanes of the
edge (`findCandidate`: the largest position first), after every vehicle has
moved. Each candidate sees the lanes as the vehicles ahead of it left them
(changed or not) and the vehicles behind it where they were; it looks right
first, then left (`MSLaneChanger::change`), and changes at once when it
wants to and is not blocked (no continuous lane changing). Messages to the
target lane's leader and follower take effect immediately: a follower
decides after its informer, with the informer's bits in its state.

`change_lanes` reproduces that order with a `lax.scan` over the vehicles
sorted by position; each step of the scan finds one candidate's neighbours
with masked minima over all slots, (M,) work, so a step costs (M, M).

Shapes: M vehicle slots, Z lanes (at most 2: `jaxround.lanes.road` checks).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxround.lanes.decide import Side, take_turn
from jaxround.lanes.follow import Driver
from jaxround.lanes.inform import slow_down_for_blocked
from jaxround.lanes.memory import after_change
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.views import Ego, LaneQ, Memory, Neighbour, push_advice

#: Far away (m).
FAR = 1e9


class EdgeView(NamedTuple):
    """An edge's vehicles after the move, and their lane tables.

    Attributes:
        pos, speed, accel: (M,) front position on the edge (m), speed, the
            acceleration of the move.
        lane: int (M,) lane index (0 rightmost).
        active: bool (M,).
        driver: `Driver` of (M,) arrays.
        v_max: (M, Z) each vehicle's `getVehicleMaxSpeed` on each lane.
        speed_limit, lane_length: (Z,).
        laneq_length, laneq_offset, next_occupation, ends_in_links: (M, Z)
            each vehicle's LaneQ per lane (`jaxround.lanes.views.LaneQ`),
            the occupation of the lanes beyond this edge.
    """

    pos: jax.Array
    speed: jax.Array
    accel: jax.Array
    lane: jax.Array
    active: jax.Array
    driver: Driver
    v_max: jax.Array
    speed_limit: jax.Array
    lane_length: jax.Array
    laneq_length: jax.Array
    laneq_offset: jax.Array
    next_occupation: jax.Array
    ends_in_links: jax.Array


class Changes(NamedTuple):
    """What `change_lanes` did. (M,) each.

    Attributes:
        lane: the lanes after the changes.
        direction: -1 right, +1 left, 0 none.
        state: the state a changer changed with (reason bits), 0 otherwise.
    """

    lane: jax.Array
    direction: jax.Array
    state: jax.Array


def _pick(tree, index):
    """Entry ``index`` of every (M,) leaf of ``tree`` (scalars as they are)."""
    return jax.tree.map(lambda x: x[index] if jnp.ndim(x) >= 1 else x, tree)


def _nearest(mask: jax.Array, distance: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(slot, exists) of the smallest ``distance`` where ``mask``, (M,) each."""
    d = jnp.where(mask, distance, jnp.inf)
    slot = jnp.argmin(d)
    return slot, jnp.isfinite(d[slot])


def _neighbour(edge: EdgeView, slot: jax.Array, exists: jax.Array, gap: jax.Array,
               lane: jax.Array) -> Neighbour:  # fmt: skip
    return Neighbour(
        exists=exists,
        gap=jnp.where(exists, gap, FAR),
        speed=edge.speed[slot],
        accel=edge.accel[slot],
        driver=_pick(edge.driver, slot),
        v_max=edge.v_max[slot, lane],
    )


def change_lanes(
    edge: EdgeView, memory: Memory, lc: LaneChangeParams, dt: float
) -> tuple[Changes, Memory]:
    """Every vehicle's lane change on the edge for one step, in SUMO's order.

    Args:
        edge: the vehicles after this step's move.
        memory: their LC2013 memory after `jaxround.lanes.memory.prepare_step`.
        lc: the lane-change parameters (scalars or (M,) per vehicle).
        dt: step length (s).

    Returns:
        (changes, memory): the lanes, directions and reasons; the memory with
        this step's states, probabilities and advices for the next step.
    """
    m = edge.pos.shape[0]
    n_lanes = edge.speed_limit.shape[0]
    slots = jnp.arange(m)
    # front to back; ties: the right lane first (findCandidate's strict <)
    order = jnp.lexsort((edge.lane, -edge.pos, ~edge.active))
    length_with_gap = edge.driver.length + edge.driver.min_gap

    def decide(carry, candidate):
        lane, mem, done, last_blocked, first_blocked, direction_out, state_out = carry
        i = candidate
        me = _pick(edge.driver, i)
        lc_i = _pick(lc, i)
        own = lane[i]
        ahead = edge.active & done  # decided this step: ahead of the candidate
        behind = edge.active & ~done & (slots != i)
        pos_i = edge.pos[i]
        # the leader on its own lane
        gap_ahead = edge.pos - edge.driver.length - pos_i - me.min_gap
        lead_slot, lead_exists = _nearest(ahead & (lane == own), edge.pos)
        leader = _neighbour(edge, lead_slot, lead_exists, gap_ahead[lead_slot], own)
        # occupation: the lengths registered on each lane so far this step
        dens = jnp.stack(
            [
                jnp.sum(jnp.where(ahead & (lane == z), length_with_gap, 0.0))
                for z in range(n_lanes)
            ]
        )
        occupation = dens + edge.next_occupation[i]

        def laneq(z):
            zc = jnp.clip(z, 0, n_lanes - 1)
            return LaneQ(
                length=edge.laneq_length[i, zc],
                best_lane_offset=edge.laneq_offset[i, zc],
                occupation=occupation[zc],
                ends_in_links=edge.ends_in_links[i, zc],
            )

        def ego_view(target):
            return Ego(
                speed=edge.speed[i], accel=edge.accel[i], pos=pos_i, driver=me,
                v_max=edge.v_max[i, own], neigh_v_max=edge.v_max[i, target],
                speed_limit=edge.speed_limit[own], lane_length=edge.lane_length[own],
            )  # fmt: skip

        curr = laneq(own)
        best = laneq(own + curr.best_lane_offset)
        state_me = mem.state[i]
        advices_me = mem.advices[i]
        # slowDownForBlocked: a vehicle that could not change into this lane
        for blocker in (last_blocked[own], first_blocked[own]):
            b = jnp.maximum(blocker, 0)
            ego_here = ego_view(own)
            blocked_view = _neighbour(edge, b, blocker >= 0, 0.0, own)
            bits, advice = slow_down_for_blocked(
                ego_here, blocked_view, edge.pos[b], dt
            )
            state_me = state_me | bits
            advices_me = push_advice(advices_me, advice)
        sides = []
        for direction in (-1, 1):
            target = own + direction
            tz = jnp.clip(target, 0, n_lanes - 1)
            nl_slot, nl_exists = _nearest(ahead & (lane == target), edge.pos)
            gap_behind = pos_i - me.length - edge.pos - edge.driver.min_gap
            nf_slot, nf_exists = _nearest(behind & (lane == target), -edge.pos)
            sides.append(Side(
                may=(target >= 0) & (target < n_lanes) & edge.active[i],
                ego=ego_view(tz), neigh=laneq(target),
                lead=_neighbour(edge, nl_slot, nl_exists, gap_ahead[nl_slot], tz),
                lead_slot=nl_slot,
                follow=_neighbour(edge, nf_slot, nf_exists, gap_behind[nf_slot], tz),
                follow_slot=nf_slot, bonus=0.0,
            ))  # fmt: skip
        turn, mem = take_turn(
            i, mem, state_me, advices_me, curr=curr, best=best, leader=leader,
            right=sides[0], left=sides[1], lc=lc_i, dt=dt,
        )  # fmt: skip
        # a vehicle blocked in an urgent change is remembered on the target lane
        for blocked_urgent, target in (
            (turn.blocked_right, own - 1), (turn.blocked_left, own + 1)
        ):  # fmt: skip
            tz = jnp.clip(target, 0, n_lanes - 1)
            last_blocked = jnp.where(
                blocked_urgent, last_blocked.at[tz].set(i), last_blocked
            )
            first_blocked = jnp.where(
                blocked_urgent & (first_blocked[tz] < 0),
                first_blocked.at[tz].set(i),
                first_blocked,
            )
        active = edge.active[i]
        direction = jnp.where(active, turn.direction, 0)
        change_state = turn.change_state
        mem = mem.replace(
            state=mem.state.at[i].set(jnp.where(active, turn.kept, mem.state[i]))
        )
        changed = slots == jnp.where(direction != 0, i, -1)
        mem = after_change(mem, changed)
        lane = lane.at[i].add(direction)
        carry = (
            lane, mem, done.at[i].set(True), last_blocked, first_blocked,
            direction_out.at[i].set(direction), state_out.at[i].set(change_state),
        )  # fmt: skip
        return carry, None

    none = -jnp.ones(n_lanes, jnp.int32)
    init = (
        edge.lane, memory, jnp.zeros(m, bool), none, none,
        jnp.zeros(m, jnp.int32), jnp.zeros(m, jnp.int32),
    )  # fmt: skip
    (lane, memory, _, _, _, direction, state), _ = jax.lax.scan(decide, init, order)
    return Changes(lane=lane, direction=direction, state=state), memory
