"""`jaxround.envs.wrappers.auto_reset`: one environment or a batch, reset where done."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.envs.wrappers import auto_reset

#: (obs (3, 2), step count (3,)) of three environments after a step, and fresh.
STEPPED = (jnp.arange(6.0).reshape(3, 2), jnp.array([1, 2, 3]))
FRESH = (jnp.full((3, 2), -1.0), jnp.zeros(3, jnp.int32))


def test_a_batch_is_reset_only_where_done() -> None:
    done = jnp.array([False, True, False])
    obs, count = jax.jit(lambda d: auto_reset(d, STEPPED, lambda: FRESH))(done)
    np.testing.assert_array_equal(obs, [[0.0, 1.0], [-1.0, -1.0], [4.0, 5.0]])
    np.testing.assert_array_equal(count, [1, 0, 3])
    obs, count = auto_reset(jnp.zeros(3, bool), STEPPED, lambda: FRESH)
    np.testing.assert_array_equal(obs, STEPPED[0])
    np.testing.assert_array_equal(count, STEPPED[1])


def test_one_environment() -> None:
    stepped, fresh = (STEPPED[0][0], STEPPED[1][0]), (FRESH[0][0], FRESH[1][0])
    obs, count = auto_reset(jnp.bool_(True), stepped, lambda: fresh)
    np.testing.assert_array_equal(obs, [-1.0, -1.0])
    assert int(count) == 0
    obs, count = auto_reset(jnp.bool_(False), stepped, lambda: fresh)
    np.testing.assert_array_equal(obs, [0.0, 1.0])
    assert int(count) == 1
