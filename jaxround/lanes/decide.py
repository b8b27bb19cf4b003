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
from jaxround.lanes.lc2013 import Wish, check_change, either, wants_change
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
    right lane's leader and follower, then the left's ((4,) each;
    `turn_of_one_side`: its look's two, (2,)): the receiver's slot, a speed
    advice (NaN: none) and state bits (0: none)."""

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


def _look(
    direction: int | jax.Array,
    side: Side,
    state: jax.Array,
    advices: jax.Array,
    kept: Kept,
    *,
    curr: LaneQ,
    best: LaneQ,
    leader: Neighbour,
    lc: LaneChangeParams,
    dt: float,
    request: jax.Array | int,
    request_s: float,
    first_blocked: Neighbour | None,
) -> tuple[jax.Array, Kept, list[tuple[jax.Array, jax.Array, jax.Array]]]:
    """One side's `checkChange` and `wantsChange` (nothing where the
    candidate may not look there): its state that way (blocked bits in),
    what it keeps after the look (``kept``'s advices those of the look
    before it, its own pushed in; ``advices``: those it decides with), and
    its two messages (to the target lane's leader, then follower)."""
    blocked = check_change(direction, side.ego, side.lead, side.follow, lc)
    wish = wants_change(
        direction, side.ego, state, kept.speed_gain_probability,
        kept.keep_right_probability, kept.look_ahead_speed, advices,
        curr=curr, neigh=side.neigh, best=best, leader=leader,
        neigh_lead=side.lead, neigh_follow=side.follow, blocked=blocked,
        lc=lc, dt=dt, roundabout_bonus=side.bonus, request=request,
        request_s=request_s, first_blocked=first_blocked,
        left_space_kept=kept.left_space, blocker_kept=kept.blocker_length,
    )  # fmt: skip
    unchanged = Wish(
        0, kept.speed_gain_probability, kept.keep_right_probability,
        kept.look_ahead_speed, jnp.full(3, jnp.nan), jnp.nan, 0, jnp.nan, 0,
        kept.left_space, kept.blocker_length,
    )  # fmt: skip
    wish = jax.tree.map(lambda new, old: jnp.where(side.may, new, old), wish, unchanged)
    # `checkChange`: a wanted change nothing blocked may still be blocked
    # by a critical leader (`getCriticalLeader`) and held back at the
    # target lane's entry (`unsafeLinkAhead`); then the request once
    # more, on the state with the blocked bits
    wanted = (blocked == 0) & ((wish.state & lca.WANTS_LANECHANGE) != 0)
    by_leader = either(
        direction < 0, lca.BLOCKED_BY_RIGHT_LEADER, lca.BLOCKED_BY_LEFT_LEADER
    )
    critical = jnp.where(wanted & side.critical, by_leader, 0)
    held = jnp.where(wanted & side.held, lca.HELD, 0)
    side_state = jnp.where(
        side.may,
        traci.influence(wish.state | blocked | critical | held, request),
        0,
    )
    own = kept.advices
    for advice in wish.own_advices:
        own = push_advice(own, advice)
    told = [
        (side.lead_slot, wish.leader_speed, wish.leader_bits),
        (side.follow_slot, wish.follower_speed, wish.follower_bits),
    ]
    after = Kept(
        wish.speed_gain_probability, wish.keep_right_probability,
        wish.look_ahead_speed, own, wish.left_space, wish.blocker_length,
    )  # fmt: skip
    return side_state, after, told


def _memory_of(memory: Memory, i: jax.Array, advices: jax.Array) -> Kept:
    """Vehicle ``i``'s `Kept` before its looks (its advices: ``advices``)."""
    return Kept(
        memory.speed_gain_probability[i], memory.keep_right_probability[i],
        memory.look_ahead_speed[i], advices, memory.left_space[i],
        memory.blocker_length[i],
    )  # fmt: skip


def _decision(state_right: jax.Array, state_left: jax.Array) -> Turn:
    """`MSLaneChanger::change`'s choice from the two sides' states: right
    first, then left, each unless blocked."""

    def wants(s: jax.Array, bit: int) -> jax.Array:
        return (s & bit) != 0

    go_right = wants(state_right, lca.RIGHT) & ~wants(state_right, lca.BLOCKED)
    go_left = ~go_right & wants(state_left, lca.LEFT) & ~wants(state_left, lca.BLOCKED)
    urgent_right = wants(state_right, lca.RIGHT) & wants(state_right, lca.URGENT)
    urgent_left = wants(state_left, lca.LEFT) & wants(state_left, lca.URGENT)
    both_urgent = wants(state_right, lca.URGENT) & wants(state_left, lca.URGENT)
    change_state = jnp.where(go_right, state_right, jnp.where(go_left, state_left, 0))
    return Turn(
        direction=jnp.where(go_right, -1, jnp.where(go_left, 1, 0)),
        change_state=change_state,
        kept=state_right | jnp.where(both_urgent, 0, state_left),
        blocked_right=urgent_right & ~go_right,
        blocked_left=urgent_left & ~go_right & ~go_left,
        state_right=state_right,
        state_left=state_left,
    )


def turn_of(
    i: jax.Array,
    memory: Memory,
    state: jax.Array,
    advices: jax.Array,
    *,
    right: Side,
    left: Side,
    **views: object,
) -> tuple[Turn, Kept, Told]:
    """Vehicle ``i``'s turn: right first, then left (`MSLaneChanger::change`),
    written nowhere.

    Args:
        i: its slot.
        memory: its probabilities and look-ahead speed are read (row ``i``).
        state, advices: its own state and advices at its turn, others'
            messages and `slowDownForBlocked` in.
        right, left: what it sees on each side.
        views: keywords of both looks: ``curr``, ``best`` (the LaneQ of its
            lane and of its best lane), ``leader`` (on its own lane),
            ``lc``, ``dt``, ``request`` and ``request_s`` (its TraCI lane
            request, `jaxround.lanes.traci`, and the seconds it has left),
            ``first_blocked`` (the first vehicle registered blocked on its
            lane, `jaxround.lanes.blockers`; None: none).

    Returns:
        (turn, kept, told): its decision, what it keeps (its new
        probabilities, look-ahead speed and advices) and its messages (4,).
    """
    views = {"request": traci.NONE, "request_s": 0.0, "first_blocked": None} | views
    kept = _memory_of(memory, i, advices)
    state_right, kept, told_right = _look(-1, right, state, advices, kept, **views)
    # the left look decides with the advices the right one pushed
    state_left, kept, told_left = _look(1, left, state, kept.advices, kept, **views)
    messages = Told(*(jnp.stack(c) for c in zip(*told_right, *told_left, strict=True)))
    return _decision(state_right, state_left), kept, messages


def turn_of_one_side(
    i: jax.Array,
    memory: Memory,
    state: jax.Array,
    advices: jax.Array,
    *,
    side: Side,
    to_right: jax.Array,
    **views: object,
) -> tuple[Turn, Kept, Told]:
    """`turn_of` for a candidate with a lane on one side at most (roads of
    one or two lanes): SUMO looks only where `mayChange`, so its turn is
    one look, to the right where ``to_right`` (bool), else to the left;
    the same turn as `turn_of` given that side and a side it may not look
    at. Its messages are the look's two (2,)."""
    views = {"request": traci.NONE, "request_s": 0.0, "first_blocked": None} | views
    kept = _memory_of(memory, i, advices)
    direction = jnp.where(to_right, -1, 1)
    side_state, kept, told = _look(direction, side, state, advices, kept, **views)
    messages = Told(*(jnp.stack(c) for c in zip(*told, strict=True)))
    state_right = jnp.where(to_right, side_state, 0)
    state_left = jnp.where(to_right, 0, side_state)
    return _decision(state_right, state_left), kept, messages


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
