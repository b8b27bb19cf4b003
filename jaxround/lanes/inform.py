"""How an urgent lane-changer negotiates with its neighbours (Euler update).

`MSLCM_LC2013::informLeader`, `informFollower` and `slowDownForBlocked`:
a vehicle that must change asks the target lane's follower to brake or let
it be overtaken, decides to pass or fall in behind the target lane's
leader, and a vehicle behind a blocked changer slows down to let it in.
Each returns speed advices and state bits for the neighbours (and advices
to the changer itself) that the receivers apply in their next step's
`patchSpeed`.

Not ported: `MSLCHelper::divergentRoute` (a neighbour leaving on another
route is negotiated with like any other) and the rules for speeds above
60 km/h (`congested()`), which `jaxround.lanes.road` refuses.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.lanes import actions as lca
from jaxround.lanes import follow
from jaxround.lanes.views import Ego, Neighbour

#: SUMO's constants (MSLCM_LC2013.cpp), m/s and m.
HELP_OVERTAKE = 10.0 / 3.6
MIN_FALLBEHIND = 7.0 / 3.6
MAX_ONRAMP_LENGTH = 200.0
POSITION_EPS = 0.1
#: Speed below which a vehicle counts as halting (m/s).
HALTING_SPEED = 0.1


def slow_down_for_blocked(
    ego: Ego, blocked: Neighbour, blocked_pos: jax.Array, dt: float
) -> tuple[jax.Array, jax.Array]:
    """`slowDownForBlocked`: a slow vehicle (below its decel in m/s) behind
    ``blocked`` (a vehicle that could not change into its lane, its front at
    ``blocked_pos`` on the same edge) leaves it room.

    Returns:
        (bits, advice): AMBACKBLOCKER(_STANDING) or 0, the speed advice or NaN.
    """
    gap = blocked_pos - blocked.driver.length - ego.pos - ego.driver.min_gap
    acts = blocked.exists & (gap > POSITION_EPS) & (ego.speed < ego.driver.decel)
    bits = jnp.where(
        blocked.speed < HALTING_SPEED, lca.AMBACKBLOCKER_STANDING, lca.AMBACKBLOCKER
    )
    advice = follow.follow_speed(
        ego.driver, ego.speed, gap - POSITION_EPS, blocked.speed, ego.v_max, dt
    )
    return jnp.where(acts, bits, 0), jnp.where(acts, advice, jnp.nan)


def inform_leader(
    ego: Ego,
    neigh_lead: Neighbour,
    *,
    blocked: jax.Array,
    my_lca: int,
    remaining_s: jax.Array,
    left_space: jax.Array,
    advices: jax.Array,
    dt: float,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """`informLeader`: pass the target lane's leader or fall in behind it.

    Args:
        blocked: the change's blocked bits (`checkChange`).
        my_lca: MLEFT or MRIGHT, the direction told to the neighbour.
        remaining_s: seconds left for the change.
        left_space: metres left on the lanes that lead on (`myLeftSpace`).
        advices: (A,) the vehicle's own advices so far (next speeds, NaN empty).

    Returns:
        (planned_speed, own_advice, leader_speed, leader_bits): the speed it
        plans (-1: overtaking, nothing to tell the follower), an advice to
        itself (NaN: none), the advice and bits for the leader (NaN / 0: none).
    """
    v, driver = ego.speed, ego.driver
    planned = jnp.minimum(v, follow.stop_speed(driver, v, left_space, ego.v_max, dt))
    usable = ~jnp.isnan(advices) & ((advices - v) / dt >= -driver.decel)
    planned = jnp.minimum(planned, jnp.min(jnp.where(usable, advices, jnp.inf)))

    next_speed = neigh_lead.speed - jnp.maximum(1.0, -neigh_lead.accel) * dt
    next_gap = neigh_lead.gap + (next_speed - planned) * dt
    target = jnp.maximum(
        follow.min_next_speed(driver, v, dt),
        follow.follow_speed(driver, v, next_gap, next_speed, ego.v_max, dt),
    )
    # blocked by the leader: overtake it, or fall in behind it
    overtake_dist = jnp.maximum(
        0.0,
        neigh_lead.gap + neigh_lead.driver.length_with_gap + driver.length
        + follow.secure_gap(neigh_lead.driver, neigh_lead.speed, v),
    )  # fmt: skip
    dv = planned - neigh_lead.speed
    overtake_s = jnp.where(
        dv > 0, overtake_dist / jnp.where(dv > 0, dv, 1.0), remaining_s + 1
    )
    cannot_pass = (
        (dv < 0)
        | (left_space - follow.brake_gap(driver, v, dt) < overtake_dist)
        | (remaining_s < overtake_s)
    )
    decel = jnp.where(
        remaining_s == 0,
        driver.decel,
        jnp.minimum(
            driver.decel, jnp.maximum(MIN_FALLBEHIND, (v - target) / remaining_s)
        ),
    )
    fall_behind = jnp.minimum(planned, jnp.maximum(0.0, v - decel * dt))
    slows = target < v
    by_leader = (blocked & lca.BLOCKED_BY_LEADER) != 0

    planned_out = jnp.where(
        by_leader,
        jnp.where(cannot_pass, jnp.where(slows, fall_behind, planned), -1.0),
        jnp.minimum(target, planned),
    )
    own = jnp.where(by_leader & cannot_pass & slows, fall_behind, target)
    own = jnp.where(by_leader & ~cannot_pass, jnp.nan, own)
    leader_speed = jnp.where(cannot_pass, jnp.inf, neigh_lead.speed)
    leader_speed = jnp.where(by_leader, leader_speed, jnp.nan)
    leader_bits = jnp.where(by_leader, my_lca | lca.AMBLOCKINGLEADER, 0)
    exists = neigh_lead.exists
    return (
        jnp.where(exists, planned_out, planned),
        jnp.where(exists, own, jnp.nan),
        jnp.where(exists, leader_speed, jnp.nan),
        jnp.where(exists, leader_bits, 0),
    )


def inform_follower(
    ego: Ego,
    neigh_follow: Neighbour,
    *,
    blocked: jax.Array,
    my_lca: int,
    remaining_s: jax.Array,
    planned: jax.Array,
    dt: float,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """`informFollower`: ask the target lane's follower to let the vehicle in
    (brake to open the gap) or to overtake it (and slow down for that).

    Returns:
        (follower_speed, follower_bits, own_advice): the advice and bits for
        the follower (NaN / 0: none) and an advice to itself (NaN: none).
    """
    v, driver = ego.speed, ego.driver
    nf, nf_driver = neigh_follow, neigh_follow.driver
    planned_pos = jnp.maximum(planned, 0.0)
    bits = my_lca | lca.AMBLOCKINGFOLLOWER
    # (a) fast enough to cut in without help
    needed = follow.secure_gap(nf_driver, nf.speed, planned)
    cut_in = (planned_pos - nf.speed >= HELP_OVERTAKE) & (
        (needed - nf.gap) / remaining_s < planned_pos - nf.speed
    )
    # (b) the follower brakes at most its decel for 1 s
    help_decel = nf_driver.decel
    nn = jnp.maximum(0.0, nf.speed - help_decel * dt)
    nn_1s = jnp.maximum(0.0, nf.speed - help_decel)
    dv = planned - nn_1s
    decel_gap = nf.gap + dv
    secure = follow.secure_gap(nf_driver, nn_1s, planned_pos)
    brake_helps = (decel_gap > 0) & (decel_gap >= secure)
    vsafe1 = jnp.maximum(
        nn,
        follow.follow_speed(
            nf_driver, nf.speed, nf.gap + planned * dt, planned, nf.v_max, dt
        ),
    )
    vsafe = jnp.maximum(
        nn,
        follow.follow_speed(
            nf_driver, nf.speed, nf.gap + (planned - vsafe1) * dt, planned, nf.v_max, dt
        ),
    )
    # (c) braking opens the gap in the seconds left
    eventually = (dv > 0) & (dv * remaining_s > secure - decel_gap + POSITION_EPS)
    # (d) let the follower overtake; a right follower (or a left one on a
    # long lane) is asked to slow down if it can before the time runs out
    faster = nf.speed > v
    special = faster & (
        (my_lca == lca.MRIGHT)
        | ((my_lca == lca.MLEFT) & (ego.lane_length > MAX_ONRAMP_LENGTH))
    )
    v_help = jnp.where(
        special,
        jnp.maximum(nn, v + HELP_OVERTAKE),
        jnp.maximum(nf.speed, v + HELP_OVERTAKE),
    )
    slow_in_time = special & ((nf.speed - v) / help_decel < remaining_s)
    overtake_dist = jnp.maximum(
        0.0,
        nf.gap + driver.length_with_gap + nf_driver.length
        + follow.secure_gap(driver, planned, v_help),
    )  # fmt: skip
    own_overtaken = jnp.maximum(
        v_help - overtake_dist / remaining_s, v - driver.decel * dt
    )

    speed_blocked = jnp.where(
        cut_in,
        planned_pos - HELP_OVERTAKE,
        jnp.where(brake_helps, vsafe, jnp.where(eventually, nn, v_help)),
    )
    own_blocked = jnp.where(
        cut_in | brake_helps | eventually | slow_in_time, jnp.nan, own_overtaken
    )
    # not blocked by the follower but by the leader: keep it that way
    keep1 = follow.follow_speed(
        nf_driver, nf.speed, nf.gap + planned * dt, planned, nf.v_max, dt
    )
    keep = follow.follow_speed(
        nf_driver, nf.speed, nf.gap + (planned - keep1) * dt, planned, nf.v_max, dt
    )
    by_follower = nf.exists & ((blocked & lca.BLOCKED_BY_FOLLOWER) != 0)
    by_leader = nf.exists & ~by_follower & ((blocked & lca.BLOCKED_BY_LEADER) != 0)
    follower_speed = jnp.where(
        by_follower, speed_blocked, jnp.where(by_leader, keep, jnp.nan)
    )
    follower_bits = jnp.where(by_follower, bits, jnp.where(by_leader, my_lca, 0))
    return follower_speed, follower_bits, jnp.where(by_follower, own_blocked, jnp.nan)
