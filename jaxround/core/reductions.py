"""Minimum and argument of the minimum, as XLA's CPU backend runs them fast.

`jnp.argmin` lowers to one reduction over two operands (value and index),
which XLA's CPU backend runs element by element instead of vectorised; over
the slots of a roundabout the step spent most of its time there. `first_min`
gives the same numbers as ``(jnp.min(x, axis), jnp.argmin(x, axis))`` for
arrays without nan from two one-operand reductions: the minimum, then the
first index that holds it (measured on the 2-core CPU: 5.7 against 12.7 us
for (12, 9, 32) arrays; docs/benchmarks.md). No loop: XLA's cost analysis
counts every operation, and the step compiles as before.

`two_smallest` keeps the two best, for tables from which a vehicle must
skip itself.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax


def first_min(values: jax.Array, axis: int = -1) -> tuple[jax.Array, jax.Array]:
    """The smallest value along `axis` and its index (the first among equals).

    Args:
        values: float (..., N, ...) without nan (mask with inf).
        axis: the axis to reduce.

    Returns:
        (min, index): float and int32 arrays of `values`' shape without `axis`;
        an all-inf slice gives (inf, 0), as jnp.min / jnp.argmin.
    """
    axis = axis % values.ndim
    n = values.shape[axis]
    best = jnp.min(values, axis=axis)
    index = lax.broadcasted_iota(jnp.int32, values.shape, axis)
    holds = values == jnp.expand_dims(best, axis)  # inf == inf: all-inf gives 0
    return best, jnp.min(jnp.where(holds, index, n), axis=axis)


def two_smallest(values: jax.Array, axis: int = -1) -> tuple[jax.Array, jax.Array]:
    """Indices and values of the two smallest entries along `axis`.

    Ordered by (value, index): the first is `first_min`'s, the second the
    smallest of the others (the first again where N is 1).

    Args:
        values: float (..., N, ...) without nan.

    Returns:
        (index, value): int32 and float arrays of `values`' shape without
        `axis`, with a last axis of the two.
    """
    axis = axis % values.ndim
    first_value, first = first_min(values, axis)
    index = lax.broadcasted_iota(jnp.int32, values.shape, axis)
    rest = jnp.where(index == jnp.expand_dims(first, axis), jnp.inf, values)
    second_value, second = first_min(rest, axis)
    return (
        jnp.stack([first, second], axis=-1),
        jnp.stack([first_value, second_value], axis=-1),
    )
