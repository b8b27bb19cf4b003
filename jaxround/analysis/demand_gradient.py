"""Gradients of expected episode metrics with respect to the demand's shape.

The demand reaches an episode only through its drawn schedule: which leg
each vehicle enters from (`EnvParams.demand.origin_share`) and which it leaves by
(`EnvParams.demand.od`, row by origin) are discrete draws, so no path through the
dynamics carries their gradient. What has a gradient is the *expected*
metric over schedules, and the likelihood ratio (score function) gives it:

    d/dθ E[f] = E[(f - b) d/dθ log p(schedule; θ)],

with b the mean of the other episodes of the batch (a leave-one-out
baseline: it keeps the estimate unbiased and cuts its variance). The
estimate is averaged over a vmapped batch of episodes.

`surrogate` builds the scalar whose `jax.grad` is this estimate.
`expected_metric` runs the episodes with the params frozen, so that no
backward pass goes through the dynamics (for whole episodes it would be
long to compile and large in memory): for the drivers' numbers, use the
pathwise gradients of `jaxround.analysis.survey` over short windows.

Not covered: the number of vehicles and the horizon (`duration_s`). The
count N is a static shape, and the departure times are uniform on
[0, duration_s): the horizon moves the support of their density, which the
likelihood ratio does not allow, and insertion, which would carry the
pathwise gradient, is a hard decision.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState, Schedule
from jaxround.envs.rollout import Policy, run_episode
from jaxround.envs.roundabout import RoundaboutEnv

#: metric(final_state) -> float (): what the expectation is taken of.
Metric = Callable[[EnvState], jax.Array]


def schedule_log_prob(
    env: RoundaboutEnv, schedule: Schedule, params: EnvParams
) -> jax.Array:
    """log p of the schedule's origins and destinations under `params`.

    As `RoundaboutEnv.draw_schedule` draws them: each vehicle's origin with
    the weights `origin_share`, then its destination with the weights of its
    origin's row of `od` (both unnormalised).

    Args:
        schedule: one schedule, N vehicles.

    Returns:
        float (): the sum over the N vehicles. Weights of 0 carry no
        gradient (`_drawable`).
    """
    origin = schedule.origin
    dest = env.route_destination[schedule.route]
    share = _drawable(params.demand.origin_share)
    share = share / jnp.sum(share)
    rows = _drawable(params.demand.od)
    rows = rows / jnp.sum(rows, axis=1, keepdims=True)
    return jnp.sum(jnp.log(share[origin]) + jnp.log(rows[origin, dest]))


def _drawable(weights: jax.Array) -> jax.Array:
    """The weights, with no gradient where they are 0: a likelihood ratio
    cannot see what is never drawn (raising a zero weight adds routes no
    sample has), so those entries get a gradient of 0, not a biased one."""
    return jnp.where(weights > 0, weights, jax.lax.stop_gradient(weights))


def leave_one_out_baseline(values: jax.Array) -> jax.Array:
    """float (B,): for each episode, the mean of the other B - 1 (B >= 2)."""
    b = values.shape[0]
    if b < 2:
        raise ValueError(f"a leave-one-out baseline needs 2 episodes or more, got {b}")
    return (jnp.sum(values) - values) / (b - 1)


def surrogate(values: jax.Array, log_probs: jax.Array) -> jax.Array:
    """The scalar whose gradient is the score-function estimate (plus the
    pathwise gradient of the mean of `values`, where they carry one).

    Its value is the mean of `values` (the second term is 0 in value, not in
    gradient).

    Args:
        values: float (B,) the metric of each episode.
        log_probs: float (B,) `schedule_log_prob` of each episode's schedule.
    """
    advantage = jax.lax.stop_gradient(values - leave_one_out_baseline(values))
    score = advantage * (log_probs - jax.lax.stop_gradient(log_probs))
    return jnp.mean(values + score)


def expected_metric(
    env: RoundaboutEnv,
    metric: Metric,
    key: jax.Array,
    n_episodes: int,
    policy: Policy | None = None,
    n_steps: int | None = None,
) -> Callable[[EnvParams], jax.Array]:
    """The batch estimate of E[metric] as a function of the params, for `jax.grad`.

    Each episode draws its schedule (`draw_schedule`) from its own key and
    runs it without auto-reset (`run_episode`); the keys are fixed, so the
    same params give the same number. ``jax.grad`` of the returned function
    gives the demand's score-function gradient (`origin_share`, `od`); the
    other parameters get 0 (the episodes run with the params frozen).

    Args:
        metric: float () of an episode's final state (`mean_crossing_time`,
            `mean_queue`, or one's own).
        n_episodes: the batch B (at least 2).
        n_steps: steps per episode (default: the whole episode).

    Returns:
        params -> float (), the mean metric of the B episodes.
    """
    if n_episodes < 2:
        raise ValueError(f"n_episodes: {n_episodes}, expected at least 2")
    k_draw, k_run = jax.random.split(key)
    draw_keys = jax.random.split(k_draw, n_episodes)
    run_keys = jax.random.split(k_run, n_episodes)

    def estimate(params: EnvParams) -> jax.Array:
        frozen = jax.lax.stop_gradient(params)
        schedules = jax.vmap(env.draw_schedule, in_axes=(0, None))(draw_keys, frozen)

        def one(schedule: Schedule, key: jax.Array) -> tuple[jax.Array, jax.Array]:
            end = run_episode(env, frozen, schedule, key, policy, n_steps)
            return metric(end), schedule_log_prob(env, schedule, params)

        values, log_probs = jax.vmap(one)(schedules, run_keys)
        return surrogate(values, log_probs)

    return estimate


def mean_crossing_time(state: EnvState) -> jax.Array:
    """float (): mean arrival minus scheduled departure of the arrived
    vehicles (s); 0 if none arrived."""
    arrived = jnp.isfinite(state.arrival_s)
    crossing = jnp.where(arrived, state.arrival_s - state.schedule.depart_s, 0.0)
    return jnp.sum(crossing) / jnp.maximum(jnp.sum(arrived), 1)


def mean_queue(state: EnvState) -> jax.Array:
    """float (): the mean queue per leg over the episode's samples (vehicles)."""
    samples = jnp.maximum(state.stats.queue_samples, 1).astype(jnp.float32)
    return jnp.mean(state.stats.queue_sum) / samples
