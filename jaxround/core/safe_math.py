"""sqrt, power and ratios with the plain forward values and finite gradients.

The dynamics evaluate both sides of many `jnp.where`s, some at points where
a derivative is infinite (sqrt at 0, ``x ** delta`` at 0 in delta, a ratio
over an infinite gap). The discarded side's zero cotangent times that
infinity is NaN, and NaN survives the `where`. These versions keep the value
bit for bit and route the discarded side through a harmless point.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def safe_sqrt(x: jax.Array) -> jax.Array:
    """``sqrt(x)`` for x > 0, else 0; gradient 0 where x <= 0."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def safe_power(x: jax.Array, exponent: jax.Array) -> jax.Array:
    """``x ** exponent`` for x > 0, else 0 (exponent > 0); finite gradients."""
    pos = x > 0
    return jnp.where(pos, jnp.power(jnp.where(pos, x, 1.0), exponent), 0.0)


def finite_or(x: jax.Array, fill: float) -> jax.Array:
    """`x` where finite, else `fill`: for inputs whose infinite entries are
    discarded later anyway (padding, "no leader")."""
    return jnp.where(jnp.isfinite(x), x, fill)
