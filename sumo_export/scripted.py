"""Scripted controllers (`jaxround.envs.scripted`) driving SUMO's AVs.

    runs = run_many(cfg, schedules, controller=ScriptedControllerFactory("eco"))

The factory builds a `PolicyController` in each SUMO worker whose policy is
the scripted rule, jitted once and called in NumPy on the occupied slots'
observation rows; the controller commands ``setSpeed(v + a dt)`` as
for a trained policy, under SUMO's speed mode 31, and a lane rule's
requests with ``changeLane``.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import numpy as np

from jaxround.envs.scripted import controller_from_spec
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import Schedule
from sumo_export.controller import PolicyController, PolicyFn
from sumo_export.traffic import DEFAULT_SLOTS, synchronous_cpu_dispatch


def scripted_policy(spec: str, dt_s: float) -> PolicyFn:
    """The NumPy ``act(obs (n, D), mask (n,)) -> (accel (n,), lane (n,))``
    of a scripted controller, on its observer's rows (``"rich"``, or
    ``"lanes"`` with a lane rule: `jaxround.envs.scripted_lanes`).

    Raises:
        ValueError: a bad spec (`jaxround.envs.scripted.controller_from_spec`).
    """
    act = jax.jit(controller_from_spec(spec, dt_s=dt_s).action)

    def policy(obs: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        action = np.asarray(act(np.asarray(obs, np.float32)), np.float64)
        accel = np.where(mask, action[:, 0], 0.0)
        return accel, np.where(mask, action[:, 1], np.nan)

    return policy


@dataclass(frozen=True)
class ScriptedControllerFactory:
    """Builds a `PolicyController` running a scripted controller inside a SUMO
    worker process (picklable); a `sumo_export.runner.ControllerFactory`.

    Attributes:
        spec: the scripted controller, e.g. ``"accel:-1"`` or ``"eco:0.3"``.
        max_slots: vehicle slots M (default: what the road holds).
    """

    spec: str
    max_slots: int | str | None = DEFAULT_SLOTS

    def __post_init__(self) -> None:
        controller_from_spec(self.spec)  # a bad spec fails here, not in a worker

    def __call__(self, cfg: ScenarioConfig, schedule: Schedule) -> PolicyController:
        synchronous_cpu_dispatch()
        act = scripted_policy(self.spec, cfg.simulation.dt_s)
        observer = controller_from_spec(self.spec).observer
        return PolicyController(cfg, schedule, act, observer, self.max_slots)
