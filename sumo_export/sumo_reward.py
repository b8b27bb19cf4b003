"""The JAX environment's reward on what SUMO reports, for environments that
train in SUMO (`sumo_export.pettingzoo_env`).

The functions are `jaxround.envs.reward`'s, jitted once on arrays padded to a
fixed size; only their inputs come from libsumo:

- ``agent.reward: paper`` (`av_reward`): each AV's speed after the step, its
  desired speed (its lane's limit times its speed factor, at most the
  vType's maximum speed) and its CO2 rate in the step (SUMO's
  ``getCO2Emission``, mg/s).
- ``agent.reward: system`` (`system_reward`): the vehicles in the network or
  waiting to be inserted before the step, and every vehicle's CO2 of the step.

A vehicle that arrives in the step has left SUMO when the step is read: its
numbers are the ones it had before the step (the JAX environment still
moves it through its last step).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core.params import EnvParams
from jaxround.envs.reward import av_reward, system_reward
from jaxround.scenario.config import ScenarioConfig


@dataclass(frozen=True)
class Reading:
    """Per vehicle in the network, what the reward reads of it.

    Attributes:
        speed: m/s, after the last step.
        v_desired: desired speed, m/s.
        co2_rate: CO2 rate of the last step, mg/s.
    """

    speed: float
    v_desired: float
    co2_rate: float


class SumoReward:
    """The scenario's reward for the AVs of one SUMO step.

    Args:
        cfg: the scenario (``agent.reward``, ``agent.share``, the drivers).
        max_slots: most vehicles in the network at once (the observer's slots).
    """

    def __init__(self, cfg: ScenarioConfig, max_slots: int) -> None:
        self.kind = cfg.agent.reward
        self.params = EnvParams.from_config(cfg)
        self.dt = cfg.simulation.dt_s
        self.size = 2 * max_slots  # the vehicles before and after a step
        self.max_speed = float(self.params.vehicle.max_speed)
        share = cfg.agent.share
        if self.kind == "system":
            self._fn = jax.jit(
                functools.partial(system_reward, dt=self.dt, share=share)
            )
        else:
            self._fn = jax.jit(av_reward)
        self._before: dict[str, Reading] = {}
        self._n_in_system = 0

    def read(self, libsumo: Any, vid: str) -> Reading:
        veh = libsumo.vehicle
        desired = veh.getAllowedSpeed(vid) * veh.getSpeedFactor(vid)
        return Reading(
            speed=veh.getSpeed(vid),
            v_desired=min(desired, self.max_speed),
            co2_rate=veh.getCO2Emission(vid),
        )

    def before_step(self, libsumo: Any, agents: Sequence[str]) -> None:
        """Remember what the step's arrivals will not show after it: the
        agents' numbers (all vehicles' for the system reward) and how many
        vehicles are in the network or waiting."""
        ids = libsumo.vehicle.getIDList() if self.kind == "system" else agents
        self._before = {vid: self.read(libsumo, vid) for vid in ids}
        pending = len(libsumo.simulation.getPendingVehicles())
        self._n_in_system = libsumo.vehicle.getIDCount() + pending

    def after_step(self, libsumo: Any, agents: Sequence[str]) -> dict[str, float]:
        """Each agent's reward for the step just made, {id: reward}.

        Args:
            libsumo: the simulation after the step.
            agents: the AVs that acted in the step (given to `before_step`).
        """
        now = set(libsumo.vehicle.getIDList())
        if self.kind == "system":
            ids = list(dict.fromkeys([*self._before, *now]))
        else:
            ids = list(agents)
        if len(ids) > self.size:
            raise OverflowError(f"{len(ids)} vehicles in a step, {self.size} rows")
        rows = np.zeros((3, self.size), np.float32)
        for k, vid in enumerate(ids):
            r = self.read(libsumo, vid) if vid in now else self._before[vid]
            rows[:, k] = (r.speed, r.v_desired, r.co2_rate)
        agent = np.zeros(self.size, bool)
        index = {vid: k for k, vid in enumerate(ids)}
        agent[[index[a] for a in agents]] = True
        if self.kind == "system":
            active = np.zeros(self.size, bool)
            active[: len(ids)] = True
            co2_step = jnp.asarray(rows[2] * self.dt)
            out = self._fn(
                jnp.float32(self._n_in_system), co2_step, active, agent, self.params
            )
        else:
            out = jnp.where(agent, self._fn(*rows, self.params), 0.0)
        out = np.asarray(out)
        return {a: float(out[index[a]]) for a in agents}
