"""What the trainers' losses share: means over the slots that hold an agent.

Samples are laid out over vehicle slots (fixed shapes); only some slots hold
an AV, and every sum over samples is a sum over those.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def masked_mean(x: jax.Array, mask: jax.Array) -> jax.Array:
    """Mean of `x` over `mask` (0 when the mask is empty); masked values may be nan.

    Args:
        x: float (...) values.
        mask: bool (...) the same shape: which values count.

    Returns:
        float () the mean.
    """
    total = jnp.sum(jnp.where(mask, x, 0.0))
    return total / jnp.maximum(jnp.sum(mask), 1)


__all__ = ["masked_mean"]
