"""SUMO's MSLink::blockedByFoe for a merging foe link and a crossing one:
the headway tests apply only where both links lead to the same lane
(``sameTargetLane``); a crossing blocks only while the times overlap."""

from __future__ import annotations

import jax.numpy as jnp
import pytest

from jaxround.core.junction import Approach, _foe_link_weight
from jaxround.core.params import EnvParams
from jaxround.core.state import Registrations
from jaxround.scenario.config import load_config

DT = 0.5


def weight(ego_arrival: float, ego_leave: float, *, same_target: bool) -> float:
    """The block weight of an ego (slot 0, 4 m/s) against one foe (slot 1)
    that arrives at its link at 10 s and leaves it at 11 s at 5 m/s (a
    follower no faster than its merge leader: SUMO's unsafeMergeSpeeds is
    false)."""
    car = EnvParams.from_config(load_config("milan")).for_vehicles(jnp.zeros(2, bool))
    foe = Registrations(
        ok=jnp.array([[False], [True]]),
        dist=jnp.array([[0.0], [20.0]]),
        arrival=jnp.array([[0.0], [10.0]]),
        leave=jnp.array([[0.0], [11.0]]),
        arrival_speed=jnp.array([[0.0], [5.0]]),
        leave_speed=jnp.array([[0.0], [5.0]]),
        braking_speed=jnp.array([[0.0], [5.0]]),
    )
    ego = Approach(
        seen=jnp.array([5.0]),
        arrival=jnp.array([ego_arrival]),
        leave=jnp.array([ego_leave]),
        arrival_speed=jnp.array([4.0]),
        leave_speed=jnp.array([4.0]),
    )
    out = _foe_link_weight(
        car, jnp.array([0]), ego, foe, jnp.array([0.0]), jnp.float32(6.0), DT,
        jnp.array([0]), same_target=same_target,
    )  # fmt: skip
    return float(out[0])


@pytest.mark.parametrize("same_target", [True, False])
def test_overlapping_times_block_both(same_target: bool) -> None:
    assert weight(10.5, 11.5, same_target=same_target) == 1.0


def test_a_merge_keeps_the_headway_a_crossing_does_not() -> None:
    # the ego arrives 0.5 s after the foe has left: inside jmTimegapMinor
    # (1.78 s for Milan's drivers), so a merge is closed, a crossing open
    assert weight(11.5, 12.5, same_target=True) == 1.0
    assert weight(11.5, 12.5, same_target=False) == 0.0
    # long after the foe: both open
    assert weight(14.0, 15.0, same_target=True) == 0.0
    assert weight(14.0, 15.0, same_target=False) == 0.0
