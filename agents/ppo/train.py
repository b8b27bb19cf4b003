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
2. GAE over (T, B, M) with the slot masks of `agents.ppo.losses`;
3. `epochs` passes of `minibatches` Adam steps on the masked PPO loss. A
   minibatch is a set of whole env steps (all M slots of a roundabout at one
   time, so the centralised input sees the same roundabout it saw in the
   rollout); non-agent slots are masked out of the loss;
4. with a ``conflict_constraint``, one step of each penetration group's
   conflict price toward its limit (`agents.ppo.constraint`).

The roundabout batch is split over the local devices (`NamedSharding` over a
1-D mesh named "batch"); with one device this is a no-op. Running
`update_chunk` chunks one after the other gives bit-identical results to
`train` at XLA's default optimisation: both scan the same update. (With
``JAX_DISABLE_MOST_OPTIMIZATIONS=1`` the two programs may round a gradient
in the last bit differently.)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from agents.common import networks
from agents.common.batch import BatchTrainer, agent_outcomes
from agents.common.config import PPOConfig
from agents.common.constraint_config import ConflictConstraintConfig
from agents.common.losses import masked_mean
from agents.ppo import constraint
from agents.ppo.constraint import ConflictLedger
from agents.ppo.losses import Batch, compute_gae, ppo_loss
from jaxround.core.state import EnvState

#: Per-update metrics, in the order of the CSV columns.
METRICS = (
    "reward_per_agent_step",
    "episode_return",
    "av_crossing_time_s",
    "finished_agents",
    "agent_steps",
    "conflicts_per_1000",
    "conflict_price",
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
        trip_noise: float (B, M) each slot's exploration noise, drawn when a
            vehicle takes the slot and held for its trip (`trip_noise`).
        ledger: the conflict price of each penetration group and the running
            conflict rate (`agents.ppo.constraint`; the price stays the
            config's without a ``conflict_constraint``).
    """

    params: Any
    opt_state: Any
    env_state: EnvState
    obs: jax.Array
    episode_return: jax.Array
    key: jax.Array
    update: jax.Array
    trip_noise: jax.Array
    ledger: ConflictLedger


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
    conflicts: jax.Array  # float (B,) conflicts in the step, all vehicles
    arrived: jax.Array  # float (B,) vehicles that left in the step


class Trainer(BatchTrainer):
    """PPO on one config: environment, network, optimiser and the pure update.

    Static settings live here (the roundabout batch and the loop of updates
    in `agents.common.batch.BatchTrainer`); everything that changes lives in
    `RunnerState`.
    """

    config: PPOConfig

    def __init__(self, config: PPOConfig) -> None:
        super().__init__(config)
        self.network = networks.ActorCritic(
            hidden=tuple(config.hidden),
            activation=config.activation,
            centralised=config.centralised,
            lane_choices=self.lane_choices,
        )
        n_adam_steps = config.num_updates * config.epochs * config.minibatches
        self.lr_schedule = optax.linear_schedule(
            config.lr, 0.0 if config.anneal_lr else config.lr, n_adam_steps
        )
        self.optimizer = optax.chain(
            optax.clip_by_global_norm(config.max_grad_norm),
            optax.adam(self.lr_schedule, eps=1e-5),
        )
        self.n_groups = len(config.penetrations)
        self.groups = constraint.groups(config.n_envs, self.n_groups)

    # ------------------------------------------------------------------ pieces

    def apply(self, params: Any, obs: jax.Array, active: jax.Array):
        return self.network.apply(params, obs, active)

    def init(self, key: jax.Array) -> RunnerState:
        """Fresh parameters and B freshly reset roundabouts."""
        start = self.fresh_start(key)
        noise = jax.random.normal(jax.random.fold_in(key, 1), start["obs"].shape[:-1])
        ledger = self.start_ledger(jax.random.fold_in(key, 2))
        return RunnerState(**start, trip_noise=self.shard(noise), ledger=ledger)

    def start_ledger(self, key: jax.Array) -> ConflictLedger:
        """The conflict prices and limits before the first update; with a
        constraint and no limit given, the limit is the AVs' vType's own rate,
        measured on `measure_episodes` episodes of the batch (`key`)."""
        settings = self.config.conflict_constraint
        price = self.scenario.agent.conflict_weight
        if settings is None:  # a fixed price; the rate is still followed
            return constraint.fixed_ledger(price, self.n_groups)
        measured = None
        if not settings.limit:
            b, m = self.config.n_envs, self.env.max_vehicles
            measured = constraint.measure_uncontrolled(
                self.env_step, self.reset_envs, key,
                n_steps=settings.measure_episodes * self.env.episode_steps,
                group=self.groups, n_groups=self.n_groups, action_shape=(b, m, 2),
            )  # fmt: skip
        return constraint.start_ledger(
            settings, start_price=price, n_groups=self.n_groups, measured=measured
        )

    def env_params_now(self, runner: RunnerState) -> Any:
        """The batch's `EnvParams` with the runner's conflict prices (the
        constant ones without a constraint)."""
        if self.config.conflict_constraint is None:
            return self.env_params
        return constraint.with_prices(self.env_params, runner.ledger.price, self.groups)

    def rollout(self, runner: RunnerState) -> tuple[RunnerState, Transition]:
        """`n_steps` env steps of all roundabouts; Transition leaves are (T, B, ...)."""
        b, dt = self.config.n_envs, self.env.dt
        env_params = self.env_params_now(runner)

        def one_step(carry, _):
            env_state, obs, ep_return, trip_noise, prev_vid, key = carry
            key, k_act, k_env, k_trip = jax.random.split(key, 4)
            active = env_state.active  # (B, M)
            out = self.apply(runner.params, obs, active)
            if self.config.trip_noise:  # a new vehicle in a slot draws anew
                fresh = jax.random.normal(k_trip, trip_noise.shape)
                trip_noise = jnp.where(env_state.vid != prev_vid, fresh, trip_noise)
                accel, change, log_prob = networks.sample(out, k_act, trip_noise)
            else:
                accel, change, log_prob = networks.sample(out, k_act)
            action = networks.env_action(accel, change)  # (B, M, 2)
            obs_next, state_next, reward, done, info = self.env_step(
                jax.random.split(k_env, b), env_state, action, env_params
            )
            o = agent_outcomes(env_state, state_next, reward, done, info, ep_return, dt)
            step = Transition(
                obs=obs,
                active=active,
                agent=o.agent,
                accel=accel,
                change=change,
                log_prob=log_prob,
                value=out.value,
                reward=o.reward,
                terminated=o.terminated,
                truncated=o.truncated,
                finished_return=o.finished_return,
                crossing_s=o.crossing_s,
                conflicts=info["conflicts"].astype(jnp.float32),
                arrived=info["arrived"].astype(jnp.float32),
            )
            carry = self.shard((state_next, obs_next, o.episode_return, trip_noise))
            return (*carry, env_state.vid, key), step

        key, k_roll = jax.random.split(runner.key)
        carry = (
            runner.env_state, runner.obs, runner.episode_return, runner.trip_noise,
            runner.env_state.vid, k_roll,
        )  # fmt: skip
        (env_state, obs, ep_return, trip_noise, _, _), traj = jax.lax.scan(
            one_step, carry, None, length=self.config.n_steps
        )
        runner = runner._replace(
            env_state=env_state, obs=obs, episode_return=ep_return, key=key,
            trip_noise=trip_noise,
        )  # fmt: skip
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

    def follow_conflicts(
        self, ledger: ConflictLedger, traj: Transition
    ) -> ConflictLedger:
        """The ledger after a rollout: running counts, and with a constraint
        the prices' multiplier step (`agents.ppo.constraint.update_ledger`)."""
        conflicts = constraint.group_totals(traj.conflicts, self.groups, self.n_groups)
        arrivals = constraint.group_totals(traj.arrived, self.groups, self.n_groups)
        settings = self.config.conflict_constraint
        if settings is not None:
            return constraint.update_ledger(ledger, settings, conflicts, arrivals)
        return constraint.tally(
            ledger, conflicts, arrivals, ConflictConstraintConfig().smoothing
        )

    def update(self, runner: RunnerState) -> tuple[RunnerState, dict[str, jax.Array]]:
        """One PPO update: rollout, GAE, optimisation. Pure."""
        n_lr_steps = runner.update * self.config.epochs * self.config.minibatches
        runner, traj = self.rollout(runner)
        runner, losses = self.learn(runner, traj)
        runner = runner._replace(ledger=self.follow_conflicts(runner.ledger, traj))
        n_conflicts, n_arrived = jnp.sum(traj.conflicts), jnp.sum(traj.arrived)
        n_finished = jnp.sum(traj.terminated & traj.agent)
        per_finished = jnp.where(n_finished > 0, 1.0 / n_finished, jnp.nan)
        metrics = {
            "reward_per_agent_step": masked_mean(traj.reward, traj.agent),
            "episode_return": jnp.sum(traj.finished_return) * per_finished,
            "av_crossing_time_s": jnp.sum(traj.crossing_s) * per_finished,
            "finished_agents": n_finished.astype(jnp.float32),
            "agent_steps": jnp.sum(traj.agent).astype(jnp.float32),
            "conflicts_per_1000": jnp.where(
                n_arrived > 0, 1000.0 * n_conflicts / n_arrived, jnp.nan
            ),
            "conflict_price": jnp.mean(runner.ledger.price),
            **losses,
            "learning_rate": self.lr_schedule(n_lr_steps),
        }
        return runner._replace(update=runner.update + 1), metrics


def make_train(
    config: PPOConfig,
) -> Callable[[jax.Array], tuple[RunnerState, dict[str, jax.Array]]]:
    """PureJaxRL's entry point: ``train(key) -> (runner_state, metrics)``.

    Metrics are stacked over updates, shape (num_updates,) each (see `METRICS`).
    """
    return Trainer(config).train


__all__ = ["METRICS", "RunnerState", "Trainer", "Transition", "make_train"]
