"""The two-lane step beside Milan's, per vehicle-step, at the same batches.

    python -m jaxround.apps.bench.lane_step --batch 256 4096 65536 \
        [--rounds 1024 4096] [--no-sumo] [--out FILE.json]

One process, one run: for two_lane.yaml, then Milan, SUMO (one process,
then one per core, as `jaxround bench` times it) and the JAX step at each
batch (the lane changer one turn after another); then two_lane.yaml again with its
lane changer in rounds (`jaxround.lanes.ring_rounds`, the same changes as
the turns one after another: `LaneChanger.in_rounds`) at the batches of
``--rounds``. Each row is `jaxround.apps.bench.jax_timing.measure_jax`
(30 simulated seconds warmed up, the next 30 timed); the JSON is written
after every row, so a run stopped by a time limit keeps what it measured.

``--alternate N`` times the two steps instead in turns, N windows of each
at every batch (two_lane, Milan, two_lane, ...), and reports the smallest
and the median time of each and their ratios: on a machine whose load
moves, the two then share its slow and quiet moments, where rows timed one
after the other may not (docs/benchmarks.md, 2026-12-03).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import jax
import numpy as np
from tqdm import tqdm

from jaxround.apps.bench.jax_timing import batch_schedules, measure_jax, warmed_window
from jaxround.apps.bench.report import code_version
from jaxround.apps.bench.sumo_timing import (
    run_sumo_parallel,
    run_sumo_window,
    usable_cpus,
)
from jaxround.envs.roundabout import make
from jaxround.scenario.config import load_config
from jaxround.scenario.schedule import make_schedule

#: Warm-up and timed window, simulated seconds (as `jaxround bench`).
WINDOW_S = 30.0
SCENARIOS = ("two_lane", "milan")
ROW_KEYS = ("us_per_vehicle_step", "vehicle_steps_per_s", "compile_s", "mean_vehicles")


def time_sumo(name: str, steps: int) -> dict[str, Any]:
    """SUMO's vehicle-steps per second on scenario `name`: one process, and
    one per usable core at once."""
    cfg = load_config(name)
    one = run_sumo_window(cfg, make_schedule(cfg, seed=0), steps)
    n = usable_cpus()
    schedules = [make_schedule(cfg, seed=i) for i in range(n)]
    parallel = run_sumo_parallel(cfg, schedules, steps)
    return {
        "one_process": one["vehicle_steps_per_s"],
        "all_cores": parallel["vehicle_steps_per_s"],
        "processes": n,
        "mean_vehicles": one["mean_vehicles"],
        "sumo_version": one.get("sumo_version"),
    }


def alternated(batch: int, rounds: int) -> dict[str, Any]:
    """Both scenarios' windows at ``batch``, compiled and warmed, then timed
    in turns ``rounds`` times each: us per vehicle-step, smallest and median,
    and two_lane's over Milan's."""
    windows = {}
    for name in SCENARIOS:
        env, params = make(load_config(name))
        steps = round(WINDOW_S / env.dt)
        warm = warmed_window(env, params, batch_schedules(env, batch, seed=0), steps)
        windows[name] = (warm.run, warm.states, params)
    walls: dict[str, list[float]] = {name: [] for name in SCENARIOS}
    vehicle_steps = {}
    for _ in range(rounds):
        for name, (run_window, states, params) in windows.items():
            started = time.perf_counter()
            out = jax.block_until_ready(run_window(states, params))
            walls[name].append(time.perf_counter() - started)
            vehicle_steps[name] = int(np.sum(jax.device_get(out[1]), dtype=np.int64))
    row: dict[str, Any] = {"batch": batch, "rounds": rounds}
    for stat, pick in (("min", min), ("median", statistics.median)):
        us = {n: 1e6 * pick(walls[n]) / vehicle_steps[n] for n in SCENARIOS}
        row |= {f"{n}_us_{stat}": us[n] for n in SCENARIOS}
        row[f"ratio_{stat}"] = us["two_lane"] / us["milan"]
    return row


def run(
    batches: list[int], rounds_batches: list[int], sumo: bool, out: Path | None
) -> dict[str, Any]:
    """Time the rows (see the module docstring); returns the JSON's object."""
    started = time.perf_counter()
    result: dict[str, Any] = {
        "device": str(jax.devices()[0]),
        "backend": jax.default_backend(),
        "code": code_version(),
        "window_s": [WINDOW_S, 2 * WINDOW_S],
        "sumo": {},
        "rows": [],
    }

    def save() -> None:
        result["wall_s"] = time.perf_counter() - started
        if out is not None:
            out.write_text(json.dumps(result, indent=1) + "\n")

    tasks = [(name, False, batches) for name in SCENARIOS]
    if rounds_batches:
        tasks.append(("two_lane", True, rounds_batches))
    largest = max(batches + rounds_batches)
    for name, in_rounds, task_batches in tasks:
        cfg = load_config(name)
        env, params = make(cfg)
        steps = round(WINDOW_S / env.dt)
        if sumo and name not in result["sumo"]:
            result["sumo"][name] = time_sumo(name, steps)
            print(f"{name} SUMO {result['sumo'][name]}", file=sys.stderr, flush=True)
            save()
        if env.lane_changer is not None:
            env.lane_changer.in_rounds = in_rounds
        pool = batch_schedules(env, largest, seed=0)
        changer = (
            None if env.lane_changer is None else ("rounds" if in_rounds else "turns")
        )
        for batch in task_batches:
            row: dict[str, Any] = {"scenario": name, "changer": changer, "batch": batch}
            try:
                schedules = jax.tree.map(lambda x, b=batch: x[:b], pool)
                timed = measure_jax(env, params, schedules, steps)
                row.update(slots=env.max_vehicles, **timed)
            except Exception as error:  # noqa: BLE001 (a batch too large is a row)
                row["error"] = repr(error)[:400]
                traceback.print_exc()
            result["rows"].append(row)
            shown = {k: row[k] for k in (*ROW_KEYS, "error") if k in row}
            print(f"{name} {changer} {batch} {shown}", file=sys.stderr, flush=True)
            save()
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m jaxround.apps.bench.lane_step",
        description=__doc__.split("\n")[0],
    )
    parser.add_argument("--batch", type=int, nargs="+", required=True, metavar="B")
    parser.add_argument(
        "--rounds", type=int, nargs="*", default=[], metavar="B",
        help="batches of two_lane.yaml again, its changer in rounds",
    )  # fmt: skip
    parser.add_argument("--no-sumo", action="store_true", help="skip SUMO's timing")
    parser.add_argument(
        "--alternate", type=int, default=0, metavar="N",
        help="instead: N windows of each scenario in turns at every batch",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, help="JSON file (refused if it exists)")
    args = parser.parse_args(argv)
    for b in [*args.batch, *args.rounds]:
        if b < 1:
            parser.error(f"batch {b}: expected a positive integer")
    if args.out is not None and args.out.exists():
        parser.error(f"--out {args.out}: exists; choose a new file")
    if args.alternate < 0:
        parser.error(f"--alternate {args.alternate}: expected N >= 1 (0: off)")
    if args.alternate:
        rows = []
        for batch in tqdm(args.batch, desc="batches"):
            rows.append(alternated(batch, args.alternate))
            if args.out is not None:
                args.out.write_text(json.dumps({"code": code_version(), "rows": rows}))
        print(json.dumps({"code": code_version(), "rows": rows}, indent=1))
        return 0
    result = run(args.batch, args.rounds, not args.no_sumo, args.out)
    if args.out is None:
        print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
