"""Random draws for schedules, without sorting (sorts are slow on XLA's CPU).

`RoundaboutEnv.draw_schedule` uses them for every automatic reset.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def sorted_uniform(key: jax.Array, n: int, horizon: jax.Array) -> jax.Array:
    """float (n,): n uniform times on [0, horizon), sorted, without a sort.

    The order statistics of n uniforms are distributed as the partial sums
    of n + 1 exponential gaps divided by their total; `cummax` keeps them
    exactly non-decreasing under float rounding.
    """
    sums = jnp.cumsum(jax.random.exponential(key, (n + 1,)))
    t = jax.lax.cummax(horizon * (sums[:n] / sums[n]))
    return jnp.minimum(t, jnp.nextafter(jnp.float32(horizon), jnp.float32(0.0)))


def inverse_cdf(key: jax.Array, weights: jax.Array) -> jax.Array:
    """int (...): an index into the last axis of `weights` (..., G) drawn with
    those (unnormalised, non-negative) weights; a zero weight is never drawn."""
    cdf = jnp.cumsum(weights, axis=-1)
    total = cdf[..., -1]
    u = jax.random.uniform(key, total.shape) * total
    u = jnp.minimum(u, jnp.nextafter(total, jnp.zeros_like(total)))  # u < total
    return jnp.sum(cdf <= u[..., None], axis=-1)  # the first index with cdf > u


def smallest_k(key: jax.Array, n: int, k: jax.Array) -> jax.Array:
    """bool (n,): k of n items chosen uniformly at random, without a sort.

    The items with the k smallest of n random 32-bit keys (ties by index):
    the k-th smallest key is found by a binary search over the key values.
    For one `key` the chosen set grows with k (the AVs at 10% are AVs at 20%).
    """
    bits = jax.random.bits(key, (n,), jnp.uint32)

    def halve(_: int, lo_hi: tuple[jax.Array, jax.Array]):
        lo, hi = lo_hi
        mid = lo + (hi - lo) // 2
        enough = jnp.sum(bits <= mid) >= k
        return jnp.where(enough, lo, mid + 1), jnp.where(enough, mid, hi)

    cut, _ = jax.lax.fori_loop(
        0, 32, halve, (jnp.uint32(0), jnp.uint32(np.iinfo(np.uint32).max))
    )
    below = bits < cut
    ties = bits == cut
    tie_rank = jnp.cumsum(ties) - 1
    return below | (ties & (tie_rank < k - jnp.sum(below)))
