"""The JaxMARL view: a JaxMARL-style loop (its LogWrapper, agents batched for
one shared policy, masked policy-gradient updates) runs a few updates, and the
view gives the environment's own numbers. One compiled program."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

pytest.importorskip("jaxmarl")

from jaxmarl.wrappers.baselines import LogWrapper  # noqa: E402

from jaxround.envs.roundabout import make  # noqa: E402
from jaxround.integrations.jaxmarl_env import RoundaboutMARL  # noqa: E402
from tests.conftest import small_config  # noqa: E402

#: Slots (agents), episode length (steps of 0.5 s), steps per update, updates.
SLOTS, EPISODE_STEPS, ROLLOUT, N_UPDATES, N_ENVS = 12, 16, 20, 3, 2


@pytest.fixture(scope="module")
def marl() -> RoundaboutMARL:
    cfg = small_config("milan", n_vehicles=30, duration_s=60.0)
    env, params = make(cfg, max_vehicles=SLOTS, episode_s=EPISODE_STEPS * 0.5)
    return RoundaboutMARL(env, params.with_penetration(0.5))


def log_prob(policy: dict[str, jax.Array], obs: jax.Array, act: jax.Array):
    """A shared linear Gaussian policy over the acceleration, (...,)."""
    mean = obs @ policy["w"] + policy["b"]
    z = (act - mean) / jnp.exp(policy["log_std"])
    return -0.5 * z**2 - policy["log_std"]


@pytest.fixture(scope="module")
def trained(marl: RoundaboutMARL) -> dict[str, Any]:
    env = LogWrapper(marl)
    d = marl.env.obs_size
    start = {"w": jnp.zeros(d), "b": jnp.float32(0.0), "log_std": jnp.float32(0.0)}
    opt = optax.adam(1e-2)

    def rollout(policy, obs, state, key):
        def one(carry, key):
            obs, state = carry
            k_act, k_step = jax.random.split(key)
            rows = jax.vmap(marl.stack)(obs)  # (E, M, D): the agents batched
            avail = jax.vmap(marl.get_avail_actions)(state.env_state)
            mask = jax.vmap(marl.stack)(avail)  # (E, M)
            mean = rows @ policy["w"] + policy["b"]
            noise = jax.random.normal(k_act, mean.shape)
            accel = mean + jnp.exp(policy["log_std"]) * noise
            action = jnp.stack([accel, jnp.zeros_like(accel)], axis=-1)  # (E, M, 2)
            actions = jax.vmap(marl.split)(action)
            obs, state, reward, done, info = jax.vmap(env.step)(
                jax.random.split(k_step, N_ENVS), state, actions
            )
            out = {
                "rows": rows,
                "accel": accel,
                "mask": mask,
                "reward": jax.vmap(marl.stack)(reward),
                "done": jax.vmap(marl.stack)(done),
                "done_all": done["__all__"],
                "returned": info["returned_episode"],
                "returns": info["returned_episode_returns"],
                "agent": info["agent"],
            }
            return (obs, state), out

        keys = jax.random.split(key, ROLLOUT)
        (obs, state), batch = jax.lax.scan(one, (obs, state), keys)
        return obs, state, batch

    def loss_fn(policy, batch):
        # reward-to-go per slot, masked: only steps in which the slot held an AV
        togo = jax.lax.associative_scan(jnp.add, batch["reward"], reverse=True)
        adv = (togo - togo.mean()) / (togo.std() + 1e-6)
        lp = log_prob(policy, batch["rows"], batch["accel"])
        mask = batch["mask"]
        return -jnp.sum(lp * adv * mask) / jnp.maximum(mask.sum(), 1.0)

    @jax.jit
    def train(key):
        k_reset, key = jax.random.split(key)
        obs, state = jax.vmap(env.reset)(jax.random.split(k_reset, N_ENVS))

        def update(carry, key):
            policy, opt_state, obs, state = carry
            obs, state, batch = rollout(policy, obs, state, key)
            loss, grads = jax.value_and_grad(loss_fn)(policy, batch)
            updates, opt_state = opt.update(grads, opt_state)
            policy = optax.apply_updates(policy, updates)
            return (policy, opt_state, obs, state), (loss, batch)

        carry = (start, opt.init(start), obs, state)
        (policy, _, _, _), (losses, batches) = jax.lax.scan(
            update, carry, jax.random.split(key, N_UPDATES)
        )
        return {"policy": policy, "losses": losses, "batches": batches}

    return jax.device_get(train(jax.random.PRNGKey(0)))


def test_spaces_and_agents(marl: RoundaboutMARL) -> None:
    assert marl.num_agents == SLOTS and len(marl.agents) == SLOTS
    assert marl.agent_classes == {"av": marl.agents}
    space = marl.action_space(marl.agents[0])
    assert space.shape == (2,)
    np.testing.assert_allclose(space.low, [-marl.params.vehicle.decel, -1.0])
    assert marl.observation_space(marl.agents[-1]).shape == (marl.env.obs_size,)


def test_a_jaxmarl_style_loop_runs_a_few_updates(trained: dict[str, Any]) -> None:
    losses, batches, policy = trained["losses"], trained["batches"], trained["policy"]
    assert losses.shape == (N_UPDATES,) and np.isfinite(losses).all()
    assert np.any(policy["w"] != 0.0)  # the updates moved the shared policy
    mask = batches["mask"]  # (U, T, E, M)
    assert mask.any() and not mask.all()
    # an agent is done exactly where its slot holds no AV, or at the episode's end
    ended = batches["done_all"][..., None]
    next_mask = np.concatenate([mask[:, 1:], mask[:, -1:]], axis=1)
    live = np.ones_like(mask, bool)
    live[:, -1] = False  # the rollout's last step has no next mask here
    np.testing.assert_array_equal(batches["done"][live], (~next_mask | ended)[live])
    # the episode ends (and the view resets) every EPISODE_STEPS steps
    flat_done = batches["done_all"].reshape(-1, N_ENVS)
    np.testing.assert_array_equal(
        np.nonzero(flat_done[:, 0])[0] + 1,
        np.arange(1, len(flat_done) // EPISODE_STEPS + 1) * EPISODE_STEPS,
    )
    # JaxMARL's LogWrapper sums each agent's rewards over the episode
    rewards = batches["reward"].reshape(-1, N_ENVS, SLOTS)[:EPISODE_STEPS].sum(0)
    returns = batches["returns"].reshape(-1, N_ENVS, SLOTS)[EPISODE_STEPS - 1]
    np.testing.assert_allclose(returns, rewards, rtol=1e-5, atol=1e-5)
    assert np.all(returns.sum(-1) < 0.0)


def test_rewards_fall_only_on_agents_with_an_av(trained: dict[str, Any]) -> None:
    b = trained["batches"]
    np.testing.assert_array_equal(b["agent"], b["mask"])
    assert np.all(b["reward"][~b["agent"]] == 0.0)
    assert np.all(b["reward"][b["agent"]] <= 0.0)
    assert np.any(b["reward"][b["agent"]] < 0.0)
