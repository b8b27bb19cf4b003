"""The roundabout as a JaxMARL `MultiAgentEnv`: each vehicle slot an agent.
Installed by ``pip install "jaxround[jaxmarl]"``.

    marl = RoundaboutMARL.make("milan")
    obs, state = marl.reset(key)                  # {"agent_0": (D,), ...}
    obs, state, rewards, dones, infos = marl.step(key, state, actions)

How the slots map onto JaxMARL's agents (as SMAX treats units that die):

- agent ``agent_i`` is slot i of `RoundaboutEnv`; all M agents are always
  in ``agents``, with the same spaces, so one shared policy (parameter
  sharing, the default of JaxMARL's IPPO / MAPPO) reads them as a batch
  (``jnp.stack([obs[a] for a in marl.agents])``, (M, D)).
- an agent acts while its slot holds an AV: ``get_avail_actions(state)[a]``
  is that mask (bool ()), and ``dones[a]`` is its negation after the step
  (the AV left the network, or the slot holds a human driver or nothing).
  Observations of empty slots are zeros. A slot freed by an AV that left
  takes the next vehicle inserted, so a done agent can come back with a new
  AV: a learner masks its transitions with the mask, not with a done that
  stays.
- ``dones["__all__"]`` ends the episode (a fixed horizon: demand and drain);
  `step` then resets, as every JaxMARL environment does.
- rewards: each slot's own reward of `RoundaboutEnv.step_env` (0 for slots
  without an AV). infos hold (M,) arrays, JaxMARL's convention: ``"agent"``
  (the slot held an AV during the step), ``"terminated"`` (its AV left),
  ``"truncated"`` (the episode ended with it inside).

JaxMARL's API has no params argument: the traced `EnvParams` are given at
construction (`with_params` for another set, e.g. another AV share).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
from jaxmarl.environments.multi_agent_env import MultiAgentEnv
from jaxmarl.environments.spaces import Box

from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs.roundabout import RoundaboutEnv, make
from jaxround.integrations.gymnax_env import action_bounds
from jaxround.scenario.config import ScenarioConfig

#: The agents' class: every slot's AV shares one policy.
AGENT_CLASS = "av"


class RoundaboutMARL(MultiAgentEnv):
    """A JaxMARL view of one `RoundaboutEnv` (see the module's docstring).

    Args:
        env: the environment; its step, observer and reward are used as they are.
        params: its traced numbers; default `env.default_params`.
    """

    def __init__(self, env: RoundaboutEnv, params: EnvParams | None = None) -> None:
        super().__init__(num_agents=env.max_vehicles)
        self.env = env
        self.params = env.default_params if params is None else params
        low, high = action_bounds(env, self.params)
        for agent in self.agents:
            self.observation_spaces[agent] = Box(
                -jnp.inf, jnp.inf, (env.obs_size,), jnp.float32
            )
            self.action_spaces[agent] = Box(low, high, (env.action_size,))

    @classmethod
    def make(
        cls,
        scenario: str | Path | ScenarioConfig = "milan",
        params: EnvParams | None = None,
        **kwargs: Any,
    ) -> RoundaboutMARL:
        """The view of `jaxround.make(scenario, **kwargs)`."""
        env, _ = make(scenario, **kwargs)
        return cls(env, params)

    def with_params(self, params: EnvParams) -> RoundaboutMARL:
        """The same view with other traced numbers."""
        return type(self)(self.env, params)

    @property
    def name(self) -> str:
        return f"Roundabout-{self.env.cfg.name}"

    @property
    def agent_classes(self) -> dict[str, list[str]]:
        return {AGENT_CLASS: list(self.agents)}

    # ------------------------------------------------------------------ dicts

    def split(self, rows: jax.Array) -> dict[str, jax.Array]:
        """Per-slot rows (M, ...) as ``{agent_i: rows[i]}``."""
        return {agent: rows[i] for i, agent in enumerate(self.agents)}

    def stack(self, values: dict[str, jax.Array]) -> jax.Array:
        """``{agent_i: x_i}`` as rows (M, ...), in slot order."""
        return jnp.stack([values[agent] for agent in self.agents])

    # ------------------------------------------------------------------ API

    def reset(self, key: jax.Array) -> tuple[dict[str, jax.Array], EnvState]:
        obs, state = self.env.reset(key, self.params)
        return self.split(obs), state

    def step_env(
        self, key: jax.Array, state: EnvState, actions: dict[str, jax.Array]
    ) -> tuple[
        dict[str, jax.Array],
        EnvState,
        dict[str, jax.Array],
        dict[str, jax.Array],
        dict[str, Any],
    ]:
        """`RoundaboutEnv.step_env` with the actions of every agent.

        Args:
            actions: ``{agent_i: float (2,)}`` for every slot.

        Returns:
            (obs, state, rewards, dones, infos): dicts by agent (dones with
            ``"__all__"``); infos of (M,) arrays.
        """
        action = self.stack(actions)  # (M, 2)
        obs, state, reward, done, info = self.env.step_env(
            key, state, action, self.params
        )
        acting = state.active & state.is_av  # (M,)
        dones = self.split(~acting | done)
        dones["__all__"] = done
        infos = {k: info[k] for k in ("agent", "terminated", "truncated")}
        return self.split(obs), state, self.split(reward), dones, infos

    def get_obs(self, state: EnvState) -> dict[str, jax.Array]:
        return self.split(self.env.observation(state, self.params))

    def get_avail_actions(self, state: EnvState) -> dict[str, jax.Array]:
        """bool () per agent: its slot holds an AV, which its action drives."""
        return self.split(state.active & state.is_av)
