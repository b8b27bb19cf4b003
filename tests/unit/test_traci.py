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
        lca.STRATEGIC | lca.AMBLOCKINGLEADER | lca.TRACI | lca.LEFT | lca.URGENT
    )
    assert influenced(lca.STAY | lca.STRATEGIC, traci.RIGHT) == (
        lca.STRATEGIC | lca.TRACI | lca.RIGHT | lca.URGENT
    )
    assert influenced(lca.LEFT | lca.COOPERATIVE, traci.HOLD) == (
        lca.COOPERATIVE | lca.TRACI | lca.STAY
    )


def test_an_agreeing_wish_stays_and_a_change_request_is_urgent() -> None:
    """Mode 1621's TraCI priority is LCP_URGENT (2): a request to change is
    urgent (SUMO's lane-change output reads ``traci|urgent``), HOLD is not."""
    assert influenced(lca.LEFT | lca.COOPERATIVE, traci.LEFT) == (
        lca.LEFT | lca.COOPERATIVE | lca.TRACI | lca.URGENT
    )
    assert influenced(lca.LEFT | lca.STRATEGIC | lca.URGENT, traci.LEFT) == (
        lca.LEFT | lca.STRATEGIC | lca.URGENT | lca.TRACI
    )
    assert influenced(0, traci.RIGHT) & lca.URGENT
    assert influenced(0, traci.HOLD) == lca.TRACI | lca.STAY


def test_safety_checks_are_kept() -> None:
    """LCP_URGENT: the blocked bits stay, so a blocked request waits."""
    assert influenced(BLOCKED, traci.LEFT) == (
        BLOCKED | lca.TRACI | lca.LEFT | lca.URGENT
    )


def test_a_wish_that_only_repeats_a_request_is_renewed() -> None:
    state = lca.TRACI | lca.LEFT | lca.URGENT
    assert influenced(state, traci.LEFT) == state
    assert influenced(lca.TRACI | lca.LEFT, traci.HOLD) == lca.TRACI | lca.STAY


def test_cancel_request_drops_any_wish_the_request_alters() -> None:
    assert bool(traci.cancels(jnp.int32(lca.LEFT | lca.SPEEDGAIN), traci.LEFT))
    agreeing = lca.TRACI | lca.LEFT | lca.URGENT | lca.SPEEDGAIN
    assert not bool(traci.cancels(jnp.int32(agreeing), traci.LEFT))
    # the request adds its urgency: SUMO's cancelRequest sees a changed state
    assert bool(traci.cancels(jnp.int32(agreeing & ~lca.URGENT), traci.LEFT))
    assert not bool(traci.cancels(jnp.int32(lca.LEFT | lca.SPEEDGAIN), traci.NONE))


def test_change_request_by_lane_index() -> None:
    lane = jnp.array([0, 1, 0, 1, 0])
    asked = jnp.array([1, 0, 0, 2, -1])
    got = traci.change_request(asked, lane, jnp.int32(2))
    assert got.tolist() == [traci.LEFT, traci.RIGHT, traci.HOLD, traci.NONE, traci.NONE]
