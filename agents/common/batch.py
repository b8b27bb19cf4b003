"""What every trainer shares: B roundabouts stepped side by side, the AVs'
per-step bookkeeping, and the loop of updates.

    class MyTrainer(BatchTrainer):    # agents.ppo.Trainer, agents.apg.APGTrainer
        def init(self, key) -> runner: ...
        def update(self, runner) -> (runner, metrics): ...

    runner, metrics = jax.jit(MyTrainer(cfg).train)(key)

`BatchTrainer` builds the environment of a config's training scenario, B
copies of its `EnvParams` (roundabout i drawing its AVs at penetration
``penetrations[i % len]``), splits the batch over the local devices
(`NamedSharding` on a 1-D mesh named "batch"), and steps it with a reset
only in the steps where an episode ends. `agent_outcomes` turns one step
into what the AVs got (reward, termination, return and crossing time of an
AV that left), the same for every trainer.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from agents.common import networks
from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs.roundabout import make
from jaxround.envs.wrappers import auto_reset
from jaxround.scenario.config import ConfigError

#: Name of the mesh axis the roundabout batch is split over.
BATCH_AXIS = "batch"


def batch_sharding(n_envs: int) -> NamedSharding:
    """Sharding of arrays whose first axis is the roundabout batch, over every
    device: the local ones, and those of the other processes after
    `jax.distributed.initialize` (`agents.run.distributed`).

    Raises:
        ConfigError: `n_envs` is not a multiple of the number of devices.
    """
    devices = jax.devices()
    if n_envs % len(devices):
        raise ConfigError(
            f"n_envs: {n_envs} roundabouts cannot be split evenly over "
            f"{len(devices)} devices"
        )
    mesh = Mesh(np.asarray(devices), (BATCH_AXIS,))
    return NamedSharding(mesh, PartitionSpec(BATCH_AXIS))


def slot_left(before: EnvState, after: EnvState, done: jax.Array) -> jax.Array:
    """bool (..., M): the slot's vehicle left during the step (not at an episode end).

    A vehicle left when its slot is empty afterwards or holds another vehicle.
    Where the episode ended the state after is a fresh episode's and says
    nothing; those samples are truncated instead.
    """
    gone = ~after.active | (after.vid != before.vid)
    return before.active & gone & ~done[..., None]


class AgentStep(NamedTuple):
    """What the AVs of B roundabouts got in one env step. Arrays (B, M)."""

    agent: jax.Array  # bool slot held an active AV at the start of the step
    reward: jax.Array  # float reward, unscaled (zero for non-agents)
    terminated: jax.Array  # bool the slot's vehicle left the network
    truncated: jax.Array  # bool the episode ended with this step
    finished_return: jax.Array  # float return of an agent that left (else 0)
    crossing_s: jax.Array  # float crossing time of an agent that left (else 0)
    episode_return: jax.Array  # float each slot's running return after the step


def agent_outcomes(
    before: EnvState,
    after: EnvState,
    reward: jax.Array,
    done: jax.Array,
    info: dict[str, Any],
    episode_return: jax.Array,
    dt: float,
) -> AgentStep:
    """The AVs' side of one step of B roundabouts.

    Args:
        before: the states the step started from, leaves (B, ...).
        after: the states after it (reset where done).
        reward: float (B, M) the environment's reward.
        done: bool (B,) the episode ended with this step.
        info: the step's info (``info["terminated"]`` (B, M), ``["truncated"]``).
        episode_return: float (B, M) each slot's return before the step.
        dt: step length, s.

    Returns:
        The `AgentStep`; its `episode_return` restarts at 0 where the slot's
        vehicle left or the episode ended.
    """
    b = done.shape[0]
    active = before.active  # (B, M)
    agent = active & before.is_av
    terminated = info["terminated"] | slot_left(before, after, done)
    terminated = terminated & active
    truncated = jnp.broadcast_to(jnp.reshape(info["truncated"], (b, -1)), active.shape)
    reward = jnp.where(agent, reward, 0.0)
    episode_return = episode_return + reward
    finished = terminated & agent
    vid = jnp.clip(before.vid, 0, None)
    depart = jnp.take_along_axis(before.schedule.depart_s, vid, axis=1)
    t_arrival = (before.step + 1).astype(jnp.float32) * dt  # (B,)
    return AgentStep(
        agent=agent,
        reward=reward,
        terminated=terminated,
        truncated=truncated,
        finished_return=jnp.where(finished, episode_return, 0.0),
        crossing_s=jnp.where(finished, t_arrival[:, None] - depart, 0.0),
        episode_return=jnp.where(terminated | truncated, 0.0, episode_return),
    )


class BatchTrainer:
    """B roundabouts of a config's training scenario, and the loop of updates.

    Subclasses set `config` fields' meaning and give `init(key) -> runner` and
    `update(runner) -> (runner, metrics)`; the runner is a pytree with an
    ``update`` counter. Static settings live here; everything that changes in
    the runner.

    Attributes:
        config: the trainer's config (`agents.common.config.TrainerConfig`).
        scenario: its training scenario.
        env: the environment; `env_params` its B parameter sets, leaves (B, ...).
        obs_size: numbers per observation row, D.
        lane_choices: the network's lane choices C (`networks.lane_choices_for`).
        sharding: the batch's sharding over the local devices.
    """

    def __init__(self, config: Any) -> None:
        config.validate()
        self.config = config
        self.sharding = batch_sharding(config.n_envs)
        self.scenario = config.training_scenario()
        #: lane choices of the network: 3 on two-lane roads (none, left, right)
        self.lane_choices = networks.lane_choices_for(
            not self.scenario.network.single_lane
        )
        self.env, params = make(
            self.scenario, max_vehicles=config.max_vehicles, episode_s=config.episode_s
        )
        b = config.n_envs
        shares = [config.penetrations[i % len(config.penetrations)] for i in range(b)]
        self.env_params: EnvParams = jax.tree.map(
            lambda x: jnp.broadcast_to(x, (b, *jnp.shape(x))), params
        ).with_penetration(shares)
        obs, _ = jax.eval_shape(self.env.reset, jax.random.PRNGKey(0), params)
        self.obs_size = int(obs.shape[-1])
        self._env_step = jax.vmap(self.env.step_env)
        self._env_reset = jax.vmap(self.env.reset)

    # ------------------------------------------------------------------ pieces

    def shard(self, tree: Any) -> Any:
        """Constrain every leaf's first axis (the roundabouts) to the batch sharding."""
        return jax.tree.map(
            lambda x: jax.lax.with_sharding_constraint(x, self.sharding), tree
        )

    def reset_envs(self, key: jax.Array) -> tuple[jax.Array, EnvState]:
        """B fresh episodes: (obs float (B, M, D), states), sharded."""
        keys = jax.random.split(key, self.config.n_envs)
        return self.shard(self._env_reset(keys, self.env_params))

    def env_step(
        self,
        keys: jax.Array,
        state: EnvState,
        action: jax.Array,
        params: EnvParams | None = None,
    ) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, dict[str, Any]]:
        """`jax.vmap(env.step)` over the B roundabouts, resetting only when needed.

        The environment's own automatic reset (`jaxround.envs.wrappers.auto_reset`:
        `step_env`, then `reset` with the same key where done) applied to the
        whole batch, so that the reset is computed only in steps where some
        episode ended: the B episodes start together and have one length, so
        that is one step in `episode_steps`.

        Args:
            keys: PRNG keys (B, 2), one per roundabout.
            state: the B states, leaves (B, ...).
            action: float (B, M, 2) per slot.
            params: the B parameter sets (leaves (B, ...)); None: `env_params`.

        Returns:
            (obs float (B, M, D), states, reward float (B, M), done bool (B,),
            info), as `jax.vmap(env.step)`.
        """
        params = self.env_params if params is None else params
        obs, state, reward, done, info = self._env_step(keys, state, action, params)
        obs, state = auto_reset(
            done, (obs, state), lambda: self._env_reset(keys, params)
        )
        return obs, state, reward, done, info

    def fresh_start(self, key: jax.Array) -> dict[str, Any]:
        """The fields every runner starts from: fresh parameters of the
        subclass's `network`, its `optimizer`'s state, B freshly reset
        roundabouts (obs, env_state), zero returns, a key, update 0."""
        k_net, k_env, k_run = jax.random.split(key, 3)
        params = networks.init_params(
            self.network, k_net, self.obs_size, self.env.max_vehicles
        )
        obs, env_state = self.reset_envs(k_env)
        return {
            "params": params,
            "opt_state": self.optimizer.init(params),
            "env_state": env_state,
            "obs": obs,
            "episode_return": self.shard(jnp.zeros(obs.shape[:-1], jnp.float32)),
            "key": k_run,
            "update": jnp.int32(0),
        }

    # ------------------------------------------------------------------ runs

    def init(self, key: jax.Array) -> Any:  # pragma: no cover - abstract
        raise NotImplementedError

    def update(self, runner: Any) -> tuple[Any, dict[str, jax.Array]]:
        raise NotImplementedError  # pragma: no cover - abstract

    def run_updates(self, runner: Any, n: int) -> tuple[Any, dict[str, jax.Array]]:
        """`n` updates by `lax.scan`; metrics (n,) each. Pure."""
        return jax.lax.scan(lambda r, _: self.update(r), runner, None, length=n)

    def train(self, key: jax.Array) -> tuple[Any, dict[str, jax.Array]]:
        """The whole run: `num_updates` updates from `init(key)`. Pure (vmap: seeds)."""
        return self.run_updates(self.init(key), self.config.num_updates)

    def update_chunk(self, n: int) -> Callable[[Any], tuple[Any, dict[str, jax.Array]]]:
        """A jitted function doing `n` updates (chunks chain bit-identically to
        `train`)."""
        return jax.jit(lambda runner: self.run_updates(runner, n))


__all__ = [
    "BATCH_AXIS",
    "AgentStep",
    "BatchTrainer",
    "agent_outcomes",
    "batch_sharding",
    "slot_left",
]
