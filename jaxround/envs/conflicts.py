"""The environment's near-conflict statistics: each step's following
encounters (`jaxround.core.surrogate_safety`) added to the episode's
`EpisodeStats`, as SUMO's SSM device counts them."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core import surrogate_safety
from jaxround.core.state import EnvState, EpisodeStats
from jaxround.scenario.safety import SafetyConfig


def step_conflicts(
    state: EnvState,
    arrived: jax.Array,
    leader: jax.Array,
    gap_next: jax.Array,
    v_next: jax.Array,
    safety: SafetyConfig,
) -> tuple[surrogate_safety.FollowingConflicts, jax.Array]:
    """Each slot's following encounter after the move: behind the leader it
    planned behind, unless either of them has left.

    Args:
        state: the state at the start of the step.
        arrived: bool (M,) the slot's vehicle left in the step.
        leader: int (M,) the slot each planned behind (-1: none).
        gap_next: float (M,) the gap to it after the move, m.
        v_next: float (M,) speeds after the move, m/s.
        safety: the thresholds.

    Returns:
        (the `FollowingConflicts`, int (M,) conflicts each slot's vehicle
        entered in the step: one for each vehicle of a pair, as SUMO's
        device writes one per vehicle).
    """
    lead = jnp.maximum(leader, 0)
    follows = state.active & ~arrived & (leader >= 0) & ~arrived[lead]
    found = surrogate_safety.following_conflicts(
        leader_vehicle=jnp.where(follows, state.vid[lead], -1),
        gap=gap_next,
        v_follower=v_next,
        v_leader=v_next[lead],
        previous_leader=state.stats.encounter_leader,
        previous_conflict=state.stats.encounter_conflict,
        ttc_threshold_s=safety.ttc_threshold_s,
        drac_threshold_mps2=safety.drac_threshold_mps2,
    )
    as_follower = found.new_conflict.astype(jnp.int32)  # (M,)
    as_leader = (
        jnp.zeros_like(as_follower).at[lead].add(jnp.where(follows, as_follower, 0))
    )
    return found, as_follower + as_leader


def add_conflicts(
    stats: EpisodeStats,
    vid: jax.Array,
    found: surrogate_safety.FollowingConflicts,
    conflicts_step: jax.Array,
) -> EpisodeStats:
    """The step's conflicts, TTC and DRAC into each vehicle's totals, (N,);
    the encounters kept for the next step.

    Args:
        vid: int (M,) each slot's vehicle at the start of the step (-1: none).
        found, conflicts_step: `step_conflicts`' results.
    """
    follows = found.encounter_leader >= 0
    n_schedule = stats.conflicts.shape[-1]
    follower = jnp.where(follows, vid, n_schedule)  # out of range: dropped
    followed = jnp.where(follows, found.encounter_leader, n_schedule)
    vehicle = jnp.where(vid >= 0, vid, n_schedule)
    min_ttc = stats.min_ttc_s.at[follower].min(found.ttc_s, mode="drop")
    max_drac = stats.max_drac_mps2.at[follower].max(found.drac_mps2, mode="drop")
    return stats.replace(
        conflicts=stats.conflicts.at[vehicle].add(conflicts_step, mode="drop"),
        min_ttc_s=min_ttc.at[followed].min(found.ttc_s, mode="drop"),
        max_drac_mps2=max_drac.at[followed].max(found.drac_mps2, mode="drop"),
        encounter_leader=found.encounter_leader,
        encounter_conflict=found.encounter_conflict,
    )
