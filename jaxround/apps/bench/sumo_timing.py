"""SUMO's side of `jaxround.apps.bench`: libsumo timed over one window, in one
process, and in one process per core at once (the peer a user would run).

What is timed: ``simulation.step()`` plus one ``vehicle.getIDCount()`` per
step, with the options of `sumo_export.runner.run_schedule` (emission device
on every vehicle, tripinfo and statistics output, junction collision
checks). Not timed: writing the scenario files, netconvert,
``libsumo.start`` (reported as ``load_s``), the warm-up steps, and the
runner's per-step Python work (queue sampling).

The window is repeated from a saved state (``simulation.saveState`` /
``loadState``, not timed) until each process has timed at least
`SUMO_MIN_TIMED_S` of wall time (``timed_wall_s``): a window of 60 steps
takes a few milliseconds, too short a time for one figure on a shared
machine. The median repeat is reported, and the spread over the repeats
(``spread``: the 10th and 90th percentiles of the rate, and their distance
from each other over the median). The processes are spawned with JAX on the
CPU (`jaxround.sumo_files.processes`); each reports its JAX (``jax``).
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import Schedule as NumpySchedule
from jaxround.sumo_files.processes import (
    cpu_process_pool,
    cpu_spawn_context,
    jax_platform_report,
)

#: A timed window is repeated until the repeats add up to this many seconds
#: of wall time in each process (one SUMO window of 30 s takes about 10 ms) ...
SUMO_MIN_TIMED_S = 1.0
#: ... or this many repeats (a stop for windows with no vehicles).
SUMO_MAX_REPEATS = 100_000


def run_sumo_window(
    cfg: ScenarioConfig, schedule: NumpySchedule, steps: int
) -> dict[str, Any]:
    """Time SUMO on steps [steps, 2 * steps) of `schedule`, in a spawned process.

    Returns:
        ``{"vehicle_steps_per_s", "steps_per_s", "vehicle_steps_per_cpu_s",
        "vehicle_steps", "mean_vehicles", "wall_s", "cpu_s", "repeats",
        "load_s", "full_episode": {...}, "sumo_version"}``; "full_episode" is
        the whole run to the last arrival, for reference.
    """
    with cpu_process_pool(1) as pool:
        return pool.submit(_sumo_worker, cfg, schedule, steps, False, True).result()


def run_sumo_parallel(
    cfg: ScenarioConfig, schedules: list[NumpySchedule], steps: int
) -> dict[str, Any]:
    """Time one SUMO process per schedule, all stepping the same window at once.

    Each process loads its scenario and runs the warm-up on its own, then
    all wait for each other and time their windows together: the throughput
    of the machine when it runs independent SUMO simulations side by side,
    as a user with that many cores would.

    Returns:
        ``{"processes", "vehicle_steps_per_s" (the sum over the processes),
        "vehicle_steps_per_cpu_s", "per_process": [...], "wall_s" (the
        slowest process), ...}``.
    """
    n = len(schedules)
    barrier = cpu_spawn_context().Barrier(n)  # reaches the workers as they start
    with cpu_process_pool(n, initializer=_keep_barrier, initargs=(barrier,)) as pool:
        futures = [pool.submit(_sumo_worker, cfg, s, steps, True) for s in schedules]
        rows = [f.result() for f in futures]
    counts = sum(r["vehicle_steps"] for r in rows)
    cpu = sum(r["cpu_s"] for r in rows)
    return {
        "processes": n,
        "vehicle_steps_per_s": sum(r["vehicle_steps_per_s"] for r in rows),
        "min_timed_wall_s": min(r["timed_wall_s"] for r in rows),
        "vehicle_steps_per_cpu_s": counts / max(cpu, 1e-9),
        "vehicle_steps": counts,
        "mean_vehicles": counts / (n * steps),
        "wall_s": max(r["wall_s"] for r in rows),
        "per_process": [
            {
                k: r[k]
                for k in (
                    "vehicle_steps_per_s",
                    "vehicle_steps",
                    "wall_s",
                    "timed_wall_s",
                    "repeats",
                    "spread",
                    "jax",
                )
            }
            for r in rows
        ],
    }


def usable_cpus() -> int:
    """The cores this process may run on (its affinity), else the CPU count."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


#: The barrier of `run_sumo_parallel`'s workers (set as each worker starts).
_BARRIER: Any = None


def _keep_barrier(barrier: Any) -> None:
    global _BARRIER
    _BARRIER = barrier


def _sumo_worker(
    cfg: ScenarioConfig,
    schedule: NumpySchedule,
    steps: int,
    together: bool = False,
    full_episode: bool = False,
) -> dict[str, Any]:
    """The body of `run_sumo_window` / `run_sumo_parallel`, in a worker process.

    Args:
        together: wait for the other workers (the barrier of
            `run_sumo_parallel`) before timing.
        full_episode: also run the rest of the episode (untimed by the
            window, reported as "full_episode").
    """
    import libsumo

    from jaxround.scenario.config import DRAIN_S
    from sumo_export.runner import sumo_arguments
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
            if together:
                _BARRIER.wait()
            counts, walls, cpus = _repeat_window(libsumo, steps, state)
            rest = {}
            if full_episode:
                rest = _rest_of_episode(
                    libsumo, cfg.demand.duration_s + DRAIN_S, steps,
                    warm=(warm_count, warm_wall), first=(counts[0], walls[0]),
                )  # fmt: skip
        finally:
            libsumo.close()
        version = libsumo.getVersion()[1]
    rates = [c / max(w, 1e-12) for c, w in zip(counts, walls, strict=True)]
    wall, cpu = statistics.median(walls), max(statistics.median(cpus), 1e-9)
    return {
        "vehicle_steps_per_s": statistics.median(rates),
        "timed_wall_s": sum(walls),
        "spread": rate_spread(rates),
        "jax": jax_platform_report(),
        "steps_per_s": steps / wall,
        "vehicle_steps_per_cpu_s": counts[0] / cpu,
        "vehicle_steps": counts[0],
        "mean_vehicles": counts[0] / steps,
        "wall_s": wall,
        "cpu_s": cpu,
        "cpu_utilisation": cpu / wall,
        "repeats": len(walls),
        "load_s": load_s,
        **rest,
        "sumo_version": version,
    }


def rate_spread(rates: list[float]) -> dict[str, float]:
    """``{"p10", "median", "p90", "relative"}`` of the repeats' rates;
    relative: (p90 - p10) / median."""
    if len(rates) < 2:
        p10 = p90 = rates[0]
    else:
        deciles = statistics.quantiles(rates, n=10, method="inclusive")
        p10, p90 = deciles[0], deciles[-1]
    median = statistics.median(rates)
    return {"p10": p10, "median": median, "p90": p90,
            "relative": (p90 - p10) / max(median, 1e-12)}  # fmt: skip


def _repeat_window(
    libsumo: Any, steps: int, state: str
) -> tuple[list[int], list[float], list[float]]:
    """Time the window from the saved `state` until the repeats add up to
    `SUMO_MIN_TIMED_S` (or `SUMO_MAX_REPEATS`); the window's vehicle-steps,
    wall and CPU seconds of each repeat."""
    counts: list[int] = []
    walls: list[float] = []
    cpus: list[float] = []
    while True:
        if counts:
            libsumo.simulation.loadState(state)
        count, wall, cpu = _sumo_steps(libsumo, steps)
        counts.append(count)
        walls.append(wall)
        cpus.append(cpu)
        if sum(walls) >= SUMO_MIN_TIMED_S or len(walls) >= SUMO_MAX_REPEATS:
            return counts, walls, cpus


def _rest_of_episode(
    libsumo: Any,
    max_time: float,
    steps: int,
    warm: tuple[int, float],
    first: tuple[int, float],
) -> dict[str, Any]:
    """Step on to the last arrival; ``{"full_episode": {...}}`` of the whole
    run (warm-up, first timed window, rest)."""
    sim = libsumo.simulation
    rest_count, rest_wall, rest_steps = 0, 0.0, 0
    while sim.getMinExpectedNumber() > 0 and sim.getTime() < max_time:
        count, wall, _ = _sumo_steps(libsumo, 1)
        rest_count += count
        rest_wall += wall
        rest_steps += 1
    full_count = warm[0] + first[0] + rest_count
    full_wall = warm[1] + first[1] + rest_wall
    return {
        "full_episode": {
            "steps": 2 * steps + rest_steps,
            "sim_end_s": float(sim.getTime()),
            "vehicle_steps": full_count,
            "wall_s": full_wall,
            "vehicle_steps_per_s": full_count / full_wall,
        }
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
