"""Analytic policy gradients (APG) on the roundabout, PureJaxRL style.

    train = make_train(cfg)                                  # cfg: APGConfig
    runner, metrics = jax.jit(train)(key)                    # one seed
    runner, metrics = jax.jit(jax.vmap(train))(keys)         # several seeds

    trainer = APGTrainer(cfg)                                # the same, in chunks
    runner = jax.jit(trainer.init)(key)
    runner, metrics = trainer.update_chunk(10)(runner)       # jitted, 10 updates

Brax's APG (and SHAC's actor without its critic): the policy is
deterministic, the mean command of the shared actor clipped to the AV's
bounds (`agents.common.networks.deterministic_action`, exactly what
`agents.common.export` writes and the SUMO controller runs; the critic and the
log-std are carried along unused), and its gradient is the derivative of
the AVs' reward through the environment itself: `env.step_env` is a pure
JAX function of the action. An update

1. rolls the B roundabouts `horizon` steps on from where the previous
   update left them (`lax.scan` over `jax.checkpoint`ed steps, resetting
   where an episode ends), every AV acting on its own observation row;
2. takes loss = minus the mean reward per AV step of that window (HV and
   empty slots masked out by ``info["agent"]``);
3. differentiates it with respect to the network through all H steps: the
   AVs' speeds and positions, every vehicle's IDM response to them, the
   emissions, the next observations;
4. clips the gradient's global norm and takes one Adam step.

The dynamics trained on are relaxed: `relax_temperature` is written into
every roundabout's `EnvParams`, above 0 the hard decisions (yielding at the
entry, halting, arrival) are smooth so that more of the gradient gets
through (`jaxround.core.relax`). A trained policy is evaluated on the exact,
SUMO-parity dynamics (temperature 0: `agents.common.evaluation`).

Why long rollouts do not give NaN or exploding gradients here:

- **Short, truncated windows.** The state carried from one window to the
  next is `stop_gradient`ed: a gradient is a product of at most `horizon`
  step Jacobians, never of the 720 steps of an episode, over which car
  following (a chain of feedbacks) makes such products explode or vanish.
  The price is a bias: effects later than H steps are not seen.
- **Saturating rules.** The command bounds, the AV's IDM cap and the exact
  decisions have zero derivative where they bind, so gradients die there
  rather than blow up; a positive temperature lets some through, smoothly.
- **Clipping.** The global norm of every gradient is clipped to
  `max_grad_norm` before Adam, whatever the window did.
- **A NaN guard.** A non-finite loss or gradient (for example a zero
  cotangent times an infinite derivative in a `jnp.where`'s discarded
  branch) skips the Adam step: parameters and optimiser state stay as they
  were, the environments go on, and `skipped_updates` counts it.
- **Checkpointed scan.** `jax.checkpoint` on each step keeps only the
  carried state per step for the backward pass and recomputes the step's
  (M, M) intermediates, so memory grows by one state per step of the
  window: longer windows cost time, not memory.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from agents.common import networks
from agents.common.batch import AgentStep, BatchTrainer, agent_outcomes
from agents.common.config import APGConfig
from agents.common.losses import masked_mean
from jaxround.core.state import EnvState

#: Per-update metrics, in the order of the CSV columns.
METRICS = (
    "reward_per_agent_step",
    "episode_return",
    "av_crossing_time_s",
    "finished_agents",
    "agent_steps",
    "loss",
    "grad_norm",
    "mean_command",
    "skipped_updates",
    "learning_rate",
)


class RunnerState(NamedTuple):
    """Everything a run carries from one update to the next (a checkpoint).

    Attributes:
        params: network parameters (`agents.common.networks.ActorCritic`).
        opt_state: Adam state (holds the learning-rate schedule's count).
        env_state: `EnvState` of the B roundabouts, leaves (B, ...).
        obs: float (B, M, D) their current observations.
        episode_return: float (B, M) undiscounted return of each slot's agent
            so far.
        key: PRNG key.
        update: int32, updates done (skipped ones included).
        skipped: int32, updates whose loss or gradient was not finite.
    """

    params: Any
    opt_state: Any
    env_state: EnvState
    obs: jax.Array
    episode_return: jax.Array
    key: jax.Array
    update: jax.Array
    skipped: jax.Array


class Window(NamedTuple):
    """Where a window of H steps ends and what happened in it."""

    env_state: EnvState  # leaves (B, ...) after the window
    obs: jax.Array  # float (B, M, D)
    episode_return: jax.Array  # float (B, M)
    steps: AgentStep  # leaves (H, B, M)
    command: jax.Array  # float (H, B, M) the commanded acceleration, m/s^2


class APGTrainer(BatchTrainer):
    """APG on one config: environment batch, network, optimiser, the pure update.

    Static settings live here (the roundabout batch and the loop of updates
    in `agents.common.batch.BatchTrainer`); everything that changes in `RunnerState`.
    """

    config: APGConfig

    def __init__(self, config: APGConfig) -> None:
        super().__init__(config)
        b = config.n_envs
        self.env_params = self.env_params.replace(
            relax_temperature=jnp.full((b,), config.relax_temperature, jnp.float32)
        )
        av = self.scenario.drivers.av
        self.accel_bounds = (-av.decel, av.accel)
        self.network = networks.ActorCritic(
            hidden=tuple(config.hidden),
            activation=config.activation,
            centralised=config.centralised,
            lane_choices=self.lane_choices,
        )
        self.lr_schedule = optax.linear_schedule(
            config.lr, 0.0 if config.anneal_lr else config.lr, config.num_updates
        )
        self.optimizer = optax.chain(
            optax.clip_by_global_norm(config.max_grad_norm),
            optax.adam(self.lr_schedule),
        )

    # ------------------------------------------------------------------ pieces

    def act(self, params: Any, obs: jax.Array, active: jax.Array) -> jax.Array:
        """The deterministic policy's env action, float (B, M, 2), differentiable
        in `params` where the command is inside its bounds.

        Args:
            params: network parameters.
            obs: float (B, M, D) observations.
            active: bool (B, M) occupied slots.
        """
        out = self.network.apply(params, obs, active)
        accel, change = networks.deterministic_action(
            out.accel_mean, out.lane_logits, self.accel_bounds
        )
        return networks.env_action(accel, change.astype(jnp.int32))

    def init(self, key: jax.Array) -> RunnerState:
        """Fresh parameters and B freshly reset roundabouts."""
        return RunnerState(**self.fresh_start(key), skipped=jnp.int32(0))

    def window(
        self,
        params: Any,
        env_state: EnvState,
        obs: jax.Array,
        episode_return: jax.Array,
        key: jax.Array,
    ) -> Window:
        """`horizon` steps of the B roundabouts under the policy `params`.

        Differentiable in `params`; each step is `jax.checkpoint`ed.
        """
        b, dt = self.config.n_envs, self.env.dt

        @jax.checkpoint
        def one_step(carry, _):
            env_state, obs, ep_return, key = carry
            key, k_env = jax.random.split(key)
            action = self.act(params, obs, env_state.active)  # (B, M, 2)
            obs_next, state_next, reward, done, info = self.env_step(
                jax.random.split(k_env, b), env_state, action
            )
            o = agent_outcomes(env_state, state_next, reward, done, info, ep_return, dt)
            carry = self.shard((state_next, obs_next, o.episode_return))
            return (*carry, key), (o, action[..., 0])

        carry = (env_state, obs, episode_return, key)
        (env_state, obs, episode_return, _), (steps, command) = jax.lax.scan(
            one_step, carry, None, length=self.config.horizon
        )
        return Window(env_state, obs, episode_return, steps, command)

    def loss(
        self,
        params: Any,
        env_state: EnvState,
        obs: jax.Array,
        episode_return: jax.Array,
        key: jax.Array,
    ) -> tuple[jax.Array, Window]:
        """Minus the mean reward per AV step over a window, and the window.

        Returns:
            (float () loss, `Window`); 0 when the window held no AV.
        """
        win = self.window(params, env_state, obs, episode_return, key)
        n_agent_steps = jnp.sum(win.steps.agent)
        loss = -jnp.sum(win.steps.reward) / jnp.maximum(n_agent_steps, 1)
        return loss, win

    def gradient(self, runner: RunnerState) -> tuple[jax.Array, Any, Window]:
        """(loss, gradient w.r.t. the parameters, window) from the runner's
        state with the key of its next update. Pure."""
        _, k_win = jax.random.split(runner.key)
        grad_fn = jax.value_and_grad(self.loss, has_aux=True)
        (loss, win), grads = grad_fn(
            runner.params,
            runner.env_state,
            runner.obs,
            runner.episode_return,
            k_win,
        )
        return loss, grads, win

    def update(self, runner: RunnerState) -> tuple[RunnerState, dict[str, jax.Array]]:
        """One APG update: a differentiated window, one guarded Adam step. Pure."""
        key, _ = jax.random.split(runner.key)
        loss, grads, win = self.gradient(runner)
        win = jax.lax.stop_gradient(win)  # truncation: the next window starts here
        grad_norm = optax.tree.norm(grads)
        finite = jnp.isfinite(loss) & jnp.isfinite(grad_norm)
        updates, opt_state = self.optimizer.update(
            grads, runner.opt_state, runner.params
        )
        params = optax.apply_updates(runner.params, updates)

        def guard(new: Any, old: Any) -> Any:
            return jax.tree.map(lambda n, o: jnp.where(finite, n, o), new, old)

        applied = runner.update - runner.skipped  # Adam steps taken before this
        skipped = runner.skipped + (~finite).astype(jnp.int32)
        steps = win.steps
        n_finished = jnp.sum(steps.terminated & steps.agent)
        per_finished = jnp.where(n_finished > 0, 1.0 / n_finished, jnp.nan)
        metrics = {
            "reward_per_agent_step": masked_mean(steps.reward, steps.agent),
            "episode_return": jnp.sum(steps.finished_return) * per_finished,
            "av_crossing_time_s": jnp.sum(steps.crossing_s) * per_finished,
            "finished_agents": n_finished.astype(jnp.float32),
            "agent_steps": jnp.sum(steps.agent).astype(jnp.float32),
            "loss": loss,
            "grad_norm": grad_norm,
            "mean_command": masked_mean(win.command, steps.agent),
            "skipped_updates": skipped.astype(jnp.float32),
            "learning_rate": self.lr_schedule(applied),
        }
        runner = RunnerState(
            params=guard(params, runner.params),
            opt_state=guard(opt_state, runner.opt_state),
            env_state=win.env_state,
            obs=win.obs,
            episode_return=win.episode_return,
            key=key,
            update=runner.update + 1,
            skipped=skipped,
        )
        return runner, metrics


def make_train(
    config: APGConfig,
) -> Callable[[jax.Array], tuple[RunnerState, dict[str, jax.Array]]]:
    """PureJaxRL's entry point: ``train(key) -> (runner_state, metrics)``.

    Metrics are stacked over updates, shape (num_updates,) each (see `METRICS`).
    """
    return APGTrainer(config).train


__all__ = ["METRICS", "APGTrainer", "RunnerState", "Window", "make_train"]
