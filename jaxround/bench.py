"""Throughput of the JAX environment against SUMO (libsumo), measured in one run.

    result = run_benchmark(load_config("milan"))
    print(format_benchmark(result))

Both simulators run the same scenario over the same window of simulated time:
the first ``sim_seconds`` of the demand are simulated untimed (a warm-up that
fills the network and, for JAX, is also the first run of the compiled
program), then the next ``sim_seconds`` are timed. Throughput is counted in
*vehicle-steps*: the number of vehicles in the network after each step, summed
over the steps (SUMO: ``libsumo.vehicle.getIDCount()``; JAX: occupied slots,
``sum(state.active)``), so the two figures compare like with like.

What is timed, SUMO (one libsumo process, spawned for this run):
    ``simulation.step()`` plus one ``vehicle.getIDCount()`` per step, with the
    options of `sumo_export.runner.run_schedule` (emission device on every
    vehicle, tripinfo and statistics output, junction collision checks).
    Not timed: writing the scenario files, netconvert, ``libsumo.start``
    (reported as ``load_s``), the warm-up steps, and the runner's per-step
    Python work (queue sampling), which the benchmark leaves out. Short windows
    are repeated from a saved state (``simulation.saveState`` / ``loadState``,
    not timed) and the median is reported.

What is timed, JAX:
    one call of a ``jax.jit``-compiled ``jax.vmap`` over B roundabouts of a
    ``lax.scan`` of ``env.step_env`` over the window's steps (dynamics,
    insertion, emissions, queue statistics and the observation, as
    `jaxround.rollout.run_episode` steps them, idle actions), until
    ``jax.block_until_ready``. Not timed: tracing and compilation (reported as
    ``compile_s``), drawing schedules, the reset, the warm-up run. Short runs
    are repeated from the same start state and the median is reported.

Roundabout i of a batch runs ``make_schedule(cfg, seed + i)``: roundabout 0
runs the very schedule SUMO runs, the others the same demand with other seeds.

Beside the timings: XLA's count of floating-point operations of one
roundabout-step (the cost analysis of a compiled one-step program), and a
yardstick timed in the same run, the bare IDM ring of `jaxround.bare_ring` at
the best batch: what the machine gives the simplest car-following step with
the same slots.
"""

from __future__ import annotations

import functools
import multiprocessing
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from jaxround.bare_ring import compiled_flops, measure_bare_ring
from jaxround.config import ScenarioConfig
from jaxround.env import RoundaboutEnv, make
from jaxround.schedule import Schedule as NumpySchedule
from jaxround.schedule import make_schedule
from jaxround.state import EnvParams, EnvState, Schedule

DEFAULT_BATCHES = (1, 16, 256, 1024, 4096)
DEFAULT_SLOT_SIZES = (32, 64, 128, 256)
#: Length of the timed window (and of the warm-up before it), simulated seconds.
#: 30 s keeps the run's peak memory (batch 4096) under 2 GB and the whole run at
#: about 4-6 minutes on a 2-core CPU; after 30 s the Milan network holds about
#: as many vehicles as its hourly mean.
DEFAULT_SIM_SECONDS = 30.0
#: Batch of the slot-scaling runs.
DEFAULT_SLOT_BATCH = 16
#: Short timed runs are repeated until they add up to this many seconds ...
MIN_TIMED_S = 1.0
#: ... or this many repeats.
MAX_REPEATS = 7
#: The same for SUMO's window (one SUMO window of 30 s takes about 10 ms).
SUMO_MIN_TIMED_S = 0.5
SUMO_MAX_REPEATS = 25

WHAT_IS_TIMED = (
    "SUMO: simulation.step() + vehicle.getIDCount() per step (runner options: "
    "emissions, tripinfo, statistics); JAX: one jitted vmap(scan(step_env)) call "
    "until block_until_ready. Not timed: compilation (compile_s), scenario files, "
    "libsumo.start, schedules, reset, the warm-up window."
)


# ------------------------------------------------------------------ public API


def run_benchmark(
    cfg: ScenarioConfig,
    batches: Sequence[int] = DEFAULT_BATCHES,
    sim_seconds: float = DEFAULT_SIM_SECONDS,
    max_vehicles: int = 32,
    slot_sizes: Sequence[int] = DEFAULT_SLOT_SIZES,
    progress: bool = True,
    *,
    slot_batch: int = DEFAULT_SLOT_BATCH,
    seed: int = 0,
) -> dict[str, Any]:
    """Measure SUMO and the JAX environment on one scenario, in this one call.

    See the module docstring for what is timed. SUMO runs first, in a spawned
    process of its own (libsumo holds one simulation per process), then JAX
    in this process, one batch size after the other, then the slot scaling.

    Args:
        cfg: the scenario.
        batches: numbers B of roundabouts stepped together by one jitted call.
        sim_seconds: simulated seconds of the warm-up and of the timed window
            (rounded to whole steps); the window is [S, 2S) of the episode.
        max_vehicles: vehicle slots M of the batch runs.
        slot_sizes: slot counts M of the slot-scaling runs.
        progress: progress bars and notes on stderr.
        slot_batch: batch of the slot-scaling runs.
        seed: schedule seed of SUMO's run (and of roundabout 0 of JAX's).

    Returns:
        ``{"sumo_vehicle_steps_per_s": x, "jax": [{"batch", "vehicle_steps_per_s",
        "steps_per_s", "compile_s", "flops_per_roundabout_step", ...}, ...],
        "best_ratio_vs_sumo": x, "bare_ring": {"vehicle_steps_per_s", ...},
        "slots": [{"max_vehicles", "us_per_step_per_roundabout",
        "us_per_vehicle_step", ...}, ...], "machine": {...}, "sim_seconds": x,
        ...}``; "steps_per_s" counts roundabout-steps (B per batched step).
    """
    batches = [_positive_int(b, "batches") for b in batches]
    slot_sizes = [_positive_int(m, "slot_sizes") for m in slot_sizes]
    max_vehicles = _positive_int(max_vehicles, "max_vehicles")
    slot_batch = _positive_int(slot_batch, "slot_batch")
    if not batches:
        raise ValueError("batches: expected at least one batch size")
    dt = cfg.simulation.dt_s
    steps = round(float(sim_seconds) / dt)
    if not sim_seconds > 0 or steps < 1:
        raise ValueError(f"sim_seconds: {sim_seconds}, expected at least one step")
    window_s = steps * dt
    started = time.perf_counter()
    load_before = _load_average()
    code = code_version()  # at the start: the code this run imported

    def note(text: str) -> None:
        if progress:
            tqdm.write(f"bench: {text}", file=sys.stderr)

    schedule = make_schedule(cfg, seed=seed)
    note(
        f"SUMO: simulated {window_s:g}-{2 * window_s:g} s ({steps} steps of {dt} s) "
        "in a libsumo process"
    )
    sumo = run_sumo_window(cfg, schedule, steps)
    sumo_rate = sumo["vehicle_steps_per_s"]

    cache: dict[tuple[int, int], dict[str, Any]] = {}
    envs: dict[int, tuple[RoundaboutEnv, EnvParams]] = {}
    pool: list[Schedule] = []  # schedules of the largest batch, made once

    def measure(m: int, batch: int) -> dict[str, Any]:
        if (m, batch) not in cache:
            if m not in envs:
                envs[m] = make(cfg, max_vehicles=m)
            env, params = envs[m]
            if not pool:
                n = max([*batches, slot_batch] if slot_sizes else batches)
                pool.append(batch_schedules(env, n, seed))
            schedules = jax.tree.map(lambda x: x[:batch], pool[0])
            cache[(m, batch)] = measure_jax(env, params, schedules, steps)
        return cache[(m, batch)]

    jax_rows = []
    bar = tqdm(batches, desc="JAX batches", unit="batch", disable=not progress)
    for b in bar:
        bar.set_postfix(batch=b)
        r = measure(max_vehicles, b)
        jax_rows.append(
            {
                "batch": b,
                "vehicle_steps_per_s": r["vehicle_steps_per_s"],
                "steps_per_s": r["steps_per_s"],
                "compile_s": r["compile_s"],
                "ratio_vs_sumo": r["vehicle_steps_per_s"] / sumo_rate,
                **{k: r[k] for k in _DETAIL_KEYS},
                **flop_rate(step_flops(envs[max_vehicles][0]), r),
            }
        )
    bar.close()

    slot_rows = []
    bar = tqdm(slot_sizes, desc="JAX slots", unit="size", disable=not progress)
    for m in bar:
        bar.set_postfix(max_vehicles=m)
        r = measure(m, slot_batch)
        slot_rows.append(
            {
                "max_vehicles": m,
                "us_per_step_per_roundabout": r["us_per_step_per_roundabout"],
                "us_per_vehicle_step": r["us_per_vehicle_step"],
                "batch": slot_batch,
                "compile_s": r["compile_s"],
                "mean_vehicles": r["mean_vehicles"],
                "overflow": r["overflow"],
                "wall_s": r["wall_s"],
                "cpu_utilisation": r["cpu_utilisation"],
                "repeats": r["repeats"],
            }
        )
    bar.close()

    best = max(jax_rows, key=lambda row: row["vehicle_steps_per_s"])
    note(f"bare ring (yardstick): batch {best['batch']}, M = {max_vehicles}")
    env = envs[max_vehicles][0]
    bare = measure_bare_ring(
        max_vehicles,
        best["batch"],
        occupancy=min(max(best["mean_vehicles"] / max_vehicles, 1e-3), 1.0),
        steps=steps,
        dt=dt,
        n_substeps=env.n_substeps,
        min_timed_s=MIN_TIMED_S,
        max_repeats=MAX_REPEATS,
    )
    bare["ratio_vs_sumo"] = bare["vehicle_steps_per_s"] / sumo_rate
    bare.update(flop_rate(bare["flops_per_roundabout_step"], bare))
    return {
        "sumo_vehicle_steps_per_s": sumo_rate,
        "jax": jax_rows,
        "best_ratio_vs_sumo": best["vehicle_steps_per_s"] / sumo_rate,
        "best_batch": best["batch"],
        "bare_ring": bare,
        "slots": slot_rows,
        "machine": {
            **machine_info(sumo.get("sumo_version")),
            "load_average_before": load_before,
        },
        "sim_seconds": window_s,
        "window_s": [window_s, 2 * window_s],
        "steps": steps,
        "dt_s": dt,
        "scenario": cfg.name,
        "n_vehicles": cfg.demand.n_vehicles,
        "max_vehicles": max_vehicles,
        "slot_batch": slot_batch,
        "seed": seed,
        "sumo": sumo,
        "code": code,
        "what_is_timed": WHAT_IS_TIMED,
        "total_wall_s": time.perf_counter() - started,
    }


def format_benchmark(result: dict[str, Any]) -> str:
    """A Markdown summary of `run_benchmark`'s result: two tables and the ratio."""
    sumo_rate = result["sumo_vehicle_steps_per_s"]
    sumo = result.get("sumo", {})
    window = result.get("window_s", [result["sim_seconds"], 2 * result["sim_seconds"]])
    lines = [
        f"Scenario `{result.get('scenario', '?')}`: simulated window "
        f"{_num(window[0])}-{_num(window[1])} s after a warm-up of "
        f"{_num(window[0])} s, M = {result.get('max_vehicles', '?')} slots.",
        "",
        "| simulator | batch | vehicle-steps/s | vs SUMO | vehicle-steps/CPU-s "
        "| roundabout-steps/s | mean vehicles | CPU use | compile (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        f"| SUMO (libsumo) | 1 | {sumo_rate:,.0f} | 1.00 "
        f"| {_fmt(sumo.get('vehicle_steps_per_cpu_s'), ',.0f')} "
        f"| {_fmt(sumo.get('steps_per_s'), ',.0f')} "
        f"| {_fmt(sumo.get('mean_vehicles'), '.1f')} "
        f"| {_fmt(sumo.get('cpu_utilisation'), '.2f')} | - |",
    ]
    for row in result["jax"]:
        lines.append(
            f"| JAX | {row['batch']} | {row['vehicle_steps_per_s']:,.0f} "
            f"| {row['vehicle_steps_per_s'] / sumo_rate:.2f} "
            f"| {_fmt(row.get('vehicle_steps_per_cpu_s'), ',.0f')} "
            f"| {row['steps_per_s']:,.0f} "
            f"| {_fmt(row.get('mean_vehicles'), '.1f')} "
            f"| {_fmt(row.get('cpu_utilisation'), '.2f')} "
            f"| {row['compile_s']:.1f} |"
        )
    best = max(result["jax"], key=lambda row: row["vehicle_steps_per_s"])
    lines += [
        "",
        f"Best JAX / SUMO: **{result['best_ratio_vs_sumo']:.2f}x** "
        f"(batch {best['batch']}).",
    ]
    bare = result.get("bare_ring")
    if bare:
        lines += [
            "",
            "| yardstick (batch "
            f"{bare['batch']}) | vehicle-steps/s | vs SUMO | us/step/roundabout "
            "| flops/step/roundabout | GFLOP/s |",
            "|---|---:|---:|---:|---:|---:|",
            _work_row("JAX environment", best),
            _work_row("bare IDM ring", bare),
            "",
            "Bare IDM ring (`jaxround.bare_ring`): the same slots and occupancy, one "
            "pairwise leader search and one IDM update per step, nothing else: "
            "the ceiling of a car-following step on this machine. Flops: XLA's "
            "cost analysis of the compiled program.",
        ]
    if result.get("slots"):
        batch = result["slots"][0].get("batch", result.get("slot_batch", "?"))
        lines += [
            "",
            f"Cost of one step against the slot count M (batch {batch}):",
            "",
            "| max_vehicles | us/step/roundabout | us/vehicle-step "
            "| mean vehicles | CPU use | compile (s) |",
            "|---:|---:|---:|---:|---:|---:|",
        ]
        for row in result["slots"]:
            lines.append(
                f"| {row['max_vehicles']} | {row['us_per_step_per_roundabout']:,.1f} "
                f"| {_fmt(row.get('us_per_vehicle_step'), ',.1f')} "
                f"| {_fmt(row.get('mean_vehicles'), '.1f')} "
                f"| {_fmt(row.get('cpu_utilisation'), '.2f')} "
                f"| {_fmt(row.get('compile_s'), '.1f')} |"
            )
    machine = result.get("machine", {})
    if machine:
        cpu = machine.get("cpu_model") or machine.get("machine", "?")
        devices = ", ".join(machine.get("jax_devices", []))
        lines += [
            "",
            f"Machine: {cpu}, {machine.get('cpu_count', '?')} CPUs, "
            f"JAX {machine.get('jax_version')} ({machine.get('jax_backend')}: "
            f"{devices}), {machine.get('sumo_version')}, {machine.get('date')}; "
            f"load average {machine.get('load_average_before')} before the run, "
            f"{machine.get('load_average')} after.",
            "",
            "CPU use: CPU seconds of the timing process per wall second (XLA may "
            "use several threads; SUMO uses one).",
        ]
    code = result.get("code", {})
    if code.get("commit"):
        changes = " with local changes" if code.get("local_changes") else ""
        lines += ["", f"Code: commit {code['commit'][:12]}{changes}."]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ SUMO


def run_sumo_window(
    cfg: ScenarioConfig, schedule: NumpySchedule, steps: int
) -> dict[str, Any]:
    """Time SUMO on steps [steps, 2 * steps) of `schedule`, in a spawned process.

    Returns:
        ``{"vehicle_steps_per_s", "steps_per_s", "vehicle_steps", "mean_vehicles",
        "wall_s", "repeats", "load_s", "full_episode": {...}, "sumo_version"}``;
        "full_episode" is the whole run to the last arrival, for reference.
    """
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        return pool.submit(_sumo_worker, cfg, schedule, steps).result()


def _sumo_worker(
    cfg: ScenarioConfig, schedule: NumpySchedule, steps: int
) -> dict[str, Any]:
    """The body of `run_sumo_window`, in the worker process."""
    import libsumo

    from sumo_export.runner import DRAIN_S, sumo_arguments
    from sumo_export.scenario import write_scenario

    with tempfile.TemporaryDirectory(prefix="jaxround-bench-") as tmp:
        out = Path(tmp)
        files = write_scenario(cfg, schedule, out)
        args = sumo_arguments(
            files.sumocfg, out / "tripinfo.xml", out / "statistics.xml"
        )
        t0 = time.perf_counter()
        libsumo.start(args)
        load_s = time.perf_counter() - t0
        try:
            sim = libsumo.simulation
            warm_count, warm_wall, _ = _sumo_steps(libsumo, steps)
            state = str(out / "window.xml")
            sim.saveState(state)
            counts: list[int] = []
            walls: list[float] = []
            cpus: list[float] = []
            while True:
                if counts:
                    sim.loadState(state)
                count, wall, cpu = _sumo_steps(libsumo, steps)
                counts.append(count)
                walls.append(wall)
                cpus.append(cpu)
                if sum(walls) >= SUMO_MIN_TIMED_S or len(walls) >= SUMO_MAX_REPEATS:
                    break
            # the rest of the episode, for the whole-run figures
            rest_count, rest_wall, rest_steps = 0, 0.0, 0
            max_time = cfg.demand.duration_s + DRAIN_S
            while sim.getMinExpectedNumber() > 0 and sim.getTime() < max_time:
                count, wall, _ = _sumo_steps(libsumo, 1)
                rest_count += count
                rest_wall += wall
                rest_steps += 1
            end_s = sim.getTime()
        finally:
            libsumo.close()
        version = libsumo.getVersion()[1]
    rates = [c / w for c, w in zip(counts, walls, strict=True)]
    wall, cpu = statistics.median(walls), max(statistics.median(cpus), 1e-9)
    full_count = warm_count + counts[0] + rest_count
    full_wall = warm_wall + walls[0] + rest_wall
    return {
        "vehicle_steps_per_s": statistics.median(rates),
        "steps_per_s": steps / wall,
        "vehicle_steps_per_cpu_s": counts[0] / cpu,
        "vehicle_steps": counts[0],
        "mean_vehicles": counts[0] / steps,
        "wall_s": wall,
        "cpu_s": cpu,
        "cpu_utilisation": cpu / wall,
        "repeats": len(walls),
        "load_s": load_s,
        "full_episode": {
            "steps": 2 * steps + rest_steps,
            "sim_end_s": float(end_s),
            "vehicle_steps": full_count,
            "wall_s": full_wall,
            "vehicle_steps_per_s": full_count / full_wall,
        },
        "sumo_version": version,
    }


def _sumo_steps(libsumo: Any, steps: int) -> tuple[int, float, float]:
    """Step SUMO `steps` times; (vehicle-steps, wall seconds, CPU seconds)."""
    step, count_ids = libsumo.simulation.step, libsumo.vehicle.getIDCount
    count = 0
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in range(steps):
        step()
        count += count_ids()
    return count, time.perf_counter() - t0, time.process_time() - c0


# ------------------------------------------------------------------ JAX

_DETAIL_KEYS = (
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
) -> Callable[[EnvState, EnvParams], tuple[EnvState, jax.Array, jax.Array]]:
    """``jit(scan)`` of one roundabout over `steps` steps, batched by `measure_jax`.

    (state, params) -> (state, vehicle-steps, overflow count since the reset).

    The scan body is `run_episode`'s with idle actions (observation carried),
    plus the count of occupied slots after each step. Cached per environment,
    so that each batch size reuses the traced step instead of tracing it again.
    """
    action = jnp.zeros((env.max_vehicles, 2), jnp.float32)
    key = jax.random.PRNGKey(0)  # step_env does not use it

    def one(
        state: EnvState, params: EnvParams
    ) -> tuple[EnvState, jax.Array, jax.Array]:
        obs = env.observation(state, params)

        def body(carry, _):
            obs, state, occupied = carry
            obs, state, _, _, _ = env.step_env(key, state, action, params)
            occupied = occupied + jnp.sum(state.active, dtype=jnp.int32)
            return (obs, state, occupied), None

        init = (obs, state, jnp.int32(0))
        (_, state, occupied), _ = jax.lax.scan(body, init, None, length=steps)
        return state, occupied, state.overflow

    return jax.jit(one)


@functools.lru_cache(maxsize=16)
def _reset(env: RoundaboutEnv) -> Callable[[Schedule, EnvParams], EnvState]:
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


def measure_jax(
    env: RoundaboutEnv, params: EnvParams, schedules: Schedule, steps: int
) -> dict[str, Any]:
    """Compile, warm up over steps [0, steps) and time steps [steps, 2 * steps).

    Args:
        schedules: one schedule per roundabout, stacked on a leading batch axis
            (see `batch_schedules`).
    """
    batch = int(schedules.depart_s.shape[0])
    batched = jax.jit(jax.vmap(_reset(env), in_axes=(0, None)))
    states = jax.block_until_ready(batched(schedules, params))
    t0 = time.perf_counter()
    run = jax.jit(jax.vmap(window_runner(env, steps), in_axes=(0, None)))
    run = run.lower(states, params).compile()
    compile_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    states = jax.block_until_ready(run(states, params)[0])  # warm-up window
    warmup_s = time.perf_counter() - t0

    walls, cpus = [], []
    while True:
        c0, t0 = time.process_time(), time.perf_counter()
        out = jax.block_until_ready(run(states, params))
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
        if sum(walls) >= MIN_TIMED_S or len(walls) >= MAX_REPEATS:
            break
    _, occupied, overflow = jax.device_get(out)
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


# ------------------------------------------------------------------ machine


def machine_info(sumo_version: str | None = None) -> dict[str, Any]:
    """Platform, CPUs, memory, Python, JAX (backend, devices) and SUMO versions."""
    try:
        memory_gib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        memory_gib = None
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_model": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpus_usable": usable,
        "memory_gib": None if memory_gib is None else round(memory_gib, 1),
        "python": platform.python_version(),
        "jax_version": jax.__version__,
        "jaxlib_version": _package_version("jaxlib"),
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in jax.devices()],
        "sumo_version": sumo_version,
        "date": datetime.now(UTC).date().isoformat(),
        "load_average": _load_average(),
    }


def code_version() -> dict[str, Any]:
    """jaxround's version and, in a git checkout, its commit and whether the
    package sources differ from it (read-only git commands)."""
    info: dict[str, Any] = {"jaxround": _package_version("jaxround")}
    root = Path(__file__).resolve().parent.parent
    git = ["git", "-C", str(root)]
    try:
        head = subprocess.run(
            [*git, "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10
        )
        if head.returncode == 0:
            info["commit"] = head.stdout.strip()
            diff = subprocess.run(
                [*git, "diff", "--quiet", "HEAD", "--", "jaxround", "sumo_export"],
                capture_output=True,
                timeout=10,
            )
            info["local_changes"] = diff.returncode != 0
    except (OSError, subprocess.SubprocessError):
        pass
    return info


def _package_version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def _load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (other work on a shared machine)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def _cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


# ------------------------------------------------------------------ helpers


def _positive_int(x: Any, name: str) -> int:
    if isinstance(x, bool) or int(x) != x or x < 1:
        raise ValueError(f"{name}: {x!r}, expected a positive integer")
    return int(x)


def _work_row(name: str, row: dict[str, Any]) -> str:
    """A row of the yardstick table: speed and XLA's flop count of one program."""
    return (
        f"| {name} | {row['vehicle_steps_per_s']:,.0f} "
        f"| {_fmt(row.get('ratio_vs_sumo'), '.2f')} "
        f"| {row['us_per_step_per_roundabout']:,.1f} "
        f"| {_fmt(row.get('flops_per_roundabout_step'), ',.0f')} "
        f"| {_fmt(row.get('gflops_per_s'), '.1f')} |"
    )


def _num(x: float) -> str:
    return f"{x:g}"


def _fmt(x: Any, spec: str) -> str:
    return "-" if x is None else format(x, spec)
