"""SUMO's list of active lanes, which orders the edges' lane-change turns
(`jaxround.lanes.active_lanes`), by hand on four lanes of two edges."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxround.lanes.active_lanes import edge_order, join

#: lanes 0 and 1 form edge A, lanes 2 and 3 edge B
SAME_EDGE = jnp.asarray(np.kron(np.eye(2, dtype=bool), np.ones((2, 2), bool)))


def test_a_lane_joining_goes_to_the_front() -> None:
    stamp = jnp.asarray([3, 0, 5, 0], jnp.int32)
    # lanes 1 and 3 join, pushed in the order of their ranks: 3 first, then 1
    out = join(
        stamp, jnp.asarray([False, True, False, True]), jnp.asarray([9, 7, 8, 2])
    )
    assert out.tolist() == [3, 7, 5, 6]  # the last pushed (lane 1) is the front
    # nothing joins: unchanged
    same = join(stamp, jnp.zeros(4, bool), jnp.arange(4))
    assert same.tolist() == stamp.tolist()


def test_edges_take_their_turns_from_their_frontmost_lane() -> None:
    # edge A's lane 1 joined last: A goes first, although B's lane 2 is older
    # than A's lane 0 would say
    assert edge_order(jnp.asarray([1, 9, 5, 0], jnp.int32), SAME_EDGE).tolist() == [
        0, 0, 1, 1,
    ]  # fmt: skip
    assert edge_order(jnp.asarray([4, 0, 2, 6], jnp.int32), SAME_EDGE).tolist() == [
        1, 1, 0, 0,
    ]  # fmt: skip
