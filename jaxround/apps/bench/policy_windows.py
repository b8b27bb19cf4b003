"""An exported policy driving the AVs over one window, in JAX and in SUMO,
timed for `jaxround.apps.bench.training`.

Both run the full scenario from its start: an untimed warm-up over [0, S)
with the policy driving, then the timed window [S, 2S). Throughput is in
env-steps (roundabout-steps) per second, with vehicle-steps beside.

- JAX: one ``jit(vmap(scan))`` over B roundabouts of the policy's
  deterministic action (`agents.common.evaluation.switched_policy`) and
  ``env.step_env``; roundabout i runs ``make_schedule(cfg, seed + i)``.
- SUMO: one spawned process per schedule, all timing the window at once
  (a barrier); per step ``simulation.step()``, the controller
  (`sumo_export.controller.PolicyController`: read, observe, policy,
  command) and ``vehicle.getIDCount()``. The controller's compiled observer
  is built in the warm-up. Each process repeats the window (from a saved
  state, the controller's memory of its AVs restored) until it has timed
  `SUMO_MIN_TIMED_S` of wall time, and reports the median repeat.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agents.common.evaluation import switched_policy
from agents.common.export import PolicyLayout
from jaxround.apps.bench.jax_timing import batch_schedules
from jaxround.apps.bench.sumo_timing import (
    SUMO_MAX_REPEATS,
    SUMO_MIN_TIMED_S,
    rate_spread,
)
from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs.roundabout import make
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import Schedule as NumpySchedule
from jaxround.scenario.schedule import make_schedule
from jaxround.sumo_files.processes import (
    cpu_process_pool,
    cpu_spawn_context,
    jax_platform_report,
)


def window_steps(cfg: ScenarioConfig, seconds: float) -> int:
    """Steps of dt in `seconds` (at least one).

    Raises:
        ValueError: less than one step.
    """
    steps = round(float(seconds) / cfg.simulation.dt_s)
    if steps < 1:
        raise ValueError(f"policy_seconds: {seconds}, expected at least one step")
    return steps


def measure_jax_policy(
    cfg: ScenarioConfig,
    arrays: dict[str, np.ndarray],
    layout: PolicyLayout,
    *,
    batch: int,
    seconds: float,
    seed: int = 0,
) -> dict[str, Any]:
    """Time B roundabouts of the policy driving the AVs in JAX over [S, 2S).

    Args:
        cfg: the scenario, its observer and action the policy's, its
            penetration the schedules' AV share.
        arrays, layout: the exported policy (`agents.common.export.load_policy`).
        batch: roundabouts B.
        seconds: S, simulated seconds of the warm-up and of the window.
        seed: schedule seed of roundabout 0.

    Returns:
        ``{"env_steps_per_s", "vehicle_steps_per_s", "env_steps_per_cpu_s",
        "batch", "max_vehicles",
        "steps", "window_s", "mean_vehicles", "av_share", "compile_s",
        "wall_s", "cpu_s", "cpu_utilisation", "overflow"}``.
    """
    steps = window_steps(cfg, seconds)
    env, params = make(cfg)
    weights = {k: jnp.asarray(v) for k, v in arrays.items()}
    act = switched_policy(weights, layout, jnp.bool_(True))
    key = jax.random.PRNGKey(0)  # neither the policy nor step_env draws from it

    def window(obs: jax.Array, state: EnvState, p: EnvParams) -> tuple[Any, ...]:
        def body(carry, _):
            obs, state, occupied, avs = carry
            action = act(obs, state, key)
            obs, state, _, _, _ = env.step_env(key, state, action, p)
            occupied = occupied + jnp.sum(state.active, dtype=jnp.int32)
            avs = avs + jnp.sum(state.active & state.is_av, dtype=jnp.int32)
            return (obs, state, occupied, avs), None

        init = (obs, state, jnp.int32(0), jnp.int32(0))
        (obs, state, occupied, avs), _ = jax.lax.scan(body, init, None, length=steps)
        return obs, state, occupied, avs, state.stats.overflow

    schedules = batch_schedules(env, batch, seed)
    reset = jax.jit(jax.vmap(env.reset_to_schedule, in_axes=(0, None)))
    obs, states = jax.block_until_ready(reset(schedules, params))
    t0 = time.perf_counter()
    run = jax.jit(jax.vmap(window, in_axes=(0, 0, None)))
    run = run.lower(obs, states, params).compile()
    compile_s = time.perf_counter() - t0
    obs, states = jax.block_until_ready(run(obs, states, params))[:2]
    c0, t0 = time.process_time(), time.perf_counter()
    out = jax.block_until_ready(run(obs, states, params))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    _, _, occupied, avs, overflow = jax.device_get(out)
    vehicle_steps = int(np.sum(occupied, dtype=np.int64))
    env_steps = batch * steps
    return {
        "env_steps_per_s": env_steps / wall,
        "vehicle_steps_per_s": vehicle_steps / wall,
        "env_steps_per_cpu_s": env_steps / max(cpu, 1e-9),
        "batch": batch,
        "max_vehicles": env.max_vehicles,
        "steps": steps,
        "window_s": [steps * env.dt, 2 * steps * env.dt],
        "mean_vehicles": vehicle_steps / env_steps,
        "av_share": int(np.sum(avs)) / max(vehicle_steps, 1),
        "compile_s": compile_s,
        "wall_s": wall,
        "cpu_s": cpu,
        "cpu_utilisation": cpu / wall,
        "overflow": int(np.sum(overflow)),
    }


def measure_sumo_in_the_loop(
    cfg: ScenarioConfig,
    policy_path: str,
    *,
    processes: int,
    seconds: float,
    seed: int = 0,
) -> dict[str, Any]:
    """Time one SUMO process per core with the policy in the loop over [S, 2S).

    Args:
        cfg: the scenario (penetration: the AV share), as `measure_jax_policy`.
        policy_path: the exported policy.
        processes: SUMO processes at once; process i runs seed + i.
        seconds: S, simulated seconds of the warm-up and of the window.
        seed: schedule seed of process 0.

    Returns:
        ``{"env_steps_per_s" (sum over the processes), "vehicle_steps_per_s",
        "env_steps_per_cpu_s" (all processes' env-steps per CPU second of
        theirs), "processes", "steps", "window_s", "mean_vehicles", "wall_s" (the
        slowest process), "controller_share" (of the timed wall time),
        "overflow_vehicle_steps", "per_process": [...]}``.
    """
    steps = window_steps(cfg, seconds)
    schedules = [make_schedule(cfg, seed=seed + i) for i in range(processes)]
    barrier = cpu_spawn_context().Barrier(processes)  # reaches the workers at start
    with cpu_process_pool(
        processes, initializer=_keep_barrier, initargs=(barrier,)
    ) as pool:
        futures = [
            pool.submit(_loop_worker, cfg, s, policy_path, steps) for s in schedules
        ]
        rows = [f.result() for f in futures]
    vehicle_steps = sum(r["vehicle_steps"] for r in rows)
    return {
        "env_steps_per_s": sum(r["env_steps_per_s"] for r in rows),
        "vehicle_steps_per_s": sum(r["vehicle_steps_per_s"] for r in rows),
        "env_steps_per_cpu_s": processes * steps / sum(r["cpu_s"] for r in rows),
        "processes": processes,
        "steps": steps,
        "window_s": [steps * cfg.simulation.dt_s, 2 * steps * cfg.simulation.dt_s],
        "mean_vehicles": vehicle_steps / (processes * steps),
        "wall_s": max(r["wall_s"] for r in rows),
        "controller_share": sum(r["controller_s"] for r in rows)
        / sum(r["wall_s"] for r in rows),
        "overflow_vehicle_steps": sum(r["overflow_vehicle_steps"] for r in rows),
        "min_timed_wall_s": min(r["timed_wall_s"] for r in rows),
        "per_process": rows,
    }


#: The barrier of `measure_sumo_in_the_loop`'s workers (set as each starts).
_BARRIER: Any = None


def _keep_barrier(barrier: Any) -> None:
    global _BARRIER
    _BARRIER = barrier


def controller_memory(controller: Any) -> tuple[dict, set]:
    """What the controller remembers between steps (the AVs it retuned or
    commanded), to restore with the saved state of a repeated window."""
    return dict(controller._retuned), set(controller._commanded)


def restore_controller_memory(controller: Any, memory: tuple[dict, set]) -> None:
    controller._retuned, controller._commanded = dict(memory[0]), set(memory[1])


def _loop_worker(
    cfg: ScenarioConfig, schedule: NumpySchedule, policy_path: str, steps: int
) -> dict[str, Any]:
    """One SUMO process of `measure_sumo_in_the_loop`: warm-up, barrier, window."""
    import libsumo

    from sumo_export.controller import PolicyControllerFactory
    from sumo_export.runner import sumo_arguments
    from sumo_export.scenario import write_scenario

    controller = PolicyControllerFactory(policy_path)(cfg, schedule)
    with tempfile.TemporaryDirectory(prefix="jaxround-bench-loop-") as tmp:
        out = Path(tmp)
        files = write_scenario(cfg, schedule, out)
        libsumo.start(
            sumo_arguments(files.sumocfg, out / "tripinfo.xml", out / "stats.xml")
        )
        try:
            sim, count_ids = libsumo.simulation, libsumo.vehicle.getIDCount
            for _ in range(steps):  # warm-up; compiles the controller's observer
                sim.step()
                controller(libsumo, sim.getTime())
            before = controller.step_times_ms()["total"].sum()
            state, memory = str(out / "window.xml"), controller_memory(controller)
            sim.saveState(state)
            _BARRIER.wait()
            counts, walls, cpus = [], [], []
            while sum(walls) < SUMO_MIN_TIMED_S and len(walls) < SUMO_MAX_REPEATS:
                if walls:  # the same window again, the controller as it was
                    sim.loadState(state)
                    restore_controller_memory(controller, memory)
                count = 0
                c0, t0 = time.process_time(), time.perf_counter()
                for _ in range(steps):
                    sim.step()
                    controller(libsumo, sim.getTime())
                    count += count_ids()
                walls.append(time.perf_counter() - t0)
                cpus.append(time.process_time() - c0)
                counts.append(count)
            controller_s = (controller.step_times_ms()["total"].sum() - before) / 1e3
        finally:
            libsumo.close()
    wall, cpu = statistics.median(walls), statistics.median(cpus)
    return {
        "env_steps_per_s": steps / wall,
        "vehicle_steps_per_s": counts[0] / wall,
        "vehicle_steps": counts[0],
        "wall_s": wall,
        "cpu_s": cpu,
        "timed_wall_s": sum(walls),
        "repeats": len(walls),
        "spread": rate_spread([steps / w for w in walls]),
        "jax": jax_platform_report(),
        "controller_s": float(controller_s) / len(walls),
        "overflow_vehicle_steps": int(controller.sumo.overflow_vehicle_steps),
        "commands": int(controller.commands),
    }
