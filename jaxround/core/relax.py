"""Smooth stand-ins for the model's hard decisions, exact at temperature 0.

A hard decision ``margin > 0`` (a gap accepted, a vehicle halting, a vehicle
still on its route) has no useful gradient. With ``EnvParams.relax_temperature``
above 0 it becomes ``sigmoid(margin / temperature)``, a weight in (0, 1) that
blends the outcomes; at 0 the weight is exactly 0 or 1 and the dynamics are the
SUMO-parity ones, bit for bit. As the temperature goes to 0 the relaxed
weights converge to the hard ones wherever the margin is not exactly 0.

Margins keep their units (s, m/s, m), so a temperature of 0.5 means half a
second for gap acceptance and half a metre per second for halting.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def soft_step(margin: jax.Array, temperature: jax.Array) -> jax.Array:
    """Weight of ``margin > 0``: exactly 0/1 at temperature 0, else a sigmoid.

    Args:
        margin: float (...).
        temperature: float scalar or broadcastable, >= 0.

    Returns:
        float (...) in [0, 1].
    """
    margin = jnp.asarray(margin, jnp.float32)
    hard = (margin > 0).astype(margin.dtype)
    smooth = temperature > 0
    # the double where keeps the unused branch's gradient finite at 0
    t = jnp.where(smooth, temperature, 1.0)
    return jnp.where(smooth, jax.nn.sigmoid(margin / t), hard)


def soft_or(a: jax.Array, b: jax.Array) -> jax.Array:
    """Weight of "a or b" for independent weights a, b in [0, 1] (exact on 0/1)."""
    return a + b - a * b


def soft_any(weights: jax.Array, axis: int = -1) -> jax.Array:
    """Weight of "any of them" along `axis` (exact on 0/1)."""
    return 1.0 - jnp.prod(1.0 - weights, axis=axis)


def blend(weight: jax.Array, if_true: jax.Array, if_false: jax.Array) -> jax.Array:
    """``weight * if_true + (1 - weight) * if_false``, equal to the plain
    selection where the weight is exactly 0 or 1 (no 0 * inf)."""
    finite = lambda x: jnp.where(jnp.isfinite(x), x, 0.0)  # noqa: E731
    mixed = weight * finite(if_true) + (1.0 - weight) * finite(if_false)
    return jnp.where(weight >= 1.0, if_true, jnp.where(weight <= 0.0, if_false, mixed))
