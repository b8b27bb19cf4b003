"""A roundabout's capacity in SUMO: what it lets in per hour as demand grows.

    python -m jaxround.apps.sumo_capacity --config two_lane \\
        --demands 2000,2500,3000 --seeds 100 101

Runs the scenario in real SUMO (human drivers only, the scenario's own
origin shares and OD matrix) at each hourly demand, on exact-count schedules
(`jaxround.scenario.schedule.make_schedule`), until every vehicle has left or
the usual cap, and reports per demand, as a mean over the seeds, the vehicles
let in within the hour (`jaxround.analysis.saturation.entry_rates`), the
share of the demand that is, the mean wait to be inserted, the mean crossing
time, the largest queue of any leg, lane changes per vehicle, collisions and
teleports. Below capacity every vehicle is let in within the hour and the
waits stay short; past it the entries level off at the capacity while the
queues grow for the whole hour. SUMO only, so it runs on two-lane
roundabouts, which the JAX side does not run yet.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxround.analysis.report import markdown_table
from jaxround.analysis.saturation import entry_rates
from jaxround.scenario.config import ScenarioConfig, config_from_dict, load_config
from jaxround.scenario.schedule import make_schedule

#: Evaluation seeds: training uses seeds below 100.
EVAL_SEEDS = (100, 101)

COLUMNS = (
    "demand (veh/h)", "entered (veh/h)", "entered share", "insertion wait (s)",
    "crossing time (s)", "largest queue (veh)", "lane changes / veh",
    "collisions", "teleports",
)  # fmt: skip


def with_demand(cfg: ScenarioConfig, vehicles_per_hour: int) -> ScenarioConfig:
    """`cfg` with this many vehicles in an hour (the horizon scaled to 3600 s)."""
    data = cfg.to_dict()
    data["demand"]["n_vehicles"] = int(vehicles_per_hour)
    data["demand"]["duration_s"] = 3600.0
    return config_from_dict(data)


def capacity_sweep(
    cfg: ScenarioConfig,
    demands: Sequence[int],
    seeds: Sequence[int] = EVAL_SEEDS,
    workers: int | None = None,
) -> list[dict[str, Any]]:
    """One row per demand (veh/h), each a mean over `seeds` (see the module)."""
    from sumo_export.runner import run_many

    rows = []
    for demand in demands:
        scenario = with_demand(cfg, demand)
        schedules = [make_schedule(scenario, seed, 0.0) for seed in seeds]
        runs = run_many(scenario, schedules, workers)
        per_seed = []
        for run in runs:
            r = run.records
            departed = r.departed
            per_seed.append({
                "entered": entry_rates(r, scenario.n_legs, 3600.0).sum(),
                "wait": float(np.mean((r.depart_s - r.scheduled_depart_s)[departed])),
                "crossing": float(np.nanmean(r.crossing_time_s)),
                "queue": float(r.queue_max_veh.max()),
                "changes": run.lane_changes / max(1, int(departed.sum())),
                "collisions": run.collisions,
                "teleports": run.teleports,
            })  # fmt: skip
        mean = {k: float(np.mean([s[k] for s in per_seed])) for k in per_seed[0]}
        rows.append({
            "demand": int(demand),
            "entered_per_h": mean["entered"],
            "entered_share": mean["entered"] / demand,
            "insertion_wait_s": mean["wait"],
            "crossing_time_s": mean["crossing"],
            "largest_queue_veh": mean["queue"],
            "lane_changes_per_vehicle": mean["changes"],
            "collisions": int(sum(s["collisions"] for s in per_seed)),
            "teleports": int(sum(s["teleports"] for s in per_seed)),
            "seeds": list(seeds),
        })  # fmt: skip
    return rows


def table(rows: Sequence[dict[str, Any]]) -> str:
    """The sweep as a Markdown table (`COLUMNS`)."""
    cells = [
        [
            str(r["demand"]), f"{r['entered_per_h']:.0f}", f"{r['entered_share']:.3f}",
            f"{r['insertion_wait_s']:.1f}", f"{r['crossing_time_s']:.1f}",
            f"{r['largest_queue_veh']:.1f}", f"{r['lane_changes_per_vehicle']:.2f}",
            str(r["collisions"]), str(r["teleports"]),
        ]
        for r in rows
    ]  # fmt: skip
    return markdown_table(COLUMNS, cells)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jaxround.apps.sumo_capacity")
    parser.add_argument("--config", default="two_lane", help="scenario")
    parser.add_argument(
        "--demands", required=True,
        help="hourly demands, comma-separated (e.g. 2000,2500,3000)",
    )  # fmt: skip
    parser.add_argument("--seeds", type=int, nargs="+", default=list(EVAL_SEEDS))
    parser.add_argument("--workers", type=int, default=None, help="SUMO processes")
    parser.add_argument("--json", action="store_true", help="print JSON rows")
    args = parser.parse_args(argv)
    demands = [int(d) for d in args.demands.split(",")]
    rows = capacity_sweep(load_config(args.config), demands, args.seeds, args.workers)
    print(json.dumps(rows, indent=1) if args.json else table(rows), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
