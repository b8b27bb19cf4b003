"""The pieces of `jaxround.lanes.ring_rounds` that stand in for SUMO's one
by one bookkeeping: the smallest advices kept, and the messages a vehicle
receives."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxround.lanes.decide import Told
from jaxround.lanes.ring_rounds import inbox, smallest
from jaxround.lanes.views import N_ADVICES, push_advice


def _pushed(advices: np.ndarray, more: np.ndarray) -> np.ndarray:
    out = jnp.asarray(advices)
    for speed in more:
        out = push_advice(out, jnp.asarray(speed))
    return np.sort(np.asarray(out))


def test_smallest_keeps_what_pushing_one_by_one_keeps() -> None:
    rng = np.random.default_rng(0)
    for n_more in (0, 3, 8, 20):
        for _ in range(5):
            advices = np.full(N_ADVICES, np.nan)
            advices[: rng.integers(0, N_ADVICES + 1)] = rng.uniform(0, 15)
            more = rng.uniform(0, 15, n_more).round(1)  # ties
            more[rng.random(n_more) < 0.4] = np.nan
            more[rng.random(n_more) < 0.1] = np.inf
            got = np.sort(np.asarray(smallest(jnp.asarray(advices), jnp.asarray(more))))
            np.testing.assert_array_equal(got, _pushed(advices, more))


def test_inbox_gathers_each_vehicles_counted_messages() -> None:
    nan = np.nan
    # 3 vehicles, 4 messages each (rows: senders)
    told = Told(
        slot=jnp.array([[1, 2, 1, 0], [0, 0, 2, 2], [1, 1, 0, 0]]),
        speed=jnp.array(
            [[5.0, 3.0, 4.0, nan], [7.0, nan, nan, 1.0], [nan, 2.0, 6.0, nan]]
        ),  # fmt: skip
        bits=jnp.array([[1, 0, 2, 0], [0, 8, 16, 0], [4, 0, 0, 0]]),
    )
    counted = jnp.ones((3, 4), bool).at[2, 1].set(False)
    bits, advices = inbox(told, counted, 3)
    np.testing.assert_array_equal(bits, [8, 1 | 2 | 4, 16])
    np.testing.assert_array_equal(advices[0, :2], [6.0, 7.0])
    np.testing.assert_array_equal(advices[1, :2], [4.0, 5.0])
    np.testing.assert_array_equal(advices[2, :2], [1.0, 3.0])
    assert np.isnan(np.asarray(advices)[:, 2:]).all()
