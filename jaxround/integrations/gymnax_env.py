"""The roundabout as a gymnax `Environment`, for gymnax's wrappers and
PureJaxRL-style training loops. Installed by ``pip install "jaxround[gymnax]"``.

    env = RoundaboutGymnax.make("milan")
    params = env.default_params
    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(
        key, state, action, params
    )

How M vehicle slots sharing one policy fit gymnax's single-agent API:

- observation: float (M, D + 1), one row per slot: the configured observer's
  D numbers (`jaxround.envs.observe`) and, last, the slot's mask (1.0 where
  the slot holds an AV, which the action drives; 0.0 for human drivers and
  empty slots). A shared policy maps each row to the row of its action.
- action: float (2M,), the (M, 2) per-slot action of `RoundaboutEnv.step`
  row by row (``agent.action: accel``: acceleration in [-decel, accel] m/s^2;
  ``assertiveness``: the raw assertiveness, bounded to +-RAW_BOUND here;
  then the lane column in [-1, 1], `jaxround.envs.lane_view`); `step`
  takes the (M, 2) array as well. Flat,
  so that a PureJaxRL script sizes its actor by ``action_space.shape[0]``
  as for any Box; rows of unmasked slots are ignored.
- reward: float (), the sum of the AV slots' rewards (the team's return; with
  ``agent.reward: system`` and ``share: 1`` it is minus the roundabout's
  cost). Each slot's own reward is ``info["slot_reward"]`` (M,), and
  ``info["agent"]`` (M,) says which slots held an AV during the step.
- terminated is always False: the episode is a fixed horizon (the demand
  and a drain), so it ends truncated after `RoundaboutEnv.episode_steps`
  steps. Vehicles leaving are per slot: ``info["slot_terminated"]``.

Params are the environment's own traced `EnvParams` and the state its
`EnvState`, so ``jax.vmap`` over params sweeps drivers or demand as with the
environment itself. gymnax's `step` computes the reset in every step and
selects it where done (its own rule); `RoundaboutEnv.step` avoids that outside
`vmap`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
from gymnax.environments import environment, spaces

from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs.assertiveness import RAW_BOUND
from jaxround.envs.roundabout import RoundaboutEnv, make
from jaxround.scenario.config import ScenarioConfig

#: Column of an observation row that holds the slot's mask.
MASK_COLUMN = -1


def with_mask(obs: jax.Array, state: EnvState) -> jax.Array:
    """The observer's rows with each slot's AV mask appended, float (M, D + 1).

    Args:
        obs: float (M, D) the observer's rows.
        state: the state they were observed in.
    """
    mask = (state.active & state.is_av).astype(obs.dtype)
    return jnp.concatenate([obs, mask[:, None]], axis=-1)


def action_bounds(env: RoundaboutEnv, params: EnvParams) -> tuple[jax.Array, ...]:
    """(low, high) of one slot's action, float (2,) each: the first number's
    range for the configured action meaning, and [-1, 1] for the lane
    column (`jaxround.envs.lane_view`: > 0.5 left, < -0.5 right, hold
    between)."""
    if env.cfg.agent.action == "assertiveness":
        first = (-RAW_BOUND, RAW_BOUND)
    else:
        first = (-params.vehicle.decel, params.av.accel)
    low = jnp.stack([jnp.asarray(first[0], jnp.float32), jnp.float32(-1.0)])
    high = jnp.stack([jnp.asarray(first[1], jnp.float32), jnp.float32(1.0)])
    return low, high


class RoundaboutGymnax(environment.Environment):
    """A gymnax view of one `RoundaboutEnv` (see the module's docstring).

    Args:
        env: the environment; its step, observer and reward are used as they are.
    """

    def __init__(self, env: RoundaboutEnv) -> None:
        super().__init__()
        self.env = env

    @classmethod
    def make(
        cls, scenario: str | Path | ScenarioConfig = "milan", **kwargs: Any
    ) -> RoundaboutGymnax:
        """The view of `jaxround.make(scenario, **kwargs)`."""
        env, _ = make(scenario, **kwargs)
        return cls(env)

    @property
    def default_params(self) -> EnvParams:
        return self.env.default_params

    @property
    def name(self) -> str:
        return f"Roundabout-{self.env.cfg.name}"

    @property
    def num_actions(self) -> int:
        """Numbers per slot of the action."""
        return self.env.action_size

    def reset_env(
        self, key: jax.Array, params: EnvParams
    ) -> tuple[jax.Array, EnvState]:
        obs, state = self.env.reset(key, params)
        return with_mask(obs, state), state

    def step_env(
        self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams
    ) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, dict[str, Any]]:
        """`RoundaboutEnv.step_env`, its per-slot reward summed.

        Args:
            action: float (2M,) or (M, 2), per slot.

        Returns:
            (obs (M, D + 1), state, reward (), terminated (), info).
        """
        action = jnp.reshape(action, (self.env.max_vehicles, self.env.action_size))
        obs, state, slot_reward, _, info = self.env.step_env(key, state, action, params)
        info = {
            "slot_reward": slot_reward,
            "agent": info["agent"],
            "slot_terminated": info["terminated"],
            "arrived": info["arrived"],
            "collisions": info["collisions"],
            "n_active": info["n_active"],
        }
        terminated = jnp.bool_(False)
        return with_mask(obs, state), state, jnp.sum(slot_reward), terminated, info

    def is_truncated(self, state: EnvState, params: EnvParams) -> jax.Array:
        return state.step >= self.env.episode_steps

    def is_terminated(self, state: EnvState, params: EnvParams) -> jax.Array:
        return jnp.bool_(False)

    def observation_space(self, params: EnvParams) -> spaces.Box:
        """float (M, D + 1); the observers' numbers are unbounded, the mask in
        [0, 1]."""
        m, d = self.env.max_vehicles, self.env.obs_size
        low = jnp.full((m, d + 1), -jnp.inf).at[:, MASK_COLUMN].set(0.0)
        high = jnp.full((m, d + 1), jnp.inf).at[:, MASK_COLUMN].set(1.0)
        return spaces.Box(low, high, (m, d + 1), jnp.float32)

    def action_space(self, params: EnvParams | None = None) -> spaces.Box:
        """float (2M,): each slot's pair within `action_bounds`."""
        low, high = action_bounds(self.env, params or self.default_params)
        m = self.env.max_vehicles
        shape = (m * self.env.action_size,)
        return spaces.Box(jnp.tile(low, m), jnp.tile(high, m), shape)

    def state_space(self, params: EnvParams) -> Any:
        raise NotImplementedError(
            "the state is a jaxround EnvState (jaxround.core.state), not a space"
        )
