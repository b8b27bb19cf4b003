"""`EnvState.validate` and `Schedule.validate`: shapes and dtypes, named (the
episode statistics too); each leg's vehicles in schedule order (`leg_order`)
and the vehicles waiting to enter per leg."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxround
from jaxround.core.state import leg_order
from jaxround.envs.queues import waiting_per_leg


@pytest.fixture(scope="module")
def states():
    env, params = jaxround.make("milan", max_vehicles=8)
    _, state = env.reset(jax.random.PRNGKey(0), params)
    keys = jax.random.split(jax.random.PRNGKey(1), 3)
    _, batch = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    return state, batch


def test_states_from_reset_are_valid_alone_and_batched(states) -> None:
    state, batch = states
    state.validate()
    batch.validate()
    assert batch.active.shape == (3, 8)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda s: s.replace(pos=s.pos[:-1]), r"EnvState.pos: shape \(7,\)"),
        (lambda s: s.replace(active=s.active.astype(jnp.float32)),
         "EnvState.active: dtype float32, expected bool"),
        (lambda s: s.replace(arrival_s=s.arrival_s[:3]), "EnvState.arrival_s"),
        (lambda s: s.replace(schedule=s.schedule.replace(route=s.schedule.route[1:])),
         "Schedule.route"),
        (lambda s: s.replace(step=jnp.zeros(2, jnp.int32)), "leading axes"),
        (lambda s: s.replace(stats=s.stats.replace(queue_sum=s.stats.queue_sum[1:])),
         r"EnvState.stats.queue_sum: shape \(3,\), expected \(..., 4\)"),
        (lambda s: s.replace(stats=s.stats.replace(overflow=jnp.float32(0))),
         "EnvState.stats.overflow: dtype float32, expected int"),
    ],
)  # fmt: skip
def test_a_wrong_field_is_named(states, change, message) -> None:
    with pytest.raises(ValueError, match=message):
        change(states[0]).validate()


def test_leg_order_by_hand() -> None:
    origin = jnp.asarray([1, 0, 1, 2, 1], jnp.int32)
    table = leg_order(origin, 3)
    assert table.tolist() == [[1, 5, 5, 5, 5], [0, 2, 4, 5, 5], [3, 5, 5, 5, 5]]


def test_waiting_per_leg_is_the_schedule_scan() -> None:
    """The per-leg binary search counts what a scan of all N vehicles counts:
    due by t and not inserted, per origin leg."""
    env, params = jaxround.make("milan", max_vehicles=8)
    _, state = env.reset(jax.random.PRNGKey(4), params)
    s = state.schedule
    for t, inserted_per_leg in ((0.0, [0, 0, 0, 0]), (95.0, [3, 1, 0, 2])):
        table = np.asarray(state.leg_vehicles)
        inserted = np.zeros(s.depart_s.shape[0], bool)
        for leg, k in enumerate(inserted_per_leg):
            inserted[table[leg, :k]] = True
        st = state.replace(leg_inserted=jnp.asarray(inserted_per_leg, jnp.int32))
        due = np.asarray(s.depart_s) <= t + 1e-4
        expected = [
            int(np.sum(due & ~inserted & (np.asarray(s.origin) == leg)))
            for leg in range(4)
        ]
        assert waiting_per_leg(st, jnp.float32(t)).tolist() == expected
        assert sum(expected) > 0 or t == 0.0
