"""One candidate's turn in `MSLaneChanger::change`, whatever the geometry.

The changers (`jaxround.lanes.changer` on a straight road,
`jaxround.lanes.ring_changer` on a roundabout's lane paths) find a
candidate's neighbours and lane tables; this module does the rest of its
turn as SUMO does: `slowDownForBlocked` for the vehicles registered blocked
on its lane, right then left `checkChange` and `wantsChange`, the messages
to the target lane's leader and follower, and which way it goes.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxround.lanes import actions as lca
from jaxround.lanes import traci
from jaxround.lanes.lc2013 import Wish, check_change, wants_change
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.views import Ego, LaneQ, Memory, Neighbour, push_advice


class Turn(NamedTuple):
    """What the candidate decided. Scalars.

    Attributes:
        direction: -1 right, +1 left, 0 stays.
        change_state: the state it changed with (0 if it stays).
        kept: the state it keeps (`setOwnState`: both sides, the left one
            dropped where both are urgent).
        blocked_right, blocked_left: it wants that way urgently and may not
            (registered as ``lastBlocked``/``firstBlocked`` on that lane).
        state_right, state_left: what it wanted each way, blocked bits in
            (SUMO's ``stateRight``/``stateLeft``; 0 where it may not look).
    """

    direction: jax.Array
    change_state: jax.Array
    kept: jax.Array
    blocked_right: jax.Array
    blocked_left: jax.Array
    state_right: jax.Array
    state_left: jax.Array


class Side(NamedTuple):
    """What the candidate sees on one side: may it look there at all (the
    lane exists and changing to it is allowed), the target lane's leader
    and follower with their slots, the target lane's LaneQ, the roundabout
    bonus of that look (m), whether a foe at the target lane's entry
    link holds a change there back (`jaxround.lanes.entry_hold`), and
    whether a critical leader other than the target lane's leader is too
    near (`jaxround.lanes.merge_leaders`)."""

    may: jax.Array
    ego: Ego
    neigh: LaneQ
    lead: Neighbour
    lead_slot: jax.Array
    follow: Neighbour
    follow_slot: jax.Array
    bonus: jax.Array | float
    held: jax.Array | bool = False
    critical: jax.Array | bool = False


class Told(NamedTuple):
    """The messages of one turn (`informLeader`/`informFollower`): to the
    right lane's leader and follower, then the left's. (4,) each: the
    receiver's slot, a speed advice (NaN: none) and state bits (0: none)."""

    slot: jax.Array
    speed: jax.Array
    bits: jax.Array


class Kept(NamedTuple):
    """What a turn leaves in the candidate's own memory (`Memory`'s fields
    but the state). Scalars, and its advices (A,)."""

    speed_gain_probability: jax.Array
    keep_right_probability: jax.Array
    look_ahead_speed: jax.Array
    advices: jax.Array
    left_space: jax.Array
    blocker_length: jax.Array


def deliver(memory: Memory, told: Told) -> Memory:
    """`inform`: each message's advice and state bits to its receiver."""
    advices, state = memory.advices, memory.state
    for n in range(told.slot.shape[0]):
        slot = told.slot[n]
        advices = advices.at[slot].set(push_advice(advices[slot], told.speed[n]))
        state = state.at[slot].set(state[slot] | told.bits[n])
    return memory.replace(advices=advices, state=state)


def turn_of(
    i: jax.Array,
    memory: Memory,
    state: jax.Array,
    advices: jax.Array,
    *,
    curr: LaneQ,
    best: LaneQ,
    leader: Neighbour,
    right: Side,
    left: Side,
    lc: LaneChangeParams,
    dt: float,
    request: jax.Array | int = traci.NONE,
    request_s: float = 0.0,
    first_blocked: Neighbour | None = None,
) -> tuple[Turn, Kept, Told]:
    """Vehicle ``i``'s turn: right first, then left (`MSLaneChanger::change`),
    written nowhere.

    Args:
        i: its slot.
        memory: its probabilities and look-ahead speed are read (row ``i``).
        state, advices: its own state and advices at its turn, others'
            messages and `slowDownForBlocked` in.
        curr, best: the LaneQ of its lane and of its best lane.
        leader: the leader on its own lane.
        right, left: what it sees on each side.
        first_blocked: the first vehicle registered blocked on its lane
            (`jaxround.lanes.blockers`).
        request, request_s: its TraCI lane request (`jaxround.lanes.traci`)
            and the seconds the request has left.

    Returns:
        (turn, kept, told): its decision, what it keeps (its new
        probabilities, look-ahead speed and advices) and its messages.
    """
    sgp = memory.speed_gain_probability[i]
    krp = memory.keep_right_probability[i]
    look = memory.look_ahead_speed[i]
    left_space, reserved = memory.left_space[i], memory.blocker_length[i]
    states, told = {}, []
    for direction, side in ((-1, right), (1, left)):
        blocked = check_change(direction, side.ego, side.lead, side.follow, lc)
        wish = wants_change(
            direction, side.ego, state, sgp, krp, look, advices,
            curr=curr, neigh=side.neigh, best=best, leader=leader,
            neigh_lead=side.lead, neigh_follow=side.follow, blocked=blocked,
            lc=lc, dt=dt, roundabout_bonus=side.bonus, request=request,
            request_s=request_s, first_blocked=first_blocked,
            left_space_kept=left_space, blocker_kept=reserved,
        )  # fmt: skip
        unchanged = Wish(0, sgp, krp, look, jnp.full(3, jnp.nan), jnp.nan, 0,
                         jnp.nan, 0, left_space, reserved)  # fmt: skip
        wish = jax.tree.map(
            lambda new, old, may=side.may: jnp.where(may, new, old), wish, unchanged
        )
        sgp = wish.speed_gain_probability
        krp = wish.keep_right_probability
        look = wish.look_ahead_speed
        left_space, reserved = wish.left_space, wish.blocker_length
        # `checkChange`: a wanted change nothing blocked may still be blocked
        # by a critical leader (`getCriticalLeader`) and held back at the
        # target lane's entry (`unsafeLinkAhead`); then the request once
        # more, on the state with the blocked bits
        wanted = (blocked == 0) & ((wish.state & lca.WANTS_LANECHANGE) != 0)
        by_leader = (
            lca.BLOCKED_BY_RIGHT_LEADER if direction < 0 else lca.BLOCKED_BY_LEFT_LEADER
        )
        critical = jnp.where(wanted & side.critical, by_leader, 0)
        held = jnp.where(wanted & side.held, lca.HELD, 0)
        states[direction] = jnp.where(
            side.may,
            traci.influence(wish.state | blocked | critical | held, request),
            0,
        )
        for advice in wish.own_advices:
            advices = push_advice(advices, advice)
        told.append((side.lead_slot, wish.leader_speed, wish.leader_bits))
        told.append((side.follow_slot, wish.follower_speed, wish.follower_bits))
    state_right, state_left = states[-1], states[1]

    def wants(s: jax.Array, bit: int) -> jax.Array:
        return (s & bit) != 0

    go_right = wants(state_right, lca.RIGHT) & ~wants(state_right, lca.BLOCKED)
    go_left = ~go_right & wants(state_left, lca.LEFT) & ~wants(state_left, lca.BLOCKED)
    urgent_right = wants(state_right, lca.RIGHT) & wants(state_right, lca.URGENT)
    urgent_left = wants(state_left, lca.LEFT) & wants(state_left, lca.URGENT)
    both_urgent = wants(state_right, lca.URGENT) & wants(state_left, lca.URGENT)
    change_state = jnp.where(go_right, state_right, jnp.where(go_left, state_left, 0))
    turn = Turn(
        direction=jnp.where(go_right, -1, jnp.where(go_left, 1, 0)),
        change_state=change_state,
        kept=state_right | jnp.where(both_urgent, 0, state_left),
        blocked_right=urgent_right & ~go_right,
        blocked_left=urgent_left & ~go_right & ~go_left,
        state_right=state_right,
        state_left=state_left,
    )
    messages = Told(*(jnp.stack(column) for column in zip(*told, strict=True)))
    return turn, Kept(sgp, krp, look, advices, left_space, reserved), messages


def keep(memory: Memory, i: jax.Array, kept: Kept) -> Memory:
    """Write what vehicle ``i``'s turn keeps into its row of ``memory``."""
    return memory.replace(
        speed_gain_probability=memory.speed_gain_probability.at[i].set(
            kept.speed_gain_probability
        ),
        keep_right_probability=memory.keep_right_probability.at[i].set(
            kept.keep_right_probability
        ),
        look_ahead_speed=memory.look_ahead_speed.at[i].set(kept.look_ahead_speed),
        advices=memory.advices.at[i].set(kept.advices),
        left_space=memory.left_space.at[i].set(kept.left_space),
        blocker_length=memory.blocker_length.at[i].set(kept.blocker_length),
    )


def take_turn(
    i: jax.Array,
    memory: Memory,
    state: jax.Array,
    advices: jax.Array,
    **views: object,
) -> tuple[Turn, Memory]:
    """`turn_of` with its messages delivered and what it keeps written, in
    a changer that takes the vehicles one by one (keywords as there)."""
    turn, kept, told = turn_of(i, memory, state, advices, **views)
    return turn, keep(deliver(memory, told), i, kept)
