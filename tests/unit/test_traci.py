"""TraCI lane requests under SUMO's default lane-change mode 1621
(`jaxround.lanes.traci`), case by case from
`MSVehicle::Influencer::influenceChangeDecision`."""

from __future__ import annotations

import jax.numpy as jnp
import pytest

from jaxround.lanes import actions as lca
from jaxround.lanes import traci

BLOCKED = lca.BLOCKED_BY_LEFT_FOLLOWER


def influenced(state: int, request: int) -> int:
    return int(traci.influence(jnp.int32(state), jnp.int32(request)))


@pytest.mark.parametrize(
    "state",
    [0, lca.LEFT | lca.STRATEGIC | lca.URGENT, lca.STAY | lca.STRATEGIC, BLOCKED],
)
def test_no_request_changes_nothing(state: int) -> None:
    assert influenced(state, traci.NONE) == state


def test_a_conflicting_wish_loses_its_direction_and_urgency() -> None:
    wish = lca.RIGHT | lca.STRATEGIC | lca.URGENT | lca.AMBLOCKINGLEADER
    assert influenced(wish, traci.LEFT) == (
        lca.STRATEGIC | lca.AMBLOCKINGLEADER | lca.TRACI | lca.LEFT
    )
    assert influenced(lca.STAY | lca.STRATEGIC, traci.RIGHT) == (
        lca.STRATEGIC | lca.TRACI | lca.RIGHT
    )
    assert influenced(lca.LEFT | lca.COOPERATIVE, traci.HOLD) == (
        lca.COOPERATIVE | lca.TRACI | lca.STAY
    )


def test_an_agreeing_wish_stays_and_the_request_is_never_urgent() -> None:
    assert influenced(lca.LEFT | lca.COOPERATIVE, traci.LEFT) == (
        lca.LEFT | lca.COOPERATIVE | lca.TRACI
    )
    assert influenced(lca.LEFT | lca.STRATEGIC | lca.URGENT, traci.LEFT) == (
        lca.LEFT | lca.STRATEGIC | lca.URGENT | lca.TRACI
    )
    assert influenced(0, traci.RIGHT) & lca.URGENT == 0


def test_safety_checks_are_kept() -> None:
    """LCP_OPPORTUNISTIC: the blocked bits stay, so a blocked request waits."""
    assert influenced(BLOCKED, traci.LEFT) == BLOCKED | lca.TRACI | lca.LEFT


def test_a_wish_that_only_repeats_a_request_is_renewed() -> None:
    state = lca.TRACI | lca.LEFT | lca.URGENT
    assert influenced(state, traci.LEFT) == lca.TRACI | lca.LEFT


def test_cancel_request_drops_any_wish_the_request_alters() -> None:
    assert bool(traci.cancels(jnp.int32(lca.LEFT | lca.SPEEDGAIN), traci.LEFT))
    assert not bool(
        traci.cancels(jnp.int32(lca.TRACI | lca.LEFT | lca.SPEEDGAIN), traci.LEFT)
    )
    assert not bool(traci.cancels(jnp.int32(lca.LEFT | lca.SPEEDGAIN), traci.NONE))


def test_change_request_by_lane_index() -> None:
    lane = jnp.array([0, 1, 0, 1, 0])
    asked = jnp.array([1, 0, 0, 2, -1])
    got = traci.change_request(asked, lane, jnp.int32(2))
    assert got.tolist() == [traci.LEFT, traci.RIGHT, traci.HOLD, traci.NONE, traci.NONE]
