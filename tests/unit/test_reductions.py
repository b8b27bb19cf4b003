"""`first_min` and `two_smallest` against jnp.min / jnp.argmin."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.core.reductions import first_min, two_smallest


def _assert_same(new: jax.Array, old: jax.Array, what: str) -> None:
    new, old = np.asarray(new), np.asarray(old)
    assert new.shape == old.shape, what
    assert np.array_equal(new, old), f"{what}: {np.argwhere(new != old)[:5].tolist()}"


@functools.cache
def _reductions():
    def both(x):
        return (
            (first_min(x, 1), two_smallest(x, 0)),
            ((jnp.min(x, 1), jnp.argmin(x, 1)), _two_by_argmin(x)),
        )

    return jax.jit(both)


def _two_by_argmin(x: jax.Array) -> tuple[jax.Array, jax.Array]:
    first = jnp.argmin(x, 0)
    rest = jnp.where(jnp.arange(x.shape[0])[:, None] == first, jnp.inf, x)
    second = jnp.argmin(rest, 0)
    values = jnp.stack([jnp.min(x, 0), jnp.min(rest, 0)], -1)
    return jnp.stack([first, second], -1).astype(jnp.int32), values


@pytest.mark.parametrize("seed", range(4))
def test_first_min_and_two_smallest_are_min_and_argmin(seed: int) -> None:
    rng = np.random.default_rng(seed)
    x = rng.integers(0, 5, (9, 7)).astype(np.float32)  # many ties
    x[rng.random(x.shape) < 0.3] = np.inf
    x[:, 0] = np.inf  # a slice with nothing
    x[0, 1] = -np.inf
    (new_min, new_two), (old_min, old_two) = _reductions()(jnp.asarray(x))
    _assert_same(new_min[0], old_min[0], "min")
    _assert_same(new_min[1], old_min[1].astype(jnp.int32), "argmin")
    _assert_same(new_two[0], old_two[0], "two smallest: indices")
    _assert_same(new_two[1], old_two[1], "two smallest: values")
