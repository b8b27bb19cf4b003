"""Constrained PPO's conflict price: a Lagrange multiplier per penetration.

With ``conflict_constraint`` set (`agents.common.constraint_config`), the
price of a near-conflict in the system reward (`EnvParams.reward.
conflict_weight`) is no longer fixed: each penetration group g (roundabout i
is in group ``i % G``, as it draws its AVs at ``penetrations[g]``) has its
own price lambda_g, and after every update's rollout

    rate_g   = 1000 * C_g / A_g           (running counts, decay `smoothing`:
                                           C_g conflicts, A_g vehicles arrived)
    excess_g = clip((rate_g - limit_g) / max(limit_g, 1), -1, 1)
    lambda_g = clip(lambda_g * exp(price_lr * excess_g), price_min, price_max)

a step on the multiplier of the Lagrangian of "conflicts per 1,000 vehicles
at most limit_g" (Altman's constrained MDP; PPO-Lagrangian in Ray, Achiam
and Amodei, "Benchmarking Safe Exploration", 2019). The price rises while
the policy is over its limit and falls while it is under, so that the
policy ends near the limit instead of at a price someone guessed.

The step is taken on log lambda, with the relative excess clipped to
[-1, 1], rather than PPO-Lagrangian's additive ``lambda += lr (rate -
limit)``: a fresh policy explores with many conflicts (40 per 1,000 on
Milan against a limit of about 4), and the additive step drove the price
from 50 to 1,400 vehicle-seconds in 35 updates and needed the other 90 of a
128-update run to come back (docs/safety.md). On log lambda one update
moves the price by at most a factor exp(price_lr) (5% by default), whatever
the rate, and the price scales itself: a tenfold change takes 47 updates.

The limit is the config's, or, by default, the AVs' own vType uncontrolled
(every action NaN), measured once on `measure_episodes` episodes of the
training batch before the first update (`measure_uncontrolled`): "no more
conflicts than uncontrolled AVs", the safety issue's constraint.

Conflicts count as the reports count them: each vehicle of a pair, human
drivers too, per 1,000 vehicles arrived (`info["conflicts"]`,
`info["arrived"]` of `RoundaboutEnv.step_env`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from agents.common.constraint_config import ConflictConstraintConfig
from jaxround.core.params import EnvParams


class ConflictLedger(NamedTuple):
    """The constraint's state, carried in the runner. Arrays (G,), float32.

    Attributes:
        price: lambda_g, the price of a conflict now, vehicle-seconds.
        limit: conflicts per 1,000 vehicles allowed.
        conflicts: running (decayed) count of conflicts.
        arrivals: running (decayed) count of vehicles arrived.
    """

    price: jax.Array
    limit: jax.Array
    conflicts: jax.Array
    arrivals: jax.Array

    def rate(self) -> jax.Array:
        """float (G,) conflicts per 1,000 vehicles, running; NaN before any
        vehicle arrived."""
        return jnp.where(
            self.arrivals > 0, 1000.0 * self.conflicts / self.arrivals, jnp.nan
        )


def groups(n_envs: int, n_groups: int) -> np.ndarray:
    """int (B,) the penetration group of each roundabout (``i % G``)."""
    return np.arange(n_envs) % n_groups


def group_totals(values: jax.Array, group: np.ndarray, n_groups: int) -> jax.Array:
    """float (G,) sums of `values` (..., B) over everything but the group."""
    per_env = jnp.sum(values.reshape(-1, values.shape[-1]), axis=0)
    return jax.ops.segment_sum(per_env.astype(jnp.float32), group, n_groups)


def with_prices(params: EnvParams, price: jax.Array, group: np.ndarray) -> EnvParams:
    """The batch's `EnvParams` (leaves (B, ...)) with roundabout i charging
    ``price[group[i]]`` per conflict."""
    reward = params.reward.replace(conflict_weight=price[group])
    return params.replace(reward=reward)


def measure_uncontrolled(
    env_step: Callable[..., tuple[Any, ...]],
    reset: Callable[[jax.Array], tuple[jax.Array, Any]],
    key: jax.Array,
    *,
    n_steps: int,
    group: np.ndarray,
    n_groups: int,
    action_shape: tuple[int, ...],
) -> tuple[jax.Array, jax.Array]:
    """Conflicts and arrivals of the batch with every AV uncontrolled.

    Args:
        env_step: ``(keys (B, 2), state, action (B, M, 2)) -> (obs, state,
            reward, done, info)``, resetting where done
            (`BatchTrainer.env_step`).
        reset: ``key -> (obs, state)`` of the B roundabouts.
        key: PRNG key.
        n_steps: env steps to run (whole episodes).
        group: int (B,) the roundabouts' penetration groups.
        n_groups: G.
        action_shape: (B, M, 2).

    Returns:
        (conflicts float (G,), arrivals float (G,)).
    """
    k_reset, k_run = jax.random.split(key)
    _, state = reset(k_reset)
    no_action = jnp.full(action_shape, jnp.nan, jnp.float32)

    def one_step(carry, step_key):
        state, conflicts, arrivals = carry
        keys = jax.random.split(step_key, action_shape[0])
        _, state, _, _, info = env_step(keys, state, no_action)
        conflicts = conflicts + group_totals(info["conflicts"], group, n_groups)
        arrivals = arrivals + group_totals(info["arrived"], group, n_groups)
        return (state, conflicts, arrivals), None

    zeros = jnp.zeros(n_groups, jnp.float32)
    (_, conflicts, arrivals), _ = jax.lax.scan(
        one_step, (state, zeros, zeros), jax.random.split(k_run, n_steps)
    )
    return conflicts, arrivals


def fixed_ledger(price: float, n_groups: int) -> ConflictLedger:
    """The ledger of a run without a constraint: the scenario's price in
    every group for good, no limit (NaN), the counts for the metrics."""
    zeros = jnp.zeros(n_groups, jnp.float32)
    return ConflictLedger(
        price=jnp.full(n_groups, price, jnp.float32),
        limit=jnp.full(n_groups, jnp.nan, jnp.float32),
        conflicts=zeros,
        arrivals=zeros,
    )


def start_ledger(
    settings: ConflictConstraintConfig,
    *,
    start_price: float,
    n_groups: int,
    measured: tuple[jax.Array, jax.Array] | None,
) -> ConflictLedger:
    """The ledger before the first update: every price `start_price` (within
    the settings' bounds); the
    limits the config's, or the measured rate (`measure_uncontrolled`'s
    counts) where it gives none."""
    if measured is None:
        limit = jnp.asarray(settings.limits(n_groups), jnp.float32)
    else:
        conflicts, arrivals = measured
        limit = 1000.0 * conflicts / jnp.maximum(arrivals, 1.0)
    zeros = jnp.zeros(n_groups, jnp.float32)
    start_price = min(max(start_price, settings.price_min), settings.price_max)
    price = jnp.full(n_groups, start_price, jnp.float32)
    return ConflictLedger(price=price, limit=limit, conflicts=zeros, arrivals=zeros)


def tally(
    ledger: ConflictLedger, conflicts: jax.Array, arrivals: jax.Array, decay: float
) -> ConflictLedger:
    """The running counts after a rollout's `conflicts` and `arrivals`
    (float (G,)), the old ones decayed by `decay`; prices unchanged."""
    return ledger._replace(
        conflicts=decay * ledger.conflicts + conflicts,
        arrivals=decay * ledger.arrivals + arrivals,
    )


def update_ledger(
    ledger: ConflictLedger,
    settings: ConflictConstraintConfig,
    conflicts: jax.Array,
    arrivals: jax.Array,
) -> ConflictLedger:
    """One multiplier step after a rollout's `conflicts` and `arrivals`
    (float (G,)); a group with no arrival yet keeps its price."""
    ledger = tally(ledger, conflicts, arrivals, settings.smoothing)
    excess = (ledger.rate() - ledger.limit) / jnp.maximum(ledger.limit, 1.0)
    step = settings.price_lr * jnp.clip(jnp.nan_to_num(excess), -1.0, 1.0)
    price = ledger.price * jnp.exp(step)
    return ledger._replace(
        price=jnp.clip(price, settings.price_min, settings.price_max)
    )


__all__ = [
    "ConflictLedger",
    "fixed_ledger",
    "group_totals",
    "groups",
    "measure_uncontrolled",
    "start_ledger",
    "tally",
    "update_ledger",
    "with_prices",
]
