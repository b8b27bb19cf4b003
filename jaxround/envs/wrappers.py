"""The automatic reset after a step, for one environment or a batch of them.

    obs, state, reward, done, info = env.step_env(key, state, action, params)
    obs, state = auto_reset(done, (obs, state), lambda: env.reset(key, params))

`RoundaboutEnv.step` uses it on one roundabout; `agents.common.batch`'s
`BatchTrainer.env_step` on B roundabouts at once, so that the reset is
computed only in the steps where some episode ended (a reset inside
``jax.vmap(env.step)`` becomes a select that computes the reset in every
step).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp


def auto_reset(done: jax.Array, stepped: Any, reset: Callable[[], Any]) -> Any:
    """`stepped` with a fresh episode's values where the episode ended.

    Args:
        done: bool () for one environment, or (B,) for a batch: the episode
            ended with this step.
        stepped: the pytree after the step, usually (obs, state); every
            leaf's leading axes are `done`'s.
        reset: returns the fresh episode's pytree, of `stepped`'s structure,
            shapes and dtypes. It runs inside a `lax.cond`: only when some
            episode ended (under an outer `vmap` both branches run; the
            result is the same).

    Returns:
        `stepped`, its leaves replaced by `reset()`'s where `done`.
    """

    def with_reset(carry: Any) -> Any:
        fresh = reset()

        def pick(new: jax.Array, old: jax.Array) -> jax.Array:
            where = jnp.reshape(done, done.shape + (1,) * (old.ndim - done.ndim))
            return jnp.where(where, new, old)

        return jax.tree.map(pick, fresh, carry)

    return jax.lax.cond(jnp.any(done), with_reset, lambda carry: carry, stepped)


__all__ = ["auto_reset"]
