"""The JAX side of `jaxround.apps.bench`: one jitted ``vmap(scan(step_env))`` call
timed over a window, and XLA's flop count of one roundabout-step.

What is timed: one call of a ``jax.jit``-compiled ``jax.vmap`` over B
roundabouts of a ``lax.scan`` of ``env.step_env`` over the window's steps
(dynamics, insertion, emissions, queue statistics and the observation, as
`jaxround.envs.rollout.run_episode` steps them, idle actions), until
``jax.block_until_ready``. Not timed: tracing and compilation (reported as
``compile_s``), drawing schedules, the reset, the warm-up run. Short runs are
repeated from the same start state and the median is reported.
"""

from __future__ import annotations

import functools
import statistics
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.apps.bare_ring import compiled_flops
from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState, Schedule
from jaxround.envs.roundabout import RoundaboutEnv
from jaxround.scenario.schedule import make_schedule

#: Short timed runs are repeated until they add up to this many seconds ...
MIN_TIMED_S = 1.0
#: ... or this many repeats.
MAX_REPEATS = 7

DETAIL_KEYS = (
    "vehicle_steps_per_cpu_s",
    "us_per_step_per_roundabout",
    "us_per_vehicle_step",
    "vehicle_steps",
    "mean_vehicles",
    "realtime_factor",
    "cpu_utilisation",
    "wall_s",
    "cpu_s",
    "repeats",
    "warmup_run_s",
    "overflow",
)


def batch_schedules(env: RoundaboutEnv, batch: int, seed: int = 0) -> Schedule:
    """``make_schedule(cfg, seed + i)`` for i < batch, stacked on a leading axis.

    Roundabout 0 runs the schedule SUMO runs; the others other seeds' schedules.
    Stacked on the host, then converted as `RoundaboutEnv.schedule_from_numpy`
    converts one schedule.
    """
    drawn = [make_schedule(env.cfg, seed=seed + i) for i in range(batch)]

    def stack(name: str) -> np.ndarray:
        return np.stack([getattr(s, name) for s in drawn])

    route = env.network.route_index[stack("origin"), stack("destination")]
    return Schedule(
        depart_s=jnp.asarray(stack("depart_s"), jnp.float32),
        route=jnp.asarray(route, jnp.int32),
        origin=jnp.asarray(stack("origin"), jnp.int32),
        speed_factor=jnp.asarray(stack("speed_factor"), jnp.float32),
        is_av=jnp.asarray(stack("is_av")),
    )


@functools.lru_cache(maxsize=16)
def window_runner(
    env: RoundaboutEnv, steps: int
) -> Callable[[EnvState, EnvParams], tuple[EnvState, jax.Array, jax.Array, jax.Array]]:
    """``jit(scan)`` of one roundabout over `steps` steps, batched by `measure_jax`.

    (state, params) -> (state, vehicle-steps, overflow count since the reset,
    sum of the observations).

    The scan body is `run_episode`'s with idle actions, plus the count of
    occupied slots after each step. The observations are summed into an
    output: XLA drops what no output reads, and without it the timed program
    would not compute the observation a learner gets every step. Cached per
    environment, so that each batch size reuses the traced step instead of
    tracing it again.
    """
    action = jnp.zeros((env.max_vehicles, 2), jnp.float32)
    key = jax.random.PRNGKey(0)  # step_env does not use it

    def one(
        state: EnvState, params: EnvParams
    ) -> tuple[EnvState, jax.Array, jax.Array, jax.Array]:
        def body(carry, _):
            state, occupied, obs_sum = carry
            obs, state, _, _, _ = env.step_env(key, state, action, params)
            occupied = occupied + jnp.sum(state.active, dtype=jnp.int32)
            return (state, occupied, obs_sum + jnp.sum(obs)), None

        init = (state, jnp.int32(0), jnp.float32(0.0))
        (state, occupied, obs_sum), _ = jax.lax.scan(body, init, None, length=steps)
        return state, occupied, state.stats.overflow, obs_sum

    return jax.jit(one)


@functools.lru_cache(maxsize=16)
def reset_runner(env: RoundaboutEnv) -> Callable[[Schedule, EnvParams], EnvState]:
    """``jit(env.reset_to_schedule)``, cached per environment like `window_runner`."""
    return jax.jit(lambda schedule, params: env.reset_to_schedule(schedule, params)[1])


@functools.lru_cache(maxsize=16)
def step_flops(env: RoundaboutEnv) -> float | None:
    """XLA's flop count of one unbatched `env.step_env` (one roundabout-step).

    Counted on a program of its own, compiled once per environment: XLA's cost
    analysis counts the body of a loop (the timed window's scan) only once.
    The count depends on the shapes only.
    """
    action = jnp.zeros((env.max_vehicles, 2), jnp.float32)
    key = jax.random.PRNGKey(0)
    params = env.default_params
    _, state = jax.eval_shape(env.reset, key, params)
    step = jax.jit(lambda s, p: env.step_env(key, s, action, p))
    return compiled_flops(step.lower(state, params).compile())


def flop_rate(flops: float | None, row: dict[str, Any]) -> dict[str, float | None]:
    """``{"flops_per_roundabout_step", "gflops_per_s"}`` of a timed row (one with
    "us_per_step_per_roundabout"); both None without a flop count."""
    us = row["us_per_step_per_roundabout"]
    return {
        "flops_per_roundabout_step": flops,
        "gflops_per_s": None if flops is None else flops / us / 1e3,
    }


class WarmedWindow(NamedTuple):
    """`warmed_window`: run the compiled batched window (states, params) ->
    `window_runner`'s outputs; states (B, ...) after the warm-up window;
    compile_s and warmup_s the seconds each took."""

    run: Any
    states: EnvState
    compile_s: float
    warmup_s: float


def warmed_window(
    env: RoundaboutEnv, params: EnvParams, schedules: Schedule, steps: int
) -> WarmedWindow:
    """Reset B roundabouts to `schedules` (stacked on a leading batch axis, see
    `batch_schedules`), compile the batched window of `steps` steps and run it
    once: the warm-up over steps [0, steps)."""
    batched = jax.jit(jax.vmap(reset_runner(env), in_axes=(0, None)))
    states = jax.block_until_ready(batched(schedules, params))
    t0 = time.perf_counter()
    run = jax.jit(jax.vmap(window_runner(env, steps), in_axes=(0, None)))
    run = run.lower(states, params).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    states = jax.block_until_ready(run(states, params)[0])
    return WarmedWindow(run, states, compile_s, time.perf_counter() - t0)


def measure_jax(
    env: RoundaboutEnv, params: EnvParams, schedules: Schedule, steps: int
) -> dict[str, Any]:
    """Compile, warm up over steps [0, steps) and time steps [steps, 2 * steps).

    Args:
        schedules: one schedule per roundabout, stacked on a leading batch axis
            (see `batch_schedules`).
    """
    batch = int(schedules.depart_s.shape[0])
    run, states, compile_s, warmup_s = warmed_window(env, params, schedules, steps)

    walls, cpus = [], []
    while True:
        c0, t0 = time.process_time(), time.perf_counter()
        out = jax.block_until_ready(run(states, params))
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
        if sum(walls) >= MIN_TIMED_S or len(walls) >= MAX_REPEATS:
            break
    _, occupied, overflow, _ = jax.device_get(out)
    vehicle_steps = int(np.sum(occupied, dtype=np.int64))
    wall, cpu = statistics.median(walls), max(statistics.median(cpus), 1e-9)
    roundabout_steps = batch * steps
    return {
        "batch": batch,
        "max_vehicles": env.max_vehicles,
        "vehicle_steps_per_s": vehicle_steps / wall,
        "steps_per_s": roundabout_steps / wall,
        "compile_s": compile_s,
        "vehicle_steps_per_cpu_s": vehicle_steps / cpu,
        "us_per_step_per_roundabout": 1e6 * wall / roundabout_steps,
        "us_per_vehicle_step": 1e6 * wall / max(vehicle_steps, 1),
        "vehicle_steps": vehicle_steps,
        "mean_vehicles": vehicle_steps / roundabout_steps,
        "realtime_factor": roundabout_steps * env.dt / wall,
        "cpu_utilisation": cpu / wall,
        "wall_s": wall,
        "cpu_s": cpu,
        "repeats": len(walls),
        "warmup_run_s": warmup_s,
        "overflow": int(np.sum(overflow)),
    }
