"""Fit human-driver parameters to a traffic survey, by gradients or black box.

The survey (`jaxround.analysis.survey`: per leg and 10-minute slot, mean and largest
queue, upstream and downstream flow) of the targets is reproduced on the same
schedules (the targets file names their seeds) in the JAX environment. The
loss is the mean squared error of the queue tables, each scaled by its
target's mean; flows are reported but carry no gradient (insertion is exact).

- `fit_gradient`: Adam on log-ratios to the scenario's values, several random
  starts in one vmapped batch, through the relaxed dynamics
  (``relax_temperature``), the gradient clipped by global norm.
- `fit_black_box`: the cross-entropy method on the same log-ratios, each
  generation one vmapped batch, for the same budget of simulated seconds.

Both report the loss of their best candidate under the exact dynamics.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from tqdm.auto import tqdm

from jaxround.analysis.survey import (
    CALIBRATABLE,
    Survey,
    measured_rollout,
    slot_queues,
    survey_steps,
)
from jaxround.core.params import EnvParams
from jaxround.core.state import Schedule
from jaxround.envs.roundabout import RoundaboutEnv
from jaxround.scenario.config import ConfigError
from jaxround.scenario.schedule import make_schedule

#: The fitted tables (the flows carry no gradient).
FITTED = ("queue_mean_veh", "queue_max_veh")
#: Candidates stay within these factors of the scenario's values.
BOUNDS = (0.25, 4.0)


def table_loss(sims: dict[str, Any], targets: dict[str, Any]) -> jax.Array:
    """The survey loss: the mean squared error of each FITTED table (S, G),
    scaled by its target's mean (at least 0.1 veh), averaged over the tables."""
    err = 0.0
    for name in FITTED:
        target = jnp.asarray(targets[name])
        scale = jnp.maximum(jnp.mean(target), 0.1)
        err = err + jnp.mean(((jnp.asarray(sims[name]) - target) / scale) ** 2)
    return err / len(FITTED)


def survey_loss(sim: Survey, target: Survey) -> float:
    """`table_loss` of two surveys (a SUMO re-run against the targets, say)."""
    tables = lambda survey: {n: getattr(survey, n) for n in FITTED}  # noqa: E731
    return float(table_loss(tables(sim), tables(target)))


def parse_param_names(text: str) -> tuple[str, ...]:
    """ "accel,tau" -> ("accel", "tau"), with a clear error for unknown names."""
    names = tuple(x.strip() for x in text.split(",") if x.strip())
    unknown = [n for n in names if n not in CALIBRATABLE]
    if not names or unknown:
        raise ConfigError(
            f"--params: unknown {unknown or 'empty list'}; choose from "
            + ",".join(CALIBRATABLE)
        )
    if len(set(names)) != len(names):
        raise ConfigError(f"--params: {text!r} names a parameter twice")
    return names


@dataclass
class Problem:
    """A calibration problem: the environment, what is fitted, the targets.

    Attributes:
        names: the fitted EnvParams fields, (P,).
        reference: float (P,) the scenario's values (log-ratio 0).
        schedules: the targets' schedules stacked, leaves (B, N).
        targets: name -> float (S, G) target tables.
        n_steps: steps of one run (S slots).
    """

    env: RoundaboutEnv
    params: EnvParams
    names: tuple[str, ...]
    reference: np.ndarray
    schedules: Schedule
    targets: dict[str, jax.Array]
    n_steps: int
    n_slots: int
    n_runs: int
    survey: Survey

    @property
    def sim_seconds_per_candidate(self) -> float:
        return self.n_runs * self.n_steps * self.env.dt

    def with_values(self, theta: jax.Array, temperature: float) -> EnvParams:
        """EnvParams at log-ratios `theta` (P,) to the reference values."""
        lo, hi = np.log(BOUNDS[0]), np.log(BOUNDS[1])
        values = jnp.asarray(self.reference) * jnp.exp(jnp.clip(theta, lo, hi))
        fields = {n: values[i] for i, n in enumerate(self.names)}
        return self.params.with_human(**fields).replace(
            relax_temperature=jnp.float32(temperature)
        )

    def loss(self, theta: jax.Array, temperature: float) -> jax.Array:
        """Scaled squared error of the queue tables, averaged over the runs."""
        params = self.with_values(theta, temperature)
        env, n = self.env, self.n_steps

        def one(schedule: Schedule) -> jax.Array:
            obs, state = env.reset_to_schedule(schedule, params)
            _, queues, _ = measured_rollout(env, params, obs, state, n)
            return queues

        queues = jax.vmap(one)(self.schedules)  # (B, T, G)
        q_mean, q_max = slot_queues(queues, n // self.n_slots)
        sims = {"queue_mean_veh": q_mean.mean(0), "queue_max_veh": q_max.mean(0)}
        return table_loss(sims, self.targets)

    def values(self, theta: np.ndarray) -> dict[str, float]:
        lo, hi = np.log(BOUNDS[0]), np.log(BOUNDS[1])
        v = self.reference * np.exp(np.clip(np.asarray(theta, np.float64), lo, hi))
        return {n: float(x) for n, x in zip(self.names, v, strict=True)}


def make_problem(
    env: RoundaboutEnv, params: EnvParams, survey: Survey, names: Sequence[str]
) -> Problem:
    """The calibration of `names` to `survey` on its own seeds' schedules."""
    legs = tuple(leg.name for leg in env.cfg.network.legs)
    if survey.legs != legs:
        raise ConfigError(
            f"the targets' legs {list(survey.legs)} are not the scenario's "
            f"{list(legs)} (scenario '{env.cfg.name}')"
        )
    if not survey.seeds:
        raise ConfigError("the targets file names no seeds (write it with measure)")
    horizon = survey.n_slots * survey.slot_s
    if horizon > env.cfg.demand.duration_s + 1e-6:
        raise ConfigError(
            f"the targets cover {horizon:.0f} s, more than the scenario's "
            f"demand horizon of {env.cfg.demand.duration_s:.0f} s"
        )
    n_steps = survey_steps(env, survey.slot_s, survey.n_slots)
    schedules = [
        env.schedule_from_numpy(make_schedule(env.cfg, seed=s, penetration=0.0))
        for s in survey.seeds
    ]
    params = params.with_penetration(0.0)
    return Problem(
        env=env,
        params=params,
        names=tuple(names),
        reference=np.array([float(params.human_number(n)) for n in names]),
        schedules=jax.tree.map(lambda *x: jnp.stack(x), *schedules),
        targets={n: jnp.asarray(getattr(survey, n), jnp.float32) for n in FITTED},
        n_steps=n_steps,
        n_slots=survey.n_slots,
        n_runs=len(schedules),
        survey=survey,
    )


def _initial(key: jax.Array, n: int, p: int, spread: float) -> jax.Array:
    return jax.random.uniform(key, (n, p), minval=-spread, maxval=spread)


def fit_gradient(
    problem: Problem,
    key: jax.Array,
    n_starts: int = 4,
    n_iters: int = 30,
    learning_rate: float = 0.05,
    temperature: float = 0.5,
    spread: float = 0.4,
    progress: bool = True,
) -> dict[str, Any]:
    """Adam from `n_starts` random log-ratios in [-spread, spread], vmapped.

    Returns a dict: "values" (best start, by exact loss), "loss_exact",
    "history" (per iteration: simulated seconds so far, the lowest relaxed
    loss met so far, over the starts),
    "wall_s", "sim_s", "non_finite_updates".
    """
    p = len(problem.names)
    opt = optax.chain(optax.clip_by_global_norm(1.0), optax.adam(learning_rate))
    theta = _initial(key, n_starts, p, spread)
    state = jax.vmap(opt.init)(theta)
    grad = jax.vmap(jax.value_and_grad(lambda th: problem.loss(th, temperature)))

    @jax.jit
    def update(theta, state):
        loss, g = grad(theta)
        ok = jnp.all(jnp.isfinite(g), axis=1) & jnp.isfinite(loss)
        g = jnp.where(ok[:, None], g, 0.0)  # a non-finite gradient is skipped
        updates, state = jax.vmap(opt.update)(g, state)
        return optax.apply_updates(theta, updates), state, loss, ~ok

    started = time.perf_counter()
    history, skipped, best = [], 0, np.inf
    per_iter = n_starts * problem.sim_seconds_per_candidate
    for i in tqdm(range(n_iters), desc="gradient fit", disable=not progress):
        theta, state, loss, bad = update(theta, state)
        skipped += int(jnp.sum(bad))
        best = min(best, float(jnp.nanmin(loss)))
        history.append(((i + 1) * per_iter, best))
    return _finish(problem, theta, history, started, skipped, n_iters * per_iter)


def fit_black_box(
    problem: Problem,
    key: jax.Array,
    population: int = 8,
    n_iters: int = 15,
    elite: float = 0.25,
    spread: float = 0.4,
    progress: bool = True,
) -> dict[str, Any]:
    """The cross-entropy method on the exact dynamics: each generation
    `population` candidates around the mean, the best `elite` share sets the
    next mean and spread. Same return as `fit_gradient`."""
    p = len(problem.names)
    n_elite = max(2, int(round(elite * population)))
    losses = jax.jit(jax.vmap(lambda th: problem.loss(th, 0.0)))
    mean, std = jnp.zeros(p), jnp.full(p, spread)
    started = time.perf_counter()
    history, best_theta, best = [], None, np.inf
    per_iter = population * problem.sim_seconds_per_candidate
    for i in tqdm(range(n_iters), desc="black-box fit", disable=not progress):
        key, sub = jax.random.split(key)
        cand = mean + std * jax.random.normal(sub, (population, p))
        loss = np.asarray(losses(cand))
        order = np.argsort(np.where(np.isfinite(loss), loss, np.inf))
        top = cand[order[:n_elite]]
        mean, std = jnp.mean(top, 0), jnp.std(top, 0) + 1e-3
        if loss[order[0]] < best:
            best, best_theta = float(loss[order[0]]), np.asarray(cand[order[0]])
        history.append(((i + 1) * per_iter, best))
    theta = jnp.asarray(best_theta)[None, :]
    return _finish(problem, theta, history, started, 0, n_iters * per_iter)


def _finish(
    problem: Problem,
    theta: jax.Array,
    history: list[tuple[float, float]],
    started: float,
    skipped: int,
    sim_s: float,
) -> dict[str, Any]:
    """Pick the candidate with the lowest exact loss."""
    exact = np.asarray(jax.jit(jax.vmap(lambda th: problem.loss(th, 0.0)))(theta))
    i = int(np.nanargmin(exact))
    return {
        "values": problem.values(np.asarray(theta[i])),
        "loss_exact": float(exact[i]),
        "history": [{"sim_s": s, "loss": v} for s, v in history],
        "wall_s": time.perf_counter() - started,
        "sim_s": sim_s,
        "non_finite_updates": skipped,
    }
