"""GAE over vehicle slots and the masked PPO loss.

Samples are laid out (T, B, M): rollout step, roundabout, vehicle slot. A
sample exists where its slot holds an active AV (the *agent* mask); HV and
empty slots are carried along in the arrays (fixed shapes) and masked out of
every sum. Slot i's trajectory is cut

- where its vehicle leaves the network (``terminated``): no bootstrap;
- where the episode ends (``truncated``): bootstrapped. The environment
  resets itself in the same step, so the true next observation is gone; the
  value of the *current* observation stands in for it,
  ``r_t + gamma * V(s_t)``;
- where the next step's slot holds no agent (defensive; it cannot happen
  without a termination): bootstrapped the same way.

As in Brax's ``compute_gae``, termination and truncation stay apart.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from agents.common import networks
from agents.common.losses import masked_mean


class Batch(NamedTuple):
    """Training samples of E env steps, M slots each. Arrays (E, M) unless noted.

    Attributes:
        obs: float (E, M, D) observation rows.
        active: bool slot holds a vehicle (for the centralised input).
        agent: bool slot holds an active AV: the sample counts.
        accel: float acceleration command taken.
        change: int32 lane choice taken.
        log_prob: float log-probability of the action when it was taken.
        value: float value estimate when the action was taken.
        advantage: float GAE advantage.
        target: float value target (advantage + value).
    """

    obs: jax.Array
    active: jax.Array
    agent: jax.Array
    accel: jax.Array
    change: jax.Array
    log_prob: jax.Array
    value: jax.Array
    advantage: jax.Array
    target: jax.Array


def compute_gae(
    reward: jax.Array,
    value: jax.Array,
    agent: jax.Array,
    terminated: jax.Array,
    truncated: jax.Array,
    last_value: jax.Array,
    last_agent: jax.Array,
    gamma: float,
    gae_lambda: float,
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimates per slot, with the cuts of the module doc.

    Args:
        reward: float (T, ...) reward of each step.
        value: float (T, ...) V(s_t).
        agent: bool (T, ...) the sample exists.
        terminated: bool (T, ...) the slot's vehicle left during step t.
        truncated: bool (T, ...) the episode ended with step t.
        last_value: float (...) V of the observation after the last step.
        last_agent: bool (...) that observation's slot holds an agent.
        gamma: discount.
        gae_lambda: GAE lambda.

    Returns:
        (advantages, targets), float (T, ...), zero where `agent` is false.
    """
    next_value = jnp.concatenate([value[1:], last_value[None]])
    next_agent = jnp.concatenate([agent[1:], last_agent[None]])
    continues = ~terminated & ~truncated & next_agent
    bootstrap = jnp.where(terminated, 0.0, jnp.where(continues, next_value, value))
    delta = reward + gamma * bootstrap - value
    discount = gamma * gae_lambda * continues.astype(value.dtype)

    def backward(acc: jax.Array, xs: tuple[jax.Array, jax.Array]):
        delta_t, discount_t = xs
        acc = delta_t + discount_t * acc
        return acc, acc

    _, adv = jax.lax.scan(
        backward, jnp.zeros_like(last_value), (delta, discount), reverse=True
    )
    adv = jnp.where(agent, adv, 0.0)
    return adv, jnp.where(agent, adv + value, 0.0)


def ppo_loss(
    params: dict,
    apply_fn: Callable[..., networks.PolicyOutput],
    batch: Batch,
    clip_eps: float,
    vf_coef: float,
    ent_coef: float,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Clipped surrogate + clipped value loss - entropy bonus, over agent samples.

    Advantages are normalised over the minibatch's agent samples. Everything
    a non-agent slot holds (action, log-prob, value, advantage, target) is
    replaced by zeros before use, so neither the loss nor its gradient depends
    on it.

    Args:
        params: network parameters.
        apply_fn: ``apply_fn(params, obs, active) -> PolicyOutput``.
        batch: the minibatch.
        clip_eps: ratio clip (also the value clip).
        vf_coef: weight of the value loss.
        ent_coef: weight of the entropy bonus.

    Returns:
        (loss, {"policy_loss", "value_loss", "entropy", "approx_kl", "clip_frac"}).
    """
    m = batch.agent

    def keep(x: jax.Array) -> jax.Array:
        return jnp.where(m, x, jnp.zeros_like(x))

    accel, change = keep(batch.accel), keep(batch.change)
    old_log_prob, old_value = keep(batch.log_prob), keep(batch.value)
    adv, target = keep(batch.advantage), keep(batch.target)
    mean = masked_mean(adv, m)
    std = jnp.sqrt(masked_mean((adv - mean) ** 2, m))
    adv = keep((adv - mean) / (std + 1e-8))

    out = apply_fn(params, batch.obs, batch.active)
    log_ratio = keep(networks.log_prob(out, accel, change) - old_log_prob)
    ratio = jnp.exp(log_ratio)
    surrogate = jnp.minimum(
        ratio * adv, jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * adv
    )
    value = keep(out.value)
    value_clipped = old_value + jnp.clip(value - old_value, -clip_eps, clip_eps)
    value_loss = 0.5 * jnp.maximum((value - target) ** 2, (value_clipped - target) ** 2)
    aux = {
        "policy_loss": -masked_mean(surrogate, m),
        "value_loss": masked_mean(value_loss, m),
        "entropy": masked_mean(networks.entropy(out), m),
        "approx_kl": masked_mean((ratio - 1.0) - log_ratio, m),
        "clip_frac": masked_mean(jnp.abs(ratio - 1.0) > clip_eps, m),
    }
    loss = aux["policy_loss"] + vf_coef * aux["value_loss"] - ent_coef * aux["entropy"]
    return loss, aux


__all__ = ["Batch", "compute_gae", "ppo_loss"]
