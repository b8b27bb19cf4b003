"""`EnvState.validate` and `Schedule.validate`: shapes and dtypes, named (the
episode statistics too)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest

import jaxround


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
