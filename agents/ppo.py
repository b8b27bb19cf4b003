"""PPO on the roundabout, PureJaxRL style: one pure `train(key)`.

    train = make_train(cfg)
    runner, metrics = jax.jit(train)(key)                    # one seed
    runner, metrics = jax.jit(jax.vmap(train))(keys)         # several seeds

    trainer = Trainer(cfg)                                   # the same, in chunks
    runner = jax.jit(trainer.init)(key)
    chunk = trainer.update_chunk(10)                         # jitted, 10 updates
    runner, metrics = chunk(runner)

Every AV of every roundabout acts with one shared `ActorCritic` on its own
observation row. An update is

1. a rollout: `lax.scan` over `n_steps` env steps of `n_envs` roundabouts
   (`jax.vmap(env.step)`, automatic reset), actions sampled for all M slots;
2. GAE over (T, B, M) with the slot masks of `agents.losses`;
3. `epochs` passes of `minibatches` Adam steps on the masked PPO loss. A
   minibatch is a set of whole env steps (all M slots of a roundabout at one
   time, so the centralised input sees the same roundabout it saw in the
   rollout); non-agent slots are masked out of the loss.

The roundabout batch is split over the local devices (`NamedSharding` over a
1-D mesh named "batch"); with one device this is a no-op. Running
`update_chunk` chunks one after the other gives bit-identical results to
`train`: both scan the same update.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from agents import networks
from agents.config import PPOConfig
from agents.losses import Batch, compute_gae, masked_mean, ppo_loss
from jaxround.config import ConfigError
from jaxround.env import make
from jaxround.state import EnvParams, EnvState

#: Name of the mesh axis the roundabout batch is split over.
BATCH_AXIS = "batch"
#: Per-update metrics, in the order of the CSV columns.
METRICS = (
    "reward_per_agent_step",
    "episode_return",
    "av_crossing_time_s",
    "finished_agents",
    "agent_steps",
    "policy_loss",
    "value_loss",
    "entropy",
    "approx_kl",
    "clip_frac",
    "learning_rate",
)


class RunnerState(NamedTuple):
    """Everything a run carries from one update to the next (a checkpoint).

    Attributes:
        params: network parameters.
        opt_state: Adam state (holds the learning-rate schedule's count).
        env_state: `EnvState` of the B roundabouts, leaves (B, ...).
        obs: float (B, M, D) their current observations.
        episode_return: float (B, M) undiscounted return of each slot's agent
            so far (unscaled rewards).
        key: PRNG key.
        update: int32, updates done.
    """

    params: Any
    opt_state: Any
    env_state: EnvState
    obs: jax.Array
    episode_return: jax.Array
    key: jax.Array
    update: jax.Array


class Transition(NamedTuple):
    """One env step of B roundabouts. Arrays (B, M) unless noted."""

    obs: jax.Array  # float (B, M, D) observation the action was taken on
    active: jax.Array  # bool slot holds a vehicle
    agent: jax.Array  # bool slot holds an active AV
    accel: jax.Array  # float acceleration command sampled
    change: jax.Array  # int32 lane choice sampled
    log_prob: jax.Array  # float log-probability of the action
    value: jax.Array  # float V(obs)
    reward: jax.Array  # float reward, unscaled (zero for non-agents)
    terminated: jax.Array  # bool the slot's vehicle left the network
    truncated: jax.Array  # bool the episode ended with this step
    finished_return: jax.Array  # float return of an agent that left (else 0)
    crossing_s: jax.Array  # float crossing time of an agent that left (else 0)


def batch_sharding(n_envs: int) -> NamedSharding:
    """Sharding of arrays whose first axis is the roundabout batch, over local devices.

    Raises:
        ConfigError: `n_envs` is not a multiple of the number of devices.
    """
    devices = jax.local_devices()
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


class Trainer:
    """PPO on one config: environment, network, optimiser and the pure update.

    Static settings live here; everything that changes lives in `RunnerState`.
    """

    def __init__(self, config: PPOConfig) -> None:
        config.validate()
        self.config = config
        self.sharding = batch_sharding(config.n_envs)
        self.scenario = config.training_scenario()
        self.env, params = make(
            self.scenario, max_vehicles=config.max_vehicles, episode_s=config.episode_s
        )
        b = config.n_envs
        shares = [config.penetrations[i % len(config.penetrations)] for i in range(b)]
        self.env_params: EnvParams = jax.tree.map(
            lambda x: jnp.broadcast_to(x, (b, *jnp.shape(x))), params
        ).replace(penetration=jnp.asarray(shares, jnp.float32))
        obs, _ = jax.eval_shape(self.env.reset, jax.random.PRNGKey(0), params)
        self.obs_size = int(obs.shape[-1])
        self.network = networks.ActorCritic(
            hidden=tuple(config.hidden),
            activation=config.activation,
            centralised=config.centralised,
        )
        n_adam_steps = config.num_updates * config.epochs * config.minibatches
        self.lr_schedule = optax.linear_schedule(
            config.lr, 0.0 if config.anneal_lr else config.lr, n_adam_steps
        )
        self.optimizer = optax.chain(
            optax.clip_by_global_norm(config.max_grad_norm),
            optax.adam(self.lr_schedule, eps=1e-5),
        )
        self._env_step = jax.vmap(self.env.step_env)
        self._env_reset = jax.vmap(self.env.reset)

    # ------------------------------------------------------------------ pieces

    def shard(self, tree: Any) -> Any:
        """Constrain every leaf's first axis (the roundabouts) to the batch sharding."""
        return jax.tree.map(
            lambda x: jax.lax.with_sharding_constraint(x, self.sharding), tree
        )

    def env_step(
        self, keys: jax.Array, state: EnvState, action: jax.Array
    ) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, dict[str, Any]]:
        """`jax.vmap(env.step)` over the B roundabouts, resetting only when needed.

        The same as the environment's own automatic reset (`step_env`, then
        `reset` with the same key where done), but the reset is computed only
        in steps where some episode ended: the B episodes start together and
        have one length, so that is one step in `episode_steps`. (Under an
        outer `vmap`, over seeds, `lax.cond` computes both branches; the
        result is the same.)
        """
        obs, new_state, reward, done, info = self._env_step(
            keys, state, action, self.env_params
        )

        def with_reset(carry: tuple[jax.Array, EnvState]):
            fresh = self._env_reset(keys, self.env_params)

            def pick(reset: jax.Array, stepped: jax.Array) -> jax.Array:
                where = jnp.reshape(done, done.shape + (1,) * (stepped.ndim - 1))
                return jnp.where(where, reset, stepped)

            return jax.tree.map(pick, fresh, carry)

        obs, state = jax.lax.cond(
            jnp.any(done), with_reset, lambda carry: carry, (obs, new_state)
        )
        return obs, state, reward, done, info

    def apply(self, params: Any, obs: jax.Array, active: jax.Array):
        return self.network.apply(params, obs, active)

    def init(self, key: jax.Array) -> RunnerState:
        """Fresh parameters and B freshly reset roundabouts."""
        cfg = self.config
        k_net, k_env, k_run = jax.random.split(key, 3)
        params = networks.init_params(
            self.network, k_net, self.obs_size, cfg.max_vehicles
        )
        keys = jax.random.split(k_env, cfg.n_envs)
        obs, env_state = self.shard(self._env_reset(keys, self.env_params))
        return RunnerState(
            params=params,
            opt_state=self.optimizer.init(params),
            env_state=env_state,
            obs=obs,
            episode_return=self.shard(jnp.zeros(obs.shape[:-1], jnp.float32)),
            key=k_run,
            update=jnp.int32(0),
        )

    def rollout(self, runner: RunnerState) -> tuple[RunnerState, Transition]:
        """`n_steps` env steps of all roundabouts; Transition leaves are (T, B, ...)."""
        b, dt = self.config.n_envs, self.env.dt

        def one_step(carry, _):
            env_state, obs, ep_return, key = carry
            key, k_act, k_env = jax.random.split(key, 3)
            active = env_state.active  # (B, M)
            agent = active & env_state.is_av
            out = self.apply(runner.params, obs, active)
            accel, change, log_prob = networks.sample(out, k_act)
            action = networks.env_action(accel, change)  # (B, M, 2)
            obs_next, state_next, reward, done, info = self.env_step(
                jax.random.split(k_env, b), env_state, action
            )
            terminated = info["terminated"] | slot_left(env_state, state_next, done)
            terminated = terminated & active
            truncated = jnp.broadcast_to(
                jnp.reshape(info["truncated"], (b, -1)), active.shape
            )
            reward = jnp.where(agent, reward, 0.0)
            ep_return = ep_return + reward
            finished = terminated & agent
            vid = jnp.clip(env_state.vid, 0, None)
            depart = jnp.take_along_axis(env_state.schedule.depart_s, vid, axis=1)
            t_arrival = (env_state.step + 1).astype(jnp.float32) * dt  # (B,)
            step = Transition(
                obs=obs,
                active=active,
                agent=agent,
                accel=accel,
                change=change,
                log_prob=log_prob,
                value=out.value,
                reward=reward,
                terminated=terminated,
                truncated=truncated,
                finished_return=jnp.where(finished, ep_return, 0.0),
                crossing_s=jnp.where(finished, t_arrival[:, None] - depart, 0.0),
            )
            ep_return = jnp.where(terminated | truncated, 0.0, ep_return)
            carry = self.shard((state_next, obs_next, ep_return))
            return (*carry, key), step

        key, k_roll = jax.random.split(runner.key)
        carry = (runner.env_state, runner.obs, runner.episode_return, k_roll)
        (env_state, obs, ep_return, _), traj = jax.lax.scan(
            one_step, carry, None, length=self.config.n_steps
        )
        runner = runner._replace(
            env_state=env_state, obs=obs, episode_return=ep_return, key=key
        )
        return runner, traj

    def learn(
        self, runner: RunnerState, traj: Transition
    ) -> tuple[RunnerState, dict[str, jax.Array]]:
        """GAE, then `epochs` x `minibatches` Adam steps; returns the loss metrics."""
        cfg = self.config
        last = runner.env_state
        last_value = self.apply(runner.params, runner.obs, last.active).value
        adv, target = compute_gae(
            traj.reward * cfg.reward_scale,
            traj.value,
            traj.agent,
            traj.terminated,
            traj.truncated,
            last_value,
            last.active & last.is_av,
            cfg.gamma,
            cfg.gae_lambda,
        )
        batch = Batch(
            traj.obs, traj.active, traj.agent, traj.accel, traj.change,
            traj.log_prob, traj.value, adv, target,
        )  # fmt: skip
        n = cfg.env_steps_per_update
        batch = jax.tree.map(lambda x: x.reshape(n, *x.shape[2:]), batch)
        grad_fn = jax.grad(ppo_loss, has_aux=True)

        def minibatch_step(carry, mb: Batch):
            params, opt_state = carry
            grads, aux = grad_fn(
                params, self.apply, mb, cfg.clip_eps, cfg.vf_coef, cfg.ent_coef
            )
            updates, opt_state = self.optimizer.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), aux

        def epoch(carry, key):
            perm = jax.random.permutation(key, n)
            shuffled = jax.tree.map(
                lambda x: x[perm].reshape(cfg.minibatches, -1, *x.shape[1:]), batch
            )
            return jax.lax.scan(minibatch_step, carry, shuffled)

        key, k_epochs = jax.random.split(runner.key)
        (params, opt_state), aux = jax.lax.scan(
            epoch,
            (runner.params, runner.opt_state),
            jax.random.split(k_epochs, cfg.epochs),
        )
        runner = runner._replace(params=params, opt_state=opt_state, key=key)
        return runner, jax.tree.map(jnp.mean, aux)

    def update(self, runner: RunnerState) -> tuple[RunnerState, dict[str, jax.Array]]:
        """One PPO update: rollout, GAE, optimisation. Pure."""
        n_lr_steps = runner.update * self.config.epochs * self.config.minibatches
        runner, traj = self.rollout(runner)
        runner, losses = self.learn(runner, traj)
        n_finished = jnp.sum(traj.terminated & traj.agent)
        per_finished = jnp.where(n_finished > 0, 1.0 / n_finished, jnp.nan)
        metrics = {
            "reward_per_agent_step": masked_mean(traj.reward, traj.agent),
            "episode_return": jnp.sum(traj.finished_return) * per_finished,
            "av_crossing_time_s": jnp.sum(traj.crossing_s) * per_finished,
            "finished_agents": n_finished.astype(jnp.float32),
            "agent_steps": jnp.sum(traj.agent).astype(jnp.float32),
            **losses,
            "learning_rate": self.lr_schedule(n_lr_steps),
        }
        return runner._replace(update=runner.update + 1), metrics

    # ------------------------------------------------------------------ runs

    def run_updates(
        self, runner: RunnerState, n: int
    ) -> tuple[RunnerState, dict[str, jax.Array]]:
        """`n` updates by `lax.scan`; metrics (n,) each. Pure."""
        return jax.lax.scan(lambda r, _: self.update(r), runner, None, length=n)

    def train(self, key: jax.Array) -> tuple[RunnerState, dict[str, jax.Array]]:
        """The whole run: `num_updates` updates from `init(key)`. Pure (vmap: seeds)."""
        return self.run_updates(self.init(key), self.config.num_updates)

    def update_chunk(
        self, n: int
    ) -> Callable[[RunnerState], tuple[RunnerState, dict[str, jax.Array]]]:
        """A jitted function doing `n` updates (chunks chain bit-identically to
        `train`)."""
        return jax.jit(lambda runner: self.run_updates(runner, n))


def make_train(
    config: PPOConfig,
) -> Callable[[jax.Array], tuple[RunnerState, dict[str, jax.Array]]]:
    """PureJaxRL's entry point: ``train(key) -> (runner_state, metrics)``.

    Metrics are stacked over updates, shape (num_updates,) each (see `METRICS`).
    """
    return Trainer(config).train


__all__ = [
    "BATCH_AXIS",
    "METRICS",
    "RunnerState",
    "Trainer",
    "Transition",
    "batch_sharding",
    "make_train",
    "slot_left",
]
