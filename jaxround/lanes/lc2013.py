"""One vehicle's wish to change lanes: SUMO 1.28's `MSLCM_LC2013`, in JAX.

`wants_change` is `MSLCM_LC2013::_wantsChange` for one direction (Euler
update, one lane per vehicle, no stops; TraCI lane requests under the
default lane-change mode, `jaxround.lanes.traci`), branch by branch in
SUMO's order: the look-ahead distance, the urgent strategic change (and its
negotiation, `jaxround.lanes.inform`), the reasons to stay, the roundabout
bonus, cooperation, speed gain to the right with keep-right, speed gain to
the left, and the non-urgent strategic change. `check_change` is
`MSLaneChanger::checkChange`'s safety test, `patch_speed` the next step's
`_patchSpeed`, `prepare_step` and `changed` the resets between.

Everything is element-wise over the vehicles' arrays (...), so a changer can
decide one vehicle at a time (SUMO's order) or many at once.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxround.lanes import actions as lca
from jaxround.lanes import follow, traci
from jaxround.lanes.anticipate import accelerating, anticipate_follow_speed
from jaxround.lanes.blockers import save_blocker_length
from jaxround.lanes.inform import inform_follower, inform_leader
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.speed_gain import SpeedGain, gain_left, gain_right
from jaxround.lanes.views import Ego, LaneQ, Neighbour

#: MSLCM_LC2013.cpp's constants.
LOOK_FORWARD = 10.0  # s
LOOK_AHEAD_SPEED_MEMORY = 0.9
RELGAIN_NORMALIZATION_MIN_SPEED = 10.0  # m/s
URGENCY = 2.0
TURN_LANE_DIST = 200.0  # m
NUMERICAL_EPS = 0.001


class Wish(NamedTuple):
    """The outcome of one `wants_change` call.

    Attributes:
        state: int32 bits (`jaxround.lanes.actions`), the blocked bits not included.
        speed_gain_probability, keep_right_probability, look_ahead_speed:
            the updated memory.
        own_advices: (3,) advices the vehicle gives itself (NaN: none).
        leader_speed, leader_bits, follower_speed, follower_bits: what it
            tells the target lane's leader and follower (NaN / 0: nothing).
        left_space, blocker_length: its ``myLeftSpace`` and
            ``myLeadingBlockerLength`` after the look (set by an urgent wish).
    """

    state: jax.Array
    speed_gain_probability: jax.Array
    keep_right_probability: jax.Array
    look_ahead_speed: jax.Array
    own_advices: jax.Array
    leader_speed: jax.Array
    leader_bits: jax.Array
    follower_speed: jax.Array
    follower_bits: jax.Array
    left_space: jax.Array
    blocker_length: jax.Array


def either(right: bool | jax.Array, if_right: Any, if_left: Any) -> Any:
    """``if_right`` or ``if_left`` (trees of the same structure) for a look
    to the right or left: chosen in Python where ``right`` is a bool, by
    `jnp.where` where it is an array (a look whose side the data decide:
    `jaxround.lanes.decide.turn_of_one_side`)."""
    if isinstance(right, bool):
        return if_right if right else if_left
    return jax.tree.map(lambda a, b: jnp.where(right, a, b), if_right, if_left)


def check_change(
    direction: int | jax.Array, ego: Ego, neigh_lead: Neighbour,
    neigh_follow: Neighbour, lc: LaneChangeParams,
) -> jax.Array:  # fmt: skip
    """`MSLaneChanger::checkChange`'s safety test: blocked (bits) where a
    target-lane neighbour overlaps or is closer than its secure gap times
    1 / lcAssertive (speeds of this step, one action step per step)."""
    right = direction < 0
    by_leader = either(right, lca.BLOCKED_BY_RIGHT_LEADER, lca.BLOCKED_BY_LEFT_LEADER)
    by_follower = either(
        right, lca.BLOCKED_BY_RIGHT_FOLLOWER, lca.BLOCKED_BY_LEFT_FOLLOWER
    )
    nf, nl = neigh_follow, neigh_lead
    follower_overlaps = nf.exists & (nf.gap < 0)
    leader_overlaps = nl.exists & (nl.gap < 0)
    back_gap = follow.secure_gap(nf.driver, nf.speed, ego.speed) * lc.safety_factor
    front_gap = follow.secure_gap(ego.driver, ego.speed, nl.speed) * lc.safety_factor
    follower_blocks = follower_overlaps | (nf.exists & (nf.gap < back_gap))
    leader_blocks = leader_overlaps | (nl.exists & (nl.gap < front_gap))
    return (
        jnp.where(follower_blocks, by_follower, 0)
        | jnp.where(leader_blocks, by_leader, 0)
        | jnp.where(follower_overlaps | leader_overlaps, lca.OVERLAPPING, 0)
    ).astype(jnp.int32)


def wants_change(
    direction: int | jax.Array,
    ego: Ego,
    memory_state: jax.Array,
    speed_gain_probability: jax.Array,
    keep_right_probability: jax.Array,
    look_ahead_speed: jax.Array,
    advices: jax.Array,
    *,
    curr: LaneQ,
    neigh: LaneQ,
    best: LaneQ,
    leader: Neighbour,
    neigh_lead: Neighbour,
    neigh_follow: Neighbour,
    blocked: jax.Array,
    lc: LaneChangeParams,
    dt: float,
    roundabout_bonus: jax.Array | float = 0.0,
    request: jax.Array | int = traci.NONE,
    request_s: float = 0.0,
    first_blocked: Neighbour | None = None,
    left_space_kept: jax.Array | float = 0.0,
    blocker_kept: jax.Array | float = 0.0,
) -> Wish:
    """`MSLCM_LC2013::_wantsChange` for ``direction`` (-1 right, +1 left: an
    int, or an int array where the data decide the side; then both of the
    speed-gain branches are computed and one kept).

    Args:
        memory_state, speed_gain_probability, keep_right_probability,
            look_ahead_speed: the vehicle's LC2013 memory (`Memory` fields).
        advices: (A,) its advices so far this step (next speeds, NaN empty).
        curr, neigh: the LaneQ of its lane and of the lane it looks at.
        best: the LaneQ of the lane ``curr.best_lane_offset`` away.
        leader: the leader on its own lane.
        neigh_lead, neigh_follow: leader and follower on the target lane.
        blocked: `check_change`'s bits for this direction.
        roundabout_bonus: `MSLCHelper::getRoundaboutDistBonus` (m; 0 off a
            roundabout).
        request, request_s: a TraCI lane request (`jaxround.lanes.traci`,
            lane-change mode 1621) and the seconds it has left.
        first_blocked: the first vehicle registered blocked on its lane.
        left_space_kept, blocker_kept: its ``myLeftSpace`` and
            ``myLeadingBlockerLength`` so far this step.
    """
    right = direction < 0
    lca_dir = either(right, lca.RIGHT, lca.LEFT)
    my_lca = either(right, lca.MRIGHT, lca.MLEFT)
    v, driver = ego.speed, ego.driver
    float_dtype = jnp.result_type(float)
    # 1. the best lane: with both lanes equally good, the one looked at
    equal = (curr.best_lane_offset == 0) & (neigh.best_lane_offset == 0)
    best_offset = jnp.where(equal, direction, curr.best_lane_offset)
    best = jax.tree.map(lambda n, b: jnp.where(equal, n, b), neigh, best)
    change_to_best = either(right, best_offset < 0, best_offset > 0)
    on_course = change_to_best & (best_offset == curr.best_lane_offset)
    abs_offset = jnp.abs(best_offset).astype(float_dtype)
    ret = memory_state & lca.MESSAGE_BITS

    # 2. the look-ahead distance (its speed jumps up, decays by 0.9 per second)
    memory_factor = 1.0 - (1.0 - LOOK_AHEAD_SPEED_MEMORY) * dt
    look_ahead = jnp.where(
        v > look_ahead_speed,
        v,
        jnp.maximum(0.0, memory_factor * look_ahead_speed + (1 - memory_factor) * v),
    )
    la_dist = (
        look_ahead * LOOK_FORWARD * lc.strategic * either(right, 1.0, lc.lookahead_left)
    )
    la_dist = la_dist + 2.0 * driver.length_with_gap
    la_dist = jnp.where(jnp.asarray(lc.strategic) < 0, -1e3, la_dist)
    current_dist = curr.length + roundabout_bonus
    neigh_dist = neigh.length + roundabout_bonus
    usable_dist = current_dist - ego.pos - best.occupation
    max_jam = jnp.maximum(neigh.occupation, curr.occupation)
    neigh_left_place = jnp.maximum(0.0, neigh_dist - ego.pos - max_jam)

    # 3. urgent: the lane ends too soon for the route
    urgent = on_course & (usable_dist / jnp.maximum(abs_offset, 1.0) < la_dist)
    # 4. reasons to stay (stopped leaders are not modelled)
    free_to_neigh_end = ~leader.exists | (neigh_dist - ego.pos <= leader.gap)
    stay = ~urgent & (
        (~change_to_best & (neigh_left_place / (abs_offset + 2.0) < la_dist))
        | ((best_offset == 0) & (neigh_left_place * 2.0 < la_dist))
        | (
            (best_offset == 0) & neigh.ends_in_links & (roundabout_bonus == 0)
            & jnp.where(jnp.asarray(lc.strategic) >= 0, neigh_dist < TURN_LANE_DIST,
                        free_to_neigh_end)
        )
    )  # fmt: skip

    # 4b. a TraCI request weighs in: it may cancel the stay or the urgency,
    # and a request the other way is not this look's business
    strategic_state = jnp.select(
        [urgent, stay],
        [ret | lca_dir | lca.STRATEGIC | lca.URGENT, ret | lca.STAY | lca.STRATEGIC],
        ret,
    ).astype(jnp.int32)
    counter = either(right, lca.LEFT, lca.RIGHT)
    asked = traci.influence(strategic_state, request)
    asked = jnp.where(
        (asked & counter) != 0, asked & ~(lca.TRACI | counter | lca.URGENT), asked
    )
    stays = (asked & lca.STAY) != 0
    urgent_now = ~stays & ((asked & lca.URGENT) != 0)

    # 5. the urgent change's negotiation with the target lane (the request's
    # remaining time where it asked)
    left_space = current_dist - ego.pos
    # room for a blocker that wants this lane (`jaxround.lanes.blockers`)
    reserved = jnp.asarray(blocker_kept, float_dtype)
    for blocker in (neigh_lead, first_blocked):
        if blocker is not None:
            reserved = save_blocker_length(
                blocker, counter=counter, kept=reserved, ego=ego.driver,
                v=ego.speed, left_space=left_space, dt=dt,
            )  # fmt: skip
    reserved = jnp.where(urgent_now, reserved, blocker_kept)
    lanes_to_go = jnp.maximum(abs_offset, 1.0)
    per_lane = left_space / jnp.maximum(look_ahead, NUMERICAL_EPS) / lanes_to_go
    remaining_s = jnp.where(
        urgent_now & ((asked & lca.TRACI) != 0),
        request_s,
        jnp.maximum(dt, per_lane / URGENCY),
    )
    planned, lead_advice, leader_speed, leader_bits = inform_leader(
        ego, neigh_lead, blocked=blocked, my_lca=my_lca, remaining_s=remaining_s,
        left_space=left_space - reserved, advices=advices, dt=dt,
    )  # fmt: skip
    follower_speed, follower_bits, follow_advice = inform_follower(
        ego, neigh_follow, blocked=blocked, my_lca=my_lca, remaining_s=remaining_s,
        planned=planned, dt=dt,
    )  # fmt: skip
    tells_follower = planned >= 0

    # 6. the lanes' speeds compared
    speeding_up = accelerating(neigh_lead) | accelerating(leader)
    neigh_vsafe = jnp.minimum(
        ego.neigh_v_max,
        anticipate_follow_speed(
            ego, neigh_lead, neigh_dist, ego.neigh_v_max, speeding_up, dt
        ),
    )
    this_vsafe = jnp.minimum(
        ego.v_max,
        anticipate_follow_speed(ego, leader, current_dist, ego.v_max, speeding_up, dt),
    )
    sgp = speed_gain_probability
    inconvenience = either(right, sgp / lc.threshold_right, -sgp / lc.threshold_left)
    inconvenience = jnp.minimum(
        1.0, jnp.maximum(this_vsafe / neigh_vsafe - 1.0, inconvenience)
    )
    speed_gain_inconvenient = inconvenience > lc.cooperative

    # 7. roundabouts: to the inner lane cooperatively, stay off the outer one
    in_roundabout = jnp.asarray(roundabout_bonus) > 0
    roundabout_req = either(
        right, lca.STAY | lca.COOPERATIVE, lca_dir | lca.COOPERATIVE
    )
    # 8. cooperation: help a vehicle that asked this one to make room
    cooperates = (
        (
            (memory_state & (lca.AMBLOCKINGFOLLOWER | lca.AMBLOCKINGFOLLOWER_DONTBRAKE))
            != 0
        )
        & ~speed_gain_inconvenient
        & ((memory_state & my_lca) != 0)
        & (change_to_best | (neigh_dist / (abs_offset + 1.0) > la_dist))
    )
    relative_gain = (neigh_vsafe - this_vsafe) / jnp.maximum(
        neigh_vsafe, RELGAIN_NORMALIZATION_MIN_SPEED
    )
    # 9. speed gain and keep right
    gain = SpeedGain(
        sgp=sgp, krp=keep_right_probability, keep_right=jnp.zeros_like(urgent),
        speed_gain=jnp.zeros_like(urgent), urgent=jnp.zeros_like(urgent),
    )  # fmt: skip
    looks = dict(ego=ego, neigh_lead=neigh_lead, this_vsafe=this_vsafe,
                 neigh_vsafe=neigh_vsafe, relative_gain=relative_gain,
                 neigh_dist=neigh_dist, lc=lc, dt=dt)  # fmt: skip
    if isinstance(right, bool):  # the side known when traced: its branch
        gain = (gain_right if right else gain_left)(gain, **looks)
    else:  # the data decide the side: both branches, one kept
        gain = either(right, gain_right(gain, **looks), gain_left(gain, **looks))
    sgp, krp, keep_right = gain.sgp, gain.krp, gain.keep_right
    speed_gain, speed_gain_urgent = gain.speed_gain, gain.urgent
    # 10. towards the best lane when speed does not suffer
    strategic = (
        on_course & (jnp.asarray(lc.strategic) >= 0) & (relative_gain >= 0)
        & either(right, sgp < 0, sgp > 0)
    )  # fmt: skip

    # after the early returns (the state before the request), the first wish
    # that holds and the request does not cancel (`cancelRequest`)
    gain_urgency = jnp.where(speed_gain_urgent, lca.URGENT, 0)
    wishes = {
        "roundabout": (in_roundabout, asked | roundabout_req),
        "cooperates": (cooperates, asked | lca_dir | lca.COOPERATIVE | lca.URGENT),
        "keep_right": (keep_right, asked | lca_dir | lca.KEEPRIGHT),
        "speed_gain": (speed_gain, asked | lca_dir | lca.SPEEDGAIN | gain_urgency),
        "strategic": (strategic, asked | lca_dir | lca.STRATEGIC),
    }
    taken = {
        name: holds & ~traci.cancels(wish, request)
        for name, (holds, wish) in wishes.items()
    }
    early = stays | urgent_now
    state = jnp.select(
        [early, *taken.values()],
        [strategic_state, *(wish for _, wish in wishes.values())],
        asked,
    ).astype(jnp.int32)
    # memory updates happen only on the paths that reach them
    reaches_gain = ~early & ~taken["roundabout"] & ~taken["cooperates"]
    # an urgent change (strategic, or for speed in 1.28) negotiates
    negotiates = urgent_now | (
        reaches_gain & ~taken["keep_right"] & taken["speed_gain"] & speed_gain_urgent
    )
    nan = jnp.asarray(jnp.nan, jnp.result_type(float))
    return Wish(
        state=state,
        speed_gain_probability=jnp.where(reaches_gain, sgp, speed_gain_probability),
        keep_right_probability=jnp.where(reaches_gain, krp, keep_right_probability),
        look_ahead_speed=look_ahead,
        own_advices=jnp.stack(
            [
                jnp.where(negotiates, lead_advice, nan),
                jnp.where(negotiates & tells_follower, follow_advice, nan),
                nan,
            ]
        ),  # fmt: skip
        leader_speed=jnp.where(negotiates, leader_speed, nan),
        leader_bits=jnp.where(negotiates, leader_bits, 0).astype(jnp.int32),
        follower_speed=jnp.where(negotiates & tells_follower, follower_speed, nan),
        follower_bits=jnp.where(negotiates & tells_follower, follower_bits, 0).astype(
            jnp.int32
        ),
        left_space=jnp.where(urgent_now, left_space, left_space_kept),
        blocker_length=reserved,
    )
