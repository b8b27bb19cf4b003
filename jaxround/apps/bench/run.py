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

SUMO runs in one libsumo process, and then in one process per usable core
at once, each on its own schedule (the peer a user with this machine would
run), each timing the window again and again for at least a second of wall
time: `jaxround.apps.bench.sumo_timing` says what is timed. JAX runs B
roundabouts in one jitted call (`jaxround.apps.bench.jax_timing`), B up to
what the device holds (`jaxround.apps.bench.device`). The ratios are taken
per wall second (the headline), per CPU second (XLA uses every core, SUMO
one), and against SUMO in one process per core.

Roundabout i of a batch runs ``make_schedule(cfg, seed + i)``: roundabout 0
runs the very schedule SUMO runs, the others the same demand with other
seeds, as do SUMO's parallel processes.

Beside the timings: XLA's count of floating-point operations of one
roundabout-step (the cost analysis of a compiled one-step program), and a
yardstick timed in the same run, the bare IDM ring of `jaxround.apps.bare_ring` at
the best batch: what the machine gives the simplest car-following step with
the same slots. `jaxround.apps.bench.report` formats the tables.

With a PPO config (``training=``, the CLI's default), the run ends with the
speed a user of the environment gets, in env-steps/s: PPO training, and an
exported policy driving the AVs in JAX and in SUMO in the loop
(`jaxround.apps.bench.training`).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
from tqdm import tqdm

from agents.common.config import PPOConfig
from agents.common.device_batch import this_device
from agents.common.export import load_policy
from jaxround.apps.bare_ring import measure_bare_ring
from jaxround.apps.bench.device import device_batches, device_record
from jaxround.apps.bench.device import policy_batch as policy_batch_of
from jaxround.apps.bench.jax_timing import (
    DETAIL_KEYS,
    MAX_REPEATS,
    MIN_TIMED_S,
    batch_schedules,
    flop_rate,
    measure_jax,
    step_flops,
)
from jaxround.apps.bench.report import (
    code_version,
    load_average,
    machine_info,
)
from jaxround.apps.bench.sumo_timing import (
    SUMO_MIN_TIMED_S,
    run_sumo_parallel,
    run_sumo_window,
    usable_cpus,
)
from jaxround.apps.bench.training import DEFAULT_POLICY_SECONDS, measure_training
from jaxround.core.params import EnvParams
from jaxround.core.state import Schedule
from jaxround.envs.roundabout import RoundaboutEnv, make
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import make_schedule

__all__ = ["run_benchmark"]

DEFAULT_SLOT_SIZES = (32, 64, 128, 256)
#: Length of the timed window (and of the warm-up before it), simulated seconds.
#: 30 s keeps the run's peak memory (batch 4096) under 2 GB and the whole run at
#: about 4-6 minutes on a 2-core CPU; after 30 s the Milan network holds about
#: as many vehicles as its hourly mean.
DEFAULT_SIM_SECONDS = 30.0
#: Batch of the slot-scaling runs.
DEFAULT_SLOT_BATCH = 16

WHAT_IS_TIMED = (
    "SUMO: simulation.step() + vehicle.getIDCount() per step (runner options: "
    "emissions, tripinfo, statistics), in one process and in one process per "
    "core at once; JAX: one jitted vmap(scan(step_env)) call until "
    "block_until_ready. Not timed: compilation (compile_s), scenario files, "
    "libsumo.start, schedules, reset, the warm-up window."
)


def run_benchmark(
    cfg: ScenarioConfig,
    batches: Sequence[int] | None = None,
    sim_seconds: float = DEFAULT_SIM_SECONDS,
    max_vehicles: int | None = None,
    slot_sizes: Sequence[int] = DEFAULT_SLOT_SIZES,
    progress: bool = True,
    *,
    slot_batch: int = DEFAULT_SLOT_BATCH,
    seed: int = 0,
    sumo_processes: int | None = None,
    training: PPOConfig | None = None,
    policy: str | Path | None = None,
    policy_batch: int | None = None,
    policy_seconds: float = DEFAULT_POLICY_SECONDS,
) -> dict[str, Any]:
    """Measure SUMO and the JAX environment on one scenario, in this one call.

    See the module docstring for what is timed. SUMO runs first, in spawned
    processes of its own (libsumo holds one simulation per process), then JAX
    in this process, one batch size after the other, then the slot scaling.

    Args:
        cfg: the scenario.
        batches: numbers B of roundabouts stepped together by one jitted call;
            None: the device's (`jaxround.apps.bench.device.device_batches`).
        sim_seconds: simulated seconds of the warm-up and of the timed window
            (rounded to whole steps); the window is [S, 2S) of the episode.
        max_vehicles: vehicle slots M of the batch runs; None: the config's
            ``simulation.max_vehicles``, else what the road holds.
        slot_sizes: slot counts M of the slot-scaling runs.
        progress: progress bars and notes on stderr.
        slot_batch: batch of the slot-scaling runs.
        seed: schedule seed of SUMO's run (and of roundabout 0 of JAX's).
        sumo_processes: SUMO processes run at once for the parallel peer
            (and for SUMO in the loop); default one per usable core.
        training: a PPO config: also time its training, and a policy of it
            driving the AVs in JAX and in SUMO (`jaxround.apps.bench.training`,
            last in the run); None: not.
        policy: the exported policy of those rollouts (with `training`);
            None: a freshly initialised network of the config.
        policy_batch: roundabouts of the JAX policy rollout (with `training`);
            None: the device's (`jaxround.apps.bench.device.policy_batch`).
        policy_seconds: warm-up and timed window of the policy rollouts,
            simulated seconds (with `training`).

    Returns:
        ``{"sumo_vehicle_steps_per_s": x, "sumo_parallel": {"processes",
        "vehicle_steps_per_s", ...}, "jax": [{"batch", "vehicle_steps_per_s",
        "steps_per_s", "compile_s", "flops_per_roundabout_step",
        "ratio_vs_sumo", "ratio_vs_sumo_per_cpu_s", ...}, ...],
        "best_ratio_vs_sumo": x, "best_ratio_vs_sumo_per_cpu_s": x,
        "best_ratio_vs_sumo_parallel": x, "bare_ring": {...}, "slots":
        [{"max_vehicles", "us_per_step_per_roundabout", "us_per_vehicle_step",
        ...}, ...], "machine": {...}, "sim_seconds": x, "max_vehicles": M,
        "jax_slot_overflow": x, "device": {...}, ...}``; "sumo" and each of
        "sumo_parallel"'s "per_process" have "timed_wall_s" (at least
        `SUMO_MIN_TIMED_S`) and "spread"; "steps_per_s" counts roundabout-steps
        (B per batched step); "jax_slot_overflow" is the largest batch's
        vehicle-steps of slot overflow at M (it runs every smaller batch's
        schedules); with `training`, "training" holds
        `jaxround.apps.bench.training.measure_training`'s result.
    """
    device = this_device()
    if batches is None:
        batches = device_batches(device)
    if policy_batch is None:
        policy_batch = policy_batch_of(device)
    batches = [_positive_int(b, "batches") for b in batches]
    slot_sizes = [_positive_int(m, "slot_sizes") for m in slot_sizes]
    if max_vehicles is not None:
        max_vehicles = _positive_int(max_vehicles, "max_vehicles")
    slot_batch = _positive_int(slot_batch, "slot_batch")
    if sumo_processes is None:
        sumo_processes = usable_cpus()
    sumo_processes = _positive_int(sumo_processes, "sumo_processes")
    if not batches:
        raise ValueError("batches: expected at least one batch size")
    if policy is not None and training is None:
        raise ValueError("policy: only with a training config (training=...)")
    if policy is not None:
        load_policy(policy)  # a missing or damaged policy fails before any run
    dt = cfg.simulation.dt_s
    steps = round(float(sim_seconds) / dt)
    if not sim_seconds > 0 or steps < 1:
        raise ValueError(f"sim_seconds: {sim_seconds}, expected at least one step")
    window_s = steps * dt
    started = time.perf_counter()
    load_before = load_average()
    code = code_version()  # at the start: the code this run imported
    runs = JaxRuns(cfg, steps, seed, max([*batches, slot_batch]))
    max_vehicles = runs.slots(max_vehicles)

    def note(text: str) -> None:
        if progress:
            tqdm.write(f"bench: {text}", file=sys.stderr)

    note(
        f"SUMO: simulated {window_s:g}-{2 * window_s:g} s ({steps} steps of {dt} s) "
        f"in one libsumo process, then in {sumo_processes} at once"
    )
    sumo = run_sumo_window(cfg, make_schedule(cfg, seed=seed), steps)
    sumo_rate = sumo["vehicle_steps_per_s"]
    parallel = run_sumo_parallel(
        cfg, [make_schedule(cfg, seed=seed + i) for i in range(sumo_processes)], steps
    )

    jax_rows = []
    for b in tqdm(batches, desc="JAX batches", unit="batch", disable=not progress):
        r = runs.measure(max_vehicles, b)
        jax_rows.append(
            {
                "batch": b,
                "vehicle_steps_per_s": r["vehicle_steps_per_s"],
                "steps_per_s": r["steps_per_s"],
                "compile_s": r["compile_s"],
                "ratio_vs_sumo": r["vehicle_steps_per_s"] / sumo_rate,
                "ratio_vs_sumo_per_cpu_s": r["vehicle_steps_per_cpu_s"]
                / sumo["vehicle_steps_per_cpu_s"],
                **{k: r[k] for k in DETAIL_KEYS},
                **flop_rate(step_flops(runs.env(max_vehicles)), r),
            }
        )
    slot_rows = [
        _slot_row(runs.measure(m, slot_batch), m, slot_batch)
        for m in tqdm(slot_sizes, desc="JAX slots", unit="size", disable=not progress)
    ]

    best = max(jax_rows, key=lambda row: row["vehicle_steps_per_s"])
    note(f"bare ring (yardstick): batch {best['batch']}, M = {max_vehicles}")
    bare = measure_bare_ring(
        max_vehicles,
        best["batch"],
        occupancy=min(max(best["mean_vehicles"] / max_vehicles, 1e-3), 1.0),
        steps=steps,
        dt=dt,
        n_substeps=runs.env(max_vehicles).n_substeps,
        min_timed_s=MIN_TIMED_S,
        max_repeats=MAX_REPEATS,
    )
    bare["ratio_vs_sumo"] = bare["vehicle_steps_per_s"] / sumo_rate
    bare.update(flop_rate(bare["flops_per_roundabout_step"], bare))
    trained = None
    if training is not None:
        trained = measure_training(
            training, policy=policy, policy_batch=policy_batch,
            policy_seconds=policy_seconds, sumo_processes=sumo_processes,
            seed=seed, progress=progress,
        )  # fmt: skip
    return {
        "sumo_vehicle_steps_per_s": sumo_rate,
        "sumo_parallel": parallel,
        "jax": jax_rows,
        "best_ratio_vs_sumo": best["vehicle_steps_per_s"] / sumo_rate,
        "best_ratio_vs_sumo_per_cpu_s": max(
            row["ratio_vs_sumo_per_cpu_s"] for row in jax_rows
        ),
        "best_ratio_vs_sumo_parallel": best["vehicle_steps_per_s"]
        / parallel["vehicle_steps_per_s"],
        "best_batch": best["batch"],
        "bare_ring": bare,
        "slots": slot_rows,
        "device": device_record(device),
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
        "jax_slot_overflow": max(row["overflow"] for row in jax_rows),
        "slot_batch": slot_batch,
        "seed": seed,
        "sumo": sumo,
        "sumo_min_timed_s": SUMO_MIN_TIMED_S,
        "code": code,
        "what_is_timed": WHAT_IS_TIMED,
        **({"training": trained} if trained is not None else {}),
        "total_wall_s": time.perf_counter() - started,
    }


class JaxRuns:
    """The JAX measurements of one benchmark: an environment per slot count,
    the schedules of the largest batch made once, each (M, batch) timed once."""

    def __init__(self, cfg: ScenarioConfig, steps: int, seed: int, largest: int):
        self.cfg, self.steps, self.seed, self.largest = cfg, steps, seed, largest
        self._envs: dict[int, tuple[RoundaboutEnv, EnvParams]] = {}
        self._pool: Schedule | None = None
        self._done: dict[tuple[int, int], dict[str, Any]] = {}

    def slots(self, m: int | None) -> int:
        """M itself, or for None the environment's default (its config's,
        else what the road holds), built now."""
        if m is None:
            env, params = make(self.cfg)
            self._envs.setdefault(env.max_vehicles, (env, params))
            return env.max_vehicles
        return m

    def env(self, m: int) -> RoundaboutEnv:
        if m not in self._envs:
            self._envs[m] = make(self.cfg, max_vehicles=m)
        return self._envs[m][0]

    def measure(self, m: int, batch: int) -> dict[str, Any]:
        """`measure_jax` of B = `batch` roundabouts with M = `m` slots."""
        if (m, batch) not in self._done:
            env = self.env(m)
            if self._pool is None:
                self._pool = batch_schedules(env, self.largest, self.seed)
            schedules = jax.tree.map(lambda x: x[:batch], self._pool)
            params = self._envs[m][1]
            self._done[(m, batch)] = measure_jax(env, params, schedules, self.steps)
        return self._done[(m, batch)]


def _slot_row(r: dict[str, Any], m: int, batch: int) -> dict[str, Any]:
    """A row of the slot-scaling table from `measure_jax`'s result."""
    return {
        "max_vehicles": m,
        "us_per_step_per_roundabout": r["us_per_step_per_roundabout"],
        "us_per_vehicle_step": r["us_per_vehicle_step"],
        "batch": batch,
        "compile_s": r["compile_s"],
        "mean_vehicles": r["mean_vehicles"],
        "overflow": r["overflow"],
        "wall_s": r["wall_s"],
        "cpu_utilisation": r["cpu_utilisation"],
        "repeats": r["repeats"],
    }


def _positive_int(x: Any, name: str) -> int:
    if isinstance(x, bool) or int(x) != x or x < 1:
        raise ValueError(f"{name}: {x!r}, expected a positive integer")
    return int(x)
