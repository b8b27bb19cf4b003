"""The two-lane changer's cost beside Milan's whole single-lane step, in one run.

    python -m jaxround.apps.bench.changer [--config two_lane] [--batch 16 256]

SUMO 1.28 drives ``--duration`` seconds of the two-lane config and its
steps are replayed through the JAX changer, as
`jaxround.apps.ring_lane_replay` does, which leaves each step its LC2013
memory. A batch is B of those steps, spread evenly over the run after its
first ``--skip`` seconds (the ring filling up). Timed, each as one jitted
``vmap`` over the B roundabouts (compilation not timed; repeated until a
second has passed or seven times, the median reported):

- the changer one turn after another (`jaxround.lanes.ring_batches`);
- the changer in rounds (`jaxround.lanes.ring_rounds`), which runs as many
  rounds as the batch's slowest step needs;
- Milan's whole single-lane step at the same batch
  (`jaxround.apps.bench.jax_timing.measure_jax`, 200 steps).

Per vehicle-step: a roundabout-step's time over the vehicles on the network.
Issue 36 allows the whole two-lane step 1.5 times Milan's per vehicle-step.
"""

from __future__ import annotations

import argparse
import functools
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np
from tqdm import tqdm

from jaxround.analysis.report import markdown_table
from jaxround.apps.bench.jax_timing import (
    MAX_REPEATS,
    MIN_TIMED_S,
    batch_schedules,
    measure_jax,
)
from jaxround.apps.ring_lane_record import record_sumo
from jaxround.apps.ring_lane_replay import SlotBook, arrays, tables_for
from jaxround.envs.roundabout import make
from jaxround.lanes import ring_batches, ring_rounds
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.views import Memory
from jaxround.scenario.config import load_config
from jaxround.scenario.schedule import make_schedule

MILAN_STEPS = 200


def _timed(fn: Callable[[], Any]) -> float:
    """Median seconds of one call of ``fn`` (compiled by a first call)."""
    jax.block_until_ready(fn())
    walls: list[float] = []
    while sum(walls) < MIN_TIMED_S and len(walls) < MAX_REPEATS:
        start = time.perf_counter()
        jax.block_until_ready(fn())
        walls.append(time.perf_counter() - start)
    return statistics.median(walls)


def replayed_steps(config: str, duration_s: float, seed: int) -> dict[str, Any]:
    """SUMO's steps with the memory the replay gives each: the network
    arrays, and per step the vehicles and memory (lists), and ``dt``."""
    cfg = load_config(config)
    tables = tables_for(cfg)
    if (tables.paths.change_path < 0).all():
        raise SystemExit(f"--config {config}: no edge has two lanes to change between")
    steps, _ = record_sumo(cfg, tables.paths, duration_s, make_schedule(cfg, seed))
    net, book = arrays(cfg, tables), SlotBook.for_steps(cfg, steps)
    lc, dt = LaneChangeParams(), cfg.simulation.dt_s
    change = jax.jit(ring_rounds.change_lanes, static_argnums=4)
    memory = Memory.zeros(book.n_slots)
    vehicles, memories, times = [], [], []
    for rec in tqdm(steps, desc="replay", leave=False):
        veh, memory, _ = book.vehicles(rec, memory)
        vehicles.append(veh)
        memories.append(memory)
        times.append(rec.time)
        _, memory, _ = change(net, veh, memory, lc, dt)
    return {"net": net, "vehicles": vehicles, "memory": memories, "time": times,
            "dt": dt, "lc": lc, "slots": book.n_slots}  # fmt: skip


def measure(replayed: dict[str, Any], batch: int, skip_s: float) -> dict[str, Any]:
    """Both changers on B = ``batch`` of the replayed steps."""
    usable = [n for n, t in enumerate(replayed["time"]) if t >= skip_s]
    if not usable:
        raise SystemExit(f"--skip {skip_s}: no recorded step after it")
    picked = [usable[int(n)] for n in np.linspace(0, len(usable) - 1, batch)]

    def stacked(key: str) -> Any:
        return jax.tree.map(lambda *x: np.stack(x), *[replayed[key][n] for n in picked])

    veh, memory = stacked("vehicles"), stacked("memory")
    net, lc, dt = replayed["net"], replayed["lc"], replayed["dt"]
    vehicles = float(np.mean(np.sum(np.asarray(veh.active), axis=1)))
    sequential = jax.jit(
        jax.vmap(functools.partial(ring_batches.change_lanes, net, lc=lc, dt=dt))
    )
    in_rounds = jax.jit(
        jax.vmap(functools.partial(ring_rounds.change_lanes, net, lc=lc, dt=dt))
    )
    settled = in_rounds(veh, memory)
    same = np.array_equal(
        np.asarray(sequential(veh, memory)[0].direction),
        np.asarray(settled[0].direction),
    )
    rounds = np.asarray(settled[2])
    seconds = {
        "sequential": _timed(lambda: sequential(veh, memory)),
        "rounds": _timed(lambda: in_rounds(veh, memory)),
    }
    return {
        "batch": batch,
        "slots": replayed["slots"],
        "mean_vehicles": vehicles,
        "same_changes": bool(same),
        "rounds_max": int(rounds.max()),
        "rounds_mean": float(rounds.mean()),
        **{
            f"us_per_vehicle_step_{name}": 1e6 * s / batch / max(vehicles, 1e-9)
            for name, s in seconds.items()
        },
        **{f"us_per_step_{name}": 1e6 * s / batch for name, s in seconds.items()},
    }


def milan(batch: int) -> dict[str, Any]:
    """`measure_jax` of Milan's step at this batch (its default slots)."""
    env, params = make(load_config("milan"))
    return measure_jax(env, params, batch_schedules(env, batch), MILAN_STEPS)


def report(rows: list[dict[str, Any]], device: str) -> str:
    """The rows as a markdown table."""
    table = [
        [
            str(r["batch"]), f"{r['slots']} / {r['milan_slots']}",
            f"{r['mean_vehicles']:.1f} / {r['milan_vehicles']:.1f}",
            f"{r['us_per_vehicle_step_sequential']:.3g}",
            f"{r['us_per_vehicle_step_rounds']:.3g}",
            f"{r['rounds_mean']:.2f} ({r['rounds_max']})",
            f"{r['milan_us_per_vehicle_step']:.3g}",
            f"{r['us_per_vehicle_step_rounds'] / r['milan_us_per_vehicle_step']:.2f}",
        ]
        for r in rows
    ]  # fmt: skip
    head = ("batch", "slots (two-lane / Milan)", "vehicles",
            "changer one by one (us)",
            "changer in rounds (us)", "rounds: mean (most)", "Milan's whole step (us)",
            "in rounds / Milan")  # fmt: skip
    return f"On {device}, per vehicle-step:\n\n" + markdown_table(head, table)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="two_lane", help="a built-in or a file")
    parser.add_argument("--duration", type=float, default=600.0, help="SUMO seconds")
    parser.add_argument("--skip", type=float, default=120.0, help="seconds left out")
    parser.add_argument("--seed", type=int, default=0, help="schedule seed")
    parser.add_argument("--batch", type=int, nargs="+", default=[16])
    parser.add_argument("--json", type=Path, help="write the rows here (new file)")
    args = parser.parse_args(argv)
    if args.duration <= args.skip or args.skip < 0:
        parser.error(f"--duration {args.duration}, --skip {args.skip}: "
                     "expected 0 <= skip < duration")  # fmt: skip
    if min(args.batch) < 1:
        parser.error(f"--batch {args.batch}: expected sizes >= 1")
    if args.json is not None and args.json.exists():
        parser.error(f"--json {args.json}: exists; give a new file")
    replayed = replayed_steps(args.config, args.duration, args.seed)
    device = jax.devices()[0].device_kind
    rows = []
    for batch in args.batch:
        base = milan(batch)
        row = measure(replayed, batch, args.skip)
        row |= {
            "milan_us_per_vehicle_step": base["us_per_vehicle_step"],
            "milan_vehicles": base["mean_vehicles"],
            "milan_slots": base["max_vehicles"],
        }
        rows.append(row)
        print(report(rows, device), flush=True)
    if args.json:
        args.json.write_text(json.dumps({"device": device, "rows": rows}, indent=1))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
