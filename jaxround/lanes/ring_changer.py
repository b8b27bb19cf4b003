"""LC2013 lane changes on a roundabout's lane paths, once per step.

`MSEdgeControl::changeLanes` runs `MSLaneChanger::laneChange` edge by edge;
within an edge the vehicles decide front to back (`jaxround.lanes.changer`
does one straight road). Here every vehicle is on a lane path
(`jaxround.lanes.paths`) and the edges are many: the turns
(`jaxround.lanes.ring_turns`, one loop) take the vehicles edge by edge (in
the order of `RingArrays.lane_order`, `context`: the step passes SUMO's,
`jaxround.lanes.active_lanes`; the table's own is lane-table order),
front to back within an edge, ties to the right lane, empty slots last.
This module is one turn (`turn`) and what the step makes of the turns
(`changes`); a turn is one look, to the one side with a lane
(`jaxround.lanes.decide.turn_of_one_side`).

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

SUMO 1.28's hold before an entry is `jaxround.lanes.entry_hold`'s, given
as `RingVehicles.entry_hold`. The vehicles about to merge ahead on the
target lane (link leaders, as the target lane's leader and as
`getCriticalLeader` finds them) are `jaxround.lanes.merge_leaders`'s,
given as `RingVehicles.merge`. Not here: link leaders of crossing junction
lanes, `unsafeLinkAhead`, partial vehicles on the follower side, stops.

Shapes: M vehicle slots, L lanes, P paths, K path positions, Z lanes of an
edge, C, U as in `jaxround.lanes.ring_tables`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxround.lanes import ring_neighbours as neighbours
from jaxround.lanes import traci
from jaxround.lanes.changer import FAR, _pick
from jaxround.lanes.decide import Kept, Side, Told, turn_of_one_side
from jaxround.lanes.follow import Driver, secure_gap
from jaxround.lanes.inform import slow_down_for_blocked
from jaxround.lanes.merge_leaders import MergeLeaders
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.ring_neighbours import RingArrays, Scene
from jaxround.lanes.views import Ego, LaneQ, Memory, Neighbour, push_advice


class RingVehicles(NamedTuple):
    """The vehicles after this step's move. (M,) each.

    Attributes:
        path: int lane path; pos: front position along it (m).
        speed, accel: after the move (m/s, m/s^2).
        active: bool; driver: `Driver` of (M,) arrays; speed_factor.
        lane_request: int lane index a TraCI request asks for this step
            (`jaxround.lanes.traci`, lasting the step; -1 or None: none).
        entry_hold: bool (M, 2) a change right / left would be held back at
            the target lane's entry link (`jaxround.lanes.entry_hold`; None:
            never).
        merge: the merge link leaders on the target lanes
            (`jaxround.lanes.merge_leaders`; None: none).
        fastest_departed: float () the largest speed factor of the vehicles
            departed so far, at least 1 (the followers' search).
    """

    path: jax.Array
    pos: jax.Array
    speed: jax.Array
    accel: jax.Array
    active: jax.Array
    driver: Driver
    speed_factor: jax.Array
    lane_request: jax.Array | None = None
    entry_hold: jax.Array | None = None
    merge: MergeLeaders | None = None
    fastest_departed: jax.Array | float = 1.0


class Sight(NamedTuple):
    """What each vehicle saw at its turn, to the right (column 0) and left
    (1). (M, 2) each: the state it wanted (blocked bits in), the target
    lane's leader and follower (slot, -1 for none) and their gaps (m), the
    roundabout bonus (m); 0, -1, inf, -1, inf, 0 on a side without a lane."""

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


class Context(NamedTuple):
    """What every turn of one step reads: the network, the vehicles after
    the move (`RingVehicles`), the parameters, and where the vehicles stand
    before any change ((M,) each: path position ``k``, ``lane``, ``on_lane``
    position (m), ``brutto`` length + minGap (m)), ``order`` (M,) their
    turns, and
    ``decides`` bool (M,) the vehicle is on an edge with a changer."""

    net: RingArrays
    veh: RingVehicles
    lc: LaneChangeParams
    dt: float
    k: jax.Array
    lane: jax.Array
    on_lane: jax.Array
    brutto: jax.Array
    order: jax.Array
    decides: jax.Array

    def v_max(self, slot: jax.Array, lane: jax.Array) -> jax.Array:
        """`MSLane::getVehicleMaxSpeed` of the vehicles in ``slot`` on
        ``lane`` (same shapes)."""
        driver, speed_factor = self.veh.driver, self.veh.speed_factor
        return jnp.minimum(
            driver.max_speed[slot], self.net.lane_speed[lane] * speed_factor[slot]
        )


class View(NamedTuple):
    """What one vehicle finds at its turn, left by the turns before it:
    the lanes (M,) and who had a turn (M,); the last and first vehicle
    registered blocked on its lane (slots, -1: none); its state and
    advices (A,) with the messages it got; every vehicle's own state (M,),
    as far as it decides a wish (the LEFT and RIGHT bits, which no message
    carries)."""

    lane: jax.Array
    done: jax.Array
    last_blocked: jax.Array
    first_blocked: jax.Array
    state: jax.Array
    advices: jax.Array
    states: jax.Array


class Outcome(NamedTuple):
    """One vehicle's turn. Scalars unless said.

    Attributes:
        direction: -1/0/+1; change_state: the state it changed with (0: none).
        state: its `myOwnState` after the turn (before `changed()`).
        kept: its probabilities, look-ahead speed and advices.
        told: its messages (2,), to the target lane's leader and follower.
        blocked, target: (2,) right and left: registered blocked on the
            target lane, and that lane.
        to_lane, to_path: where a change takes it.
        sight: what it saw, (2,) each.
    """

    direction: jax.Array
    change_state: jax.Array
    state: jax.Array
    kept: Kept
    told: Told
    blocked: jax.Array
    target: jax.Array
    to_lane: jax.Array
    to_path: jax.Array
    sight: Sight


def context(
    net: RingArrays, veh: RingVehicles, lc: LaneChangeParams, dt: float
) -> Context:
    """The step's `Context`; the turns go edge by edge in the order of
    ``net.lane_order`` (`jaxround.lanes.active_lanes`), front to back
    within an edge, ties to the right lane; the vehicles on an edge without
    a changer come after them (their turns change nothing: SUMO has no
    changer there), empty slots last."""
    k, lane, on_lane = locate(net, veh.path, veh.pos)
    decides = veh.active & (net.change_path[veh.path, k] >= 0).any(axis=-1)
    # (~active, ~decides, lane order) as one key: a sort of three keys, not five
    n_lanes = net.lane_order.shape[0]
    group = net.lane_order[lane] + n_lanes * (
        (~decides).astype(jnp.int32) + 2 * (~veh.active).astype(jnp.int32)
    )
    order = jnp.lexsort((net.lane_index[lane], -on_lane, group))
    brutto = veh.driver.length + veh.driver.min_gap
    return Context(net, veh, lc, dt, k, lane, on_lane, brutto, order, decides)


def turn(ctx: Context, i: jax.Array, view: View, memory: Memory) -> Outcome:
    """Vehicle ``i``'s turn, as it finds the step (``memory``: its
    probabilities and look-ahead speed, row ``i``, are read)."""
    net, veh, dt = ctx.net, ctx.veh, ctx.dt
    driver, lane, on_lane = veh.driver, view.lane, ctx.on_lane
    slots = jnp.arange(veh.pos.shape[0])
    me = _pick(driver, i)
    lc_i = _pick(ctx.lc, i)
    p, k, own, pos_i = veh.path[i], ctx.k[i], ctx.lane[i], on_lane[i]
    active_i = veh.active[i]
    others = veh.active & (slots != i)
    n_lanes = net.lane_length.shape[0]
    weight = jnp.where(veh.active, ctx.brutto, 0.0)
    occupied = jnp.zeros(n_lanes).at[lane].add(weight)
    scene = Scene(lane=lane, on_lane=on_lane, speed=veh.speed, driver=driver,
                  others=others, done=view.done,
                  fastest_departed=veh.fastest_departed, path=veh.path)  # fmt: skip

    def neighbour(slot, exists, gap) -> Neighbour:
        return Neighbour(
            exists=exists, gap=jnp.where(exists, gap, FAR), speed=veh.speed[slot],
            accel=veh.accel[slot], driver=_pick(driver, slot),
            v_max=ctx.v_max(slot, lane[slot]), state=view.states[slot],
        )  # fmt: skip

    # occupation: dens on this edge + nextOccupation beyond it
    edge = net.edge_lanes[p, k]  # (Z,)
    dens = jnp.sum(
        jnp.where(view.done[None, :] & (lane[None, :] == edge[:, None]), weight, 0.0),
        axis=1,
    )
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
            v_max=ctx.v_max(i, own), neigh_v_max=ctx.v_max(i, target),
            speed_limit=net.lane_speed[own], lane_length=net.lane_length[own],
        )  # fmt: skip

    curr = laneq(z_own)
    best = laneq(z_own + curr.best_lane_offset)
    own_lead, own_exists, own_gap = neighbours.leader_on(net, scene, i, p, own, own, dt)
    leader = neighbour(own_lead, own_exists, own_gap)
    state_me, advices_me = view.state, view.advices
    for blocker in (view.last_blocked, view.first_blocked):
        b = jnp.maximum(blocker, 0)
        bits, advice = slow_down_for_blocked(
            ego_view(own), neighbour(b, blocker >= 0, 0.0), on_lane[b], dt
        )
        state_me = state_me | bits
        advices_me = push_advice(advices_me, advice)
    # roads of one or two lanes: a lane on one side at most
    # (`RingArrays.from_tables`), so one look, to the side that has one
    to_right = net.lane_side[own, 0] >= 0
    side = jnp.where(to_right, 0, 1)
    tz = jnp.maximum(net.lane_side[own, side], 0)
    q = jnp.maximum(net.change_path[p, k, side], 0)
    lead = neighbours.leader_on(net, scene, i, q, tz, own, dt)
    lead, critical = with_merge(veh, i, side, lead, me, lc_i.safety_factor)
    back = neighbours.follower_on(net, scene, i, tz)
    bonus = neighbours.roundabout_bonus(
        net, occupied, (p, k, z_own, side), own, pos_i, lc_i.cooperative
    )
    look = Side(
        may=(net.lane_side[own, side] >= 0)
        & (net.change_path[p, k, side] >= 0) & active_i,
        ego=ego_view(tz), neigh=laneq(net.lane_index[tz]),
        lead=neighbour(*lead), lead_slot=lead[0],
        follow=neighbour(*back), follow_slot=back[0], bonus=bonus,
        held=False if veh.entry_hold is None else veh.entry_hold[i, side],
        critical=critical,
    )  # fmt: skip
    request = traci.NONE
    if veh.lane_request is not None:
        request = traci.change_request(
            veh.lane_request[i], net.lane_index[own], jnp.sum(edge >= 0)
        )
    decision, kept, told = turn_of_one_side(
        i, memory, state_me, advices_me, curr=curr, best=best, leader=leader,
        side=look, to_right=to_right, lc=lc_i, dt=dt, request=request,
        request_s=traci.REQUEST_STEPS * dt,
        first_blocked=neighbour(
            jnp.maximum(view.first_blocked, 0), view.first_blocked >= 0, 0.0
        ),
    )  # fmt: skip
    # an empty slot's turn leaves nothing: no messages, and its memory as it
    # was (cleared), so that a vehicle inserted into it starts as SUMO's new
    # vehicles do (MSLCM_LC2013's constructor: zeros, no advices)
    told = told._replace(
        speed=jnp.where(active_i, told.speed, jnp.nan),
        bits=jnp.where(active_i, told.bits, 0),
    )
    as_was = Kept(
        memory.speed_gain_probability[i], memory.keep_right_probability[i],
        memory.look_ahead_speed[i], view.advices, memory.left_space[i],
        memory.blocker_length[i],
    )  # fmt: skip
    kept = jax.tree.map(lambda new, old: jnp.where(active_i, new, old), kept, as_was)
    # no changer on its edge (one lane, or changing not allowed): SUMO
    # registers it unchanged without asking the model
    decides = ctx.decides[i]
    direction = jnp.where(decides, decision.direction, 0)
    changes_lane = direction != 0
    seen = (jnp.where(lead[1], lead[0], -1), lead[2],
            jnp.where(back[1], back[0], -1), back[2], bonus)  # fmt: skip
    unseen = (-1, jnp.inf, -1, jnp.inf, 0.0)  # the side without a lane
    on_side = jnp.arange(2) == side
    return Outcome(
        direction=direction,
        change_state=jnp.where(changes_lane, decision.change_state, 0),
        state=jnp.where(decides, decision.kept, view.state),
        kept=kept,
        told=told,
        blocked=jnp.stack([decision.blocked_right, decision.blocked_left]),
        target=jnp.stack([tz, tz]),
        to_lane=jnp.where(changes_lane, tz, own),
        to_path=jnp.where(changes_lane, q, p),
        sight=Sight(
            jnp.stack([decision.state_right, decision.state_left]),
            *(jnp.where(on_side, x, y) for x, y in zip(seen, unseen, strict=True)),
        ),
    )


def with_merge(
    veh: RingVehicles,
    i: jax.Array,
    side: int,
    lead: tuple[jax.Array, jax.Array, jax.Array],
    me: Driver,
    safety_factor: jax.Array,
) -> tuple[tuple[jax.Array, jax.Array, jax.Array], jax.Array | bool]:
    """Vehicle ``i``'s leader on the target lane of ``side`` (slot, exists,
    gap) with the merge's link leader (`jaxround.lanes.merge_leaders`):
    it leads unless a leader's back comes before the merge's link
    (`getLeaderOnConsecutive`); then whether, behind such a leader, it
    blocks the change as a critical leader (`getCriticalLeader`)."""
    if veh.merge is None:
        return lead, False
    slot, exists, gap = lead
    m_slot = veh.merge.slot[i, side]
    m_gap = veh.merge.gap[i, side]
    has_link = m_slot >= 0
    before = exists & (gap + me.min_gap < veh.merge.link_at[i, side])
    use_link = has_link & ~before
    lead = (
        jnp.where(use_link, m_slot, slot),
        exists | use_link,
        jnp.where(use_link, m_gap, gap),
    )
    v_link = veh.speed[jnp.maximum(m_slot, 0)]
    secure = secure_gap(me, veh.speed[i], v_link) * safety_factor
    critical = (
        before & has_link & (m_slot != slot) & veh.merge.critical[i, side]
        & (m_gap < secure)
    )  # fmt: skip
    return lead, critical


def changes(ctx: Context, outcome: Outcome) -> RingChanges:
    """The step's `RingChanges` from every vehicle's outcome ((M,) each)."""
    net, veh = ctx.net, ctx.veh
    path = outcome.to_path
    old_start = jnp.take_along_axis(net.lane_offset[veh.path], ctx.lane[:, None], 1)
    new_start = jnp.take_along_axis(net.lane_offset[path], outcome.to_lane[:, None], 1)
    moved = outcome.direction != 0
    pos = jnp.where(moved, veh.pos - old_start[:, 0] + new_start[:, 0], veh.pos)
    return RingChanges(
        path, pos, outcome.to_lane, outcome.direction, outcome.change_state,
        outcome.sight,
    )  # fmt: skip
