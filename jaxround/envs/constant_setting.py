"""AVs with a constant setting in JAX, a batch of schedules side by side.

A constant setting (`jaxround.scenario.best_constant.BestConstant`) is a
declared AV vType and, optionally, a ``cruise:V`` command on every AV and
step, as SUMO runs it (the vType in the route file, the scripted controller
through libsumo). `constant_setting_runs` runs it on departure schedules
until every vehicle has left or the cap, with as many slots as the traffic
needs (`jaxround.envs.slots.redo_on_overflow`).

Shapes: B schedules, M slots.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core.capacity import road_capacity
from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs.observe import rich_observation
from jaxround.envs.rollout import Policy, runs_until_left, uncontrolled_policy
from jaxround.envs.roundabout import RoundaboutEnv, make
from jaxround.envs.scripted import controller_from_spec
from jaxround.envs.slots import redo_on_overflow
from jaxround.scenario.best_constant import BestConstant
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import Schedule


def constant_config(cfg: ScenarioConfig, constant: BestConstant) -> ScenarioConfig:
    """The scenario with the constant's AV vType, and AV actions that are
    speed commands (a ``cruise:V`` commands speeds whatever the scenario's
    agent does)."""
    new = constant.config_for(cfg)
    return dataclasses.replace(
        new, agent=dataclasses.replace(new.agent, action="accel")
    )


def constant_policy(
    env: RoundaboutEnv, params: EnvParams, constant: BestConstant
) -> Policy:
    """The constant's command per step: ``cruise:V`` on the rich observation
    (`jaxround.envs.scripted`), or none (the AVs drive the vType)."""
    spec = constant.controller_spec
    if spec is None:
        return uncontrolled_policy(env)
    controller = controller_from_spec(spec, env.dt)

    def act(obs: jax.Array, state: EnvState, key: jax.Array) -> jax.Array:
        del obs, key
        rich = rich_observation(env.net, state, params, env.route_destination)
        accel = controller.act(rich)  # (M,)
        return jnp.stack([accel, jnp.full_like(accel, jnp.nan)], axis=1)

    return act


def constant_setting_runs(
    cfg: ScenarioConfig,
    constant: BestConstant,
    schedules: Sequence[Schedule],
    *,
    max_vehicles: int,
    cap_s: float,
    progress: bool = False,
) -> tuple[RoundaboutEnv, EnvState, list[int]]:
    """Every schedule with the AVs on the constant setting, in one batch
    (`jaxround.envs.rollout.runs_until_left`).

    Args:
        cfg: the scenario (its AV vType is replaced by the constant's).
        constant: the setting.
        schedules: B numpy schedules (`jaxround.scenario.schedule`).
        max_vehicles: slots M to start from (redone with more on overflow).
        cap_s: simulated seconds a run may go on.
        progress: a progress bar in simulated time on stderr.

    Returns:
        (the environment of the reported runs, their final states batched
        over B, the slot counts tried).
    """
    cfg = constant_config(cfg, constant)

    def run_with(slots: int) -> tuple[RoundaboutEnv, EnvState]:
        env, params = make(cfg, max_vehicles=slots, episode_s=cap_s)
        batch = jax.tree.map(
            lambda *xs: np.stack(xs), *[env.schedule_from_numpy(s) for s in schedules]
        )
        policy = constant_policy(env, params, constant)
        keys = jnp.tile(jax.random.PRNGKey(0), (len(schedules), 1))
        return env, runs_until_left(
            env, params, batch, keys, lambda flag: policy,
            jnp.zeros(len(schedules), bool),
            desc=f"JAX, best constant, {len(schedules)} runs" if progress else None,
        )  # fmt: skip

    env, _ = make(cfg, max_vehicles=max_vehicles, episode_s=cap_s)
    (env, states), tried = redo_on_overflow(
        run_with, lambda run: int(np.sum(run[1].stats.overflow)),
        max_vehicles=max_vehicles, road=road_capacity(env.network, cfg),
        what="best constant (JAX)",
    )  # fmt: skip
    return env, states, tried
