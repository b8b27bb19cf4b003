"""The roundabout in real SUMO as one Gymnasium environment for one shared
policy (Stable-Baselines3 and other single-agent learners). Installed by
``pip install "jaxround[pettingzoo]"``.

    env = SumoSharedPolicyEnv(SumoParallelEnv(load_config("milan"), 0.5))
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(action)

A view of `sumo_export.pettingzoo_env.SumoParallelEnv` with the layout of the
JAX environment's gymnax view (`jaxround.integrations.gymnax_env`):

- observation: float32 (M, D + 1), one row per vehicle slot in SUMO's order:
  the observer's D numbers and, last, 1.0 where the slot holds an AV (0.0
  for human drivers and empty slots);
- action: float32 (2M,), each slot's (2,) action row by row (an (M, 2)
  array is taken as well); rows of unmasked slots are ignored;
- reward: the sum of the AVs' rewards of the step;
- terminated: every vehicle has left; truncated: the horizon and drain are over.

A slot's vehicle can change from one step to the next (vehicles come and go):
a learner that shares one policy over the rows (per-row network) fits this
layout; a network over the whole (M, D + 1) array sees the slots as SUMO
orders them.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from sumo_export.pettingzoo_env import SumoParallelEnv


class SumoSharedPolicyEnv(gymnasium.Env):
    """One Gymnasium environment over a `SumoParallelEnv` (module docstring).

    Args:
        parallel: the PettingZoo environment; its slots M are the rows.
    """

    metadata = {"render_modes": []}

    def __init__(self, parallel: SumoParallelEnv) -> None:
        self.parallel = parallel
        self.slots = parallel.controller.sumo.max_slots
        d = parallel.observation_space("").shape[0]
        low = np.full((self.slots, d + 1), -np.inf, np.float32)
        high = np.full((self.slots, d + 1), np.inf, np.float32)
        low[:, -1], high[:, -1] = 0.0, 1.0
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        one = parallel.action_space("")
        self.action_space = spaces.Box(
            np.tile(one.low, self.slots),
            np.tile(one.high, self.slots),
            dtype=np.float32,
        )
        self._ids: list[str] = []

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.parallel.reset(seed=seed, options=options)
        return self._observation(), {"agents": list(self.parallel.agents)}

    def step(
        self, action: np.ndarray
    ) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Send each AV's row of `action`, float (2M,) or (M, 2), and step SUMO.

        Raises:
            ValueError: `action` has another size.
        """
        action = np.asarray(action, np.float32)
        if action.size != self.action_space.shape[0]:
            raise ValueError(
                f"action of shape {action.shape}, expected "
                f"{self.action_space.shape} or ({self.slots}, 2)"
            )
        action = action.reshape(self.slots, 2)
        agents = set(self.parallel.agents)
        actions = {vid: action[k] for k, vid in enumerate(self._ids) if vid in agents}
        _, rewards, _, truncations, _ = self.parallel.step(actions)
        over = not self.parallel.agents
        truncated = over and any(truncations.values())
        info = {"agents": list(self.parallel.agents), "rewards": rewards}
        obs = self._observation()
        return (
            obs,
            float(sum(rewards.values())),
            over and not truncated,
            truncated,
            info,
        )

    def _observation(self) -> np.ndarray:
        ids, rows = self.parallel.slot_rows()
        self._ids = ids
        obs = np.zeros(self.observation_space.shape, np.float32)
        obs[: len(ids), :-1] = rows
        agents = set(self.parallel.agents)
        obs[: len(ids), -1] = [vid in agents for vid in ids]
        return obs

    def close(self) -> None:
        self.parallel.close()
