"""The gymnax view: gymnax's own wrappers step it in a jitted, vmapped loop, and
it gives what the environment gives. One compiled program for the module."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("gymnax")

from gymnax.wrappers.purerl import FlattenObservationWrapper, LogWrapper  # noqa: E402

from jaxround.envs.roundabout import make  # noqa: E402
from jaxround.integrations.gymnax_env import (  # noqa: E402
    MASK_COLUMN,
    RoundaboutGymnax,
)
from tests.conftest import small_config  # noqa: E402

#: Slots, episode length (steps of 0.5 s), steps of the loop, roundabouts.
SLOTS, EPISODE_STEPS, LOOP_STEPS, N_ENVS = 16, 24, 30, 2


@pytest.fixture(scope="module")
def view() -> RoundaboutGymnax:
    cfg = small_config("milan", n_vehicles=30, duration_s=60.0)
    env, _ = make(cfg, max_vehicles=SLOTS, episode_s=EPISODE_STEPS * 0.5)
    return RoundaboutGymnax(env)


@pytest.fixture(scope="module")
def trace(view: RoundaboutGymnax) -> dict[str, Any]:
    """gymnax's LogWrapper over its FlattenObservationWrapper, N_ENVS
    roundabouts under vmap, LOOP_STEPS steps of random actions in one jit;
    per step the wrapped outputs and, for comparison, the environment's own
    observation and reward of the same transition."""
    env = LogWrapper(FlattenObservationWrapper(view))
    params = view.default_params.with_penetration(0.5)
    space = view.action_space(params)

    def env_reward(state, action, key):  # the environment's own, no view
        rows = action.reshape(SLOTS, 2)  # the flat action, row by row
        return view.env.step_env(key, state, rows, params)[2]

    @jax.jit
    def loop(key: jax.Array) -> dict[str, Any]:
        keys = jax.random.split(key, N_ENVS)
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
        first_env_obs = jax.vmap(view.env.reset, in_axes=(0, None))(keys, params)[0]

        def one(carry, key):
            obs, state = carry
            k_act, k_step = jax.random.split(key)
            action = jax.vmap(space.sample)(jax.random.split(k_act, N_ENVS))
            step_keys = jax.random.split(k_step, N_ENVS)
            before = state.env_state  # LogEnvState -> EnvState (Flatten keeps it)
            obs, state, reward, terminated, truncated, info = jax.vmap(
                env.step, in_axes=(0, 0, 0, None)
            )(step_keys, state, action, params)
            after = state.env_state
            out = {
                "obs": obs,
                "reward": reward,
                "terminated": terminated,
                "truncated": truncated,
                "returned": info["returned_episode"],
                "returns": info["returned_episode_returns"],
                "lengths": info["returned_episode_lengths"],
                "slot_reward": info["slot_reward"],
                "env_reward": jax.vmap(env_reward)(before, action, step_keys),
                "env_obs": jax.vmap(view.env.observation, in_axes=(0, None))(
                    after, params
                ),
                "av_mask": after.active & after.is_av,
            }
            return (obs, state), out

        steps = jax.random.split(key, LOOP_STEPS)
        _, trace = jax.lax.scan(one, (obs, state), steps)
        return {"first_obs": obs, "first_env_obs": first_env_obs, **trace}

    return jax.device_get(loop(jax.random.PRNGKey(3)))


def test_spaces_say_the_shapes_and_the_bounds(view: RoundaboutGymnax) -> None:
    params = view.default_params
    obs_space, act_space = view.observation_space(params), view.action_space(params)
    assert obs_space.shape == (SLOTS, view.env.obs_size + 1)
    assert act_space.shape == (SLOTS * 2,)
    action = act_space.sample(jax.random.PRNGKey(0))
    assert bool(act_space.contains(action))
    assert not bool(act_space.contains(action.at[0].set(99.0)))
    rows_low, rows_high = (
        act_space.low.reshape(SLOTS, 2),
        act_space.high.reshape(SLOTS, 2),
    )
    np.testing.assert_allclose(rows_low, [[-params.vehicle.decel, -1.0]] * SLOTS)
    np.testing.assert_allclose(rows_high, [[params.av.accel, 1.0]] * SLOTS)
    obs = jnp.zeros(obs_space.shape).at[:, MASK_COLUMN].set(1.0)
    assert bool(obs_space.contains(obs))
    assert not bool(obs_space.contains(obs.at[0, MASK_COLUMN].set(2.0)))


def test_gymnax_wrappers_step_it_in_a_jitted_loop(
    view: RoundaboutGymnax, trace: dict[str, Any]
) -> None:
    d = view.env.obs_size + 1
    assert trace["obs"].shape == (LOOP_STEPS, N_ENVS, SLOTS * d)
    assert np.isfinite(trace["obs"]).all()
    # each roundabout's episode ends after EPISODE_STEPS steps, truncated
    ended = np.nonzero(trace["returned"][:, 0])[0]
    np.testing.assert_array_equal(ended, [EPISODE_STEPS - 1])
    assert trace["truncated"][EPISODE_STEPS - 1].all()
    assert not trace["terminated"].any()
    # LogWrapper's return is the sum of the episode's rewards
    first = trace["reward"][:EPISODE_STEPS].sum(axis=0)
    np.testing.assert_allclose(trace["returns"][EPISODE_STEPS - 1], first, rtol=1e-5)
    np.testing.assert_array_equal(trace["lengths"][EPISODE_STEPS - 1], EPISODE_STEPS)
    assert np.all(first < 0.0)  # AVs acted: the default reward costs time


def test_it_gives_the_environments_observation_and_reward(
    trace: dict[str, Any],
) -> None:
    rows = trace["first_obs"].reshape(N_ENVS, SLOTS, -1)
    np.testing.assert_array_equal(rows[..., :MASK_COLUMN], trace["first_env_obs"])
    # before the reset at the episode's end: the environment's own numbers
    live = slice(0, EPISODE_STEPS - 1)
    rows = trace["obs"][live].reshape(EPISODE_STEPS - 1, N_ENVS, SLOTS, -1)
    np.testing.assert_allclose(rows[..., :MASK_COLUMN], trace["env_obs"][live])
    np.testing.assert_array_equal(rows[..., MASK_COLUMN], trace["av_mask"][live])
    assert trace["av_mask"].any()
    np.testing.assert_allclose(trace["slot_reward"], trace["env_reward"], atol=1e-6)
    np.testing.assert_allclose(
        trace["reward"], trace["slot_reward"].sum(axis=-1), rtol=1e-5, atol=1e-5
    )
