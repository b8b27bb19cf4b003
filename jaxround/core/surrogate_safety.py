"""Near-conflicts between a follower and its leader, as SUMO's SSM device
counts them (``MSDevice_SSM``, ``src/microsim/devices/MSDevice_SSM.cpp``).

After every step the device updates each *encounter* of two vehicles with
their new positions and speeds and keeps its smallest time to collision (TTC)
and largest deceleration to avoid a crash (DRAC); an encounter whose TTC
ever fell to the threshold, or whose DRAC ever rose to its threshold, is
written as a conflict, once by each vehicle of the pair. For a following
encounter (``determineTTCandDRAC``, types FOLLOWING_FOLLOWER / _LEADER), with
the bumper-to-bumper gap g and the speed difference dv = v_follower - v_leader:

    TTC  = g / dv        if dv > 0, none otherwise; 0 if g <= 0
    DRAC = dv^2 / (2 g)  if dv > 0, 0 otherwise;    none if g <= 0

On a single-lane roundabout every conflict SUMO wrote was a following one
(Milan at 100% AVs, tau 0.5-1 s: 210 of 210), so that is what is counted
here. An encounter is the pair of a vehicle and the leader it follows: it
begins when that leader becomes the one ahead and ends when another does or
one of them leaves (SUMO keeps a pair for as long as it stays within its
range, 50 m, plus 5 s; on one lane a follower meets its leader once). The
count is made when an encounter first qualifies, which gives the same total
as counting at its end.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

#: The TTC of a pair that is not closing in (SUMO's INVALID_DOUBLE), s:
#: finite, as every statistic the environment keeps is, and far past any
#: threshold.
NO_TTC_S = 1e6


def time_to_collision(
    gap: jax.Array, v_follower: jax.Array, v_leader: jax.Array
) -> jax.Array:
    """MSDevice_SSM::computeTTC: gap / dv when closing in (`NO_TTC_S` if
    not, 0 once the gap is gone), float of the inputs' shape."""
    closing = v_follower - v_leader
    ttc = gap / jnp.where(closing > 0, closing, 1.0)
    return jnp.where(gap <= 0, 0.0, jnp.where(closing > 0, ttc, NO_TTC_S))


def deceleration_to_avoid_crash(
    gap: jax.Array, v_follower: jax.Array, v_leader: jax.Array
) -> jax.Array:
    """MSDevice_SSM::computeDRAC: dv^2 / (2 gap) when closing in, 0 when not,
    and 0 (no value) once the gap is gone, float of the inputs' shape."""
    closing = jnp.maximum(v_follower - v_leader, 0.0)
    return jnp.where(gap > 0, 0.5 * closing**2 / jnp.where(gap > 0, gap, 1.0), 0.0)


class FollowingConflicts(NamedTuple):
    """One step's following measures of each slot to its leader, (M,).

    Attributes:
        ttc_s: float, TTC to the leader (`NO_TTC_S`: none).
        drac_mps2: float, DRAC behind the leader (0: none).
        encounter_leader: int, the leader's vehicle (schedule index; -1: none),
            to be kept for the next step.
        encounter_conflict: bool, the encounter with that leader has
            qualified as a conflict, to be kept for the next step.
        new_conflict: bool, it qualified in this step for the first time.
    """

    ttc_s: jax.Array
    drac_mps2: jax.Array
    encounter_leader: jax.Array
    encounter_conflict: jax.Array
    new_conflict: jax.Array


def following_conflicts(
    *,
    leader_vehicle: jax.Array,
    gap: jax.Array,
    v_follower: jax.Array,
    v_leader: jax.Array,
    previous_leader: jax.Array,
    previous_conflict: jax.Array,
    ttc_threshold_s: float,
    drac_threshold_mps2: float,
) -> FollowingConflicts:
    """Update every slot's following encounter after the move.

    Args:
        leader_vehicle: int (M,) the vehicle (schedule index) each slot
            follows after the move, -1 for none or an empty slot.
        gap: float (M,) bumper-to-bumper gap to it after the move, m.
        v_follower, v_leader: float (M,) both speeds after the move, m/s.
        previous_leader, previous_conflict: int (M,), bool (M,) the
            encounter each slot had after the previous step.
        ttc_threshold_s, drac_threshold_mps2: what makes a conflict.

    Returns:
        `FollowingConflicts`, (M,) each.
    """
    has_leader = leader_vehicle >= 0
    ttc = jnp.where(has_leader, time_to_collision(gap, v_follower, v_leader), NO_TTC_S)
    drac = jnp.where(
        has_leader, deceleration_to_avoid_crash(gap, v_follower, v_leader), 0.0
    )
    critical = has_leader & ((ttc <= ttc_threshold_s) | (drac >= drac_threshold_mps2))
    same_encounter = has_leader & (leader_vehicle == previous_leader)
    already = previous_conflict & same_encounter
    return FollowingConflicts(
        ttc_s=ttc,
        drac_mps2=drac,
        encounter_leader=jnp.where(has_leader, leader_vehicle, -1),
        encounter_conflict=already | critical,
        new_conflict=critical & ~already,
    )
