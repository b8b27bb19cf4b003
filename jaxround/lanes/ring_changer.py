"""LC2013 lane changes on a roundabout's lane paths, once per step.

`MSEdgeControl::changeLanes` runs `MSLaneChanger::laneChange` edge by edge;
within an edge the vehicles decide front to back (`jaxround.lanes.changer`
does one straight road). Here every vehicle is on a lane path
(`jaxround.lanes.paths`) and the edges are many: one `lax.scan` takes the
vehicles edge by edge (in lane-table order; SUMO takes them in the order
its lanes became occupied, which only matters where a neighbour is found
on another edge), front to back within an edge, ties to the right lane.

What a candidate sees, as `MSLaneChanger::getRealLeader`/`getRealFollower`
find it (SUMO's source as read in docs/lc2013-map.md section 2):

- a leader on its own or the target lane: the nearest vehicle ahead on
  that lane as the vehicles ahead of it left it; failing that, one whose
  back is still on the lane (partly on it); failing that, if the lane ends
  within ``brakeGap(v) + minGap`` (or the candidate is on an internal
  lane), the nearest vehicle on the lanes the path goes on to, on lanes that
  begin within that distance;
- a follower on the target lane: the nearest vehicle behind on it; failing
  that, among the vehicles on the lanes upstream of it (`RingLanes`'
  upstream table, searched as `MSLane::getFollowersOnConsecutive` does to
  the lanes' braking distance), the one whose secure gap is most
  violated, a vehicle coming over a minor link with its gap floored at 0.

Not here: link leaders (vehicles on a crossing or merging junction lane),
`getCriticalLeader`, `unsafeLinkAhead`, partial vehicles on the follower
side, stops.

Shapes: M vehicle slots, L lanes, P paths, K path positions, Z lanes of an
edge, C, U as in `jaxround.lanes.ring_tables`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxround.lanes import ring_neighbours as neighbours
from jaxround.lanes.changer import FAR, _pick
from jaxround.lanes.decide import Side, take_turn
from jaxround.lanes.follow import Driver
from jaxround.lanes.inform import slow_down_for_blocked
from jaxround.lanes.memory import after_change
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.ring_neighbours import RingArrays, Scene
from jaxround.lanes.views import Ego, LaneQ, Memory, Neighbour, push_advice


class RingVehicles(NamedTuple):
    """The vehicles after this step's move. (M,) each.

    Attributes:
        path: int lane path; pos: front position along it (m).
        speed, accel: after the move (m/s, m/s^2).
        active: bool; driver: `Driver` of (M,) arrays; speed_factor.
    """

    path: jax.Array
    pos: jax.Array
    speed: jax.Array
    accel: jax.Array
    active: jax.Array
    driver: Driver
    speed_factor: jax.Array


class Sight(NamedTuple):
    """What each vehicle saw at its turn, to the right (column 0) and left
    (1). (M, 2) each: the state it wanted (blocked bits in), the target
    lane's leader and follower (slot, -1 for none) and their gaps (m), the
    roundabout bonus (m)."""

    state: jax.Array
    lead: jax.Array
    lead_gap: jax.Array
    follow: jax.Array
    follow_gap: jax.Array
    bonus: jax.Array


class RingChanges(NamedTuple):
    """What `change_lanes` did. (M,) each: the paths and positions after the
    changes, the lanes, -1/0/+1 for right/none/left, and the state a vehicle
    changed with (0 otherwise); and what every vehicle saw."""

    path: jax.Array
    pos: jax.Array
    lane: jax.Array
    direction: jax.Array
    state: jax.Array
    sight: Sight


def locate(net: RingArrays, path: jax.Array, pos: jax.Array) -> tuple[jax.Array, ...]:
    """(k, lane, pos_on_lane), (M,) each, of vehicles at ``pos`` on ``path``."""
    starts = net.path_lane_start[path]
    k = jnp.clip(jnp.sum(starts <= pos[:, None], axis=1) - 1, 0, starts.shape[1] - 1)
    lane = jnp.take_along_axis(net.path_lanes[path], k[:, None], axis=1)[:, 0]
    start = jnp.take_along_axis(starts, k[:, None], axis=1)[:, 0]
    return k, lane, pos - start


def change_lanes(
    net: RingArrays,
    veh: RingVehicles,
    memory: Memory,
    lc: LaneChangeParams,
    dt: float,
) -> tuple[RingChanges, Memory]:
    """Every vehicle's lane change for one step, in SUMO's order.

    Args:
        veh: the vehicles after this step's move.
        memory: their LC2013 memory after `jaxround.lanes.memory.prepare_step`.
        lc: lane-change parameters (scalars or (M,)).
    """
    m = veh.pos.shape[0]
    slots = jnp.arange(m)
    driver = veh.driver
    k0, lane0, on_lane = locate(net, veh.path, veh.pos)
    order = jnp.lexsort((net.lane_index[lane0], -on_lane, net.lane_order[lane0],
                         ~veh.active))  # fmt: skip
    brutto = driver.length + driver.min_gap
    v_max_on = jnp.minimum(  # (M, L) getVehicleMaxSpeed on every lane
        driver.max_speed[:, None], net.lane_speed[None, :] * veh.speed_factor[:, None]
    )
    n_lanes = net.lane_length.shape[0]

    def neighbour(slot, exists, gap, lane_of_slot) -> Neighbour:
        return Neighbour(
            exists=exists, gap=jnp.where(exists, gap, FAR), speed=veh.speed[slot],
            accel=veh.accel[slot], driver=_pick(driver, slot),
            v_max=v_max_on[slot, lane_of_slot],
        )  # fmt: skip

    def decide(carry, i):
        lane, path, done, last_blocked, first_blocked, mem, dir_out, state_out = carry
        me = _pick(driver, i)
        lc_i = _pick(lc, i)
        p, k, own, pos_i = path[i], k0[i], lane[i], on_lane[i]
        active_i = veh.active[i]
        others = veh.active & (slots != i)
        occupied = jnp.zeros(n_lanes).at[lane].add(jnp.where(veh.active, brutto, 0.0))

        scene = Scene(lane=lane, on_lane=on_lane, speed=veh.speed, driver=driver,
                      others=others, done=done)  # fmt: skip

        def leader_on(q, target):
            return neighbours.leader_on(net, scene, i, q, target, own, dt)

        def follower_on(target):
            return neighbours.follower_on(net, scene, i, target)

        # occupation: dens on this edge + nextOccupation beyond it
        edge = net.edge_lanes[p, k]  # (Z,)
        dens = jnp.array([
            jnp.sum(jnp.where(veh.active & done & (lane == edge[z]), brutto, 0.0))
            for z in range(edge.shape[0])
        ])  # fmt: skip
        nxt = net.laneq_next[p, k]  # (Z, C)
        next_occ = jnp.sum(jnp.where(nxt >= 0, occupied[jnp.maximum(nxt, 0)], 0.0), 1)
        z_own = net.lane_index[own]

        def laneq(z):
            zc = jnp.clip(z, 0, edge.shape[0] - 1)
            return LaneQ(
                length=net.laneq_length[p, k, zc],
                best_lane_offset=net.laneq_offset[p, k, zc],
                occupation=dens[zc] + next_occ[zc],
                ends_in_links=net.laneq_ends[p, k, zc],
            )

        def ego_view(target):
            return Ego(
                speed=veh.speed[i], accel=veh.accel[i], pos=pos_i, driver=me,
                v_max=v_max_on[i, own], neigh_v_max=v_max_on[i, target],
                speed_limit=net.lane_speed[own], lane_length=net.lane_length[own],
            )  # fmt: skip

        def bonus(side):
            return neighbours.roundabout_bonus(
                net, occupied, (p, k, z_own, side), own, pos_i, lc_i.cooperative
            )

        curr = laneq(z_own)
        best = laneq(z_own + curr.best_lane_offset)
        own_lead, own_exists, own_gap = leader_on(p, own)
        leader = neighbour(own_lead, own_exists, own_gap, lane[own_lead])
        state_me, advices_me = mem.state[i], mem.advices[i]
        for blocker in (last_blocked[own], first_blocked[own]):
            b = jnp.maximum(blocker, 0)
            blocked_view = neighbour(b, blocker >= 0, 0.0, lane[b])
            bits, advice = slow_down_for_blocked(ego_view(own), blocked_view,
                                                 on_lane[b], dt)  # fmt: skip
            state_me = state_me | bits
            advices_me = push_advice(advices_me, advice)
        sides, targets, seen = [], [], []
        for side in (0, 1):
            target = net.lane_side[own, side]
            new_path = net.change_path[p, k, side]
            tz = jnp.maximum(target, 0)
            q = jnp.maximum(new_path, 0)
            lead_slot, lead_exists, lead_gap = leader_on(q, tz)
            follow_slot, follow_exists, follow_gap = follower_on(tz)
            sides.append(Side(
                may=(target >= 0) & (new_path >= 0) & active_i,
                ego=ego_view(tz), neigh=laneq(net.lane_index[tz]),
                lead=neighbour(lead_slot, lead_exists, lead_gap, lane[lead_slot]),
                lead_slot=lead_slot,
                follow=neighbour(follow_slot, follow_exists, follow_gap,
                                 lane[follow_slot]),
                follow_slot=follow_slot, bonus=bonus(side),
            ))  # fmt: skip
            targets.append((tz, q))
            seen.append((
                jnp.where(lead_exists, lead_slot, -1), lead_gap,
                jnp.where(follow_exists, follow_slot, -1), follow_gap, sides[-1].bonus,
            ))  # fmt: skip
        turn, mem = take_turn(
            i, mem, state_me, advices_me, curr=curr, best=best, leader=leader,
            right=sides[0], left=sides[1], lc=lc_i, dt=dt,
        )  # fmt: skip
        for blocked_urgent, (tz, _) in zip(
            (turn.blocked_right, turn.blocked_left), targets, strict=True
        ):
            last_blocked = jnp.where(blocked_urgent, last_blocked.at[tz].set(i),
                                     last_blocked)  # fmt: skip
            first_blocked = jnp.where(
                blocked_urgent & (first_blocked[tz] < 0),
                first_blocked.at[tz].set(i), first_blocked,
            )  # fmt: skip
        # no changer on its edge (one lane, or changing not allowed): SUMO
        # registers it unchanged without asking the model
        decides = active_i & ((net.change_path[p, k] >= 0).any())
        direction = jnp.where(decides, turn.direction, 0)
        mem = mem.replace(
            state=mem.state.at[i].set(jnp.where(decides, turn.kept, mem.state[i]))
        )
        mem = after_change(mem, slots == jnp.where(direction != 0, i, -1))
        to_lane = jnp.where(direction < 0, targets[0][0], targets[1][0])
        to_path = jnp.where(direction < 0, targets[0][1], targets[1][1])
        lane = lane.at[i].set(jnp.where(direction != 0, to_lane, own))
        path = path.at[i].set(jnp.where(direction != 0, to_path, p))
        carry = (
            lane,
            path,
            done.at[i].set(True),
            last_blocked,
            first_blocked,
            mem,
            dir_out.at[i].set(direction),
            state_out.at[i].set(jnp.where(direction != 0, turn.change_state, 0)),
        )
        sight = Sight(
            jnp.stack([turn.state_right, turn.state_left]),
            *(jnp.stack([seen[0][f], seen[1][f]]) for f in range(5)),
        )
        return carry, sight

    none = -jnp.ones(n_lanes, jnp.int32)
    zeros = jnp.zeros(m, jnp.int32)
    init = (lane0, veh.path, jnp.zeros(m, bool), none, none, memory, zeros, zeros)
    (lane, path, _, _, _, memory, direction, state), seen = jax.lax.scan(
        decide, init, order
    )
    sight = jax.tree.map(lambda x: jnp.zeros_like(x).at[order].set(x), seen)
    old_start = jnp.take_along_axis(net.lane_offset[veh.path], lane0[:, None], 1)[:, 0]
    new_start = jnp.take_along_axis(net.lane_offset[path], lane[:, None], 1)[:, 0]
    pos = jnp.where(direction != 0, veh.pos - old_start + new_start, veh.pos)
    return RingChanges(path, pos, lane, direction, state, sight), memory
