"""JAX against SUMO on the same departure schedules.

`parity_report` runs every seed's schedule in SUMO (parallel processes) and in
the JAX environment (one vmapped, jitted batch), with the AVs driven the same
way in both (`jaxround.apps.drivers`: uncontrolled, a scripted controller or an
exported policy), and compares the metrics and each vehicle's crossing time.
Both simulators run until every scheduled vehicle has left, or the same cap
(the demand horizon plus `drain_s`, by default
`jaxround.scenario.config.DRAIN_S`), reported with the vehicles still inside
at the cap, run by run. Every mean and every per-vehicle error is over the
same vehicles on both sides: those that arrived in both runs of a schedule.

Past capacity (queues that grow, vehicles left outside at the cap) the
report's "saturation" part is the measure (`jaxround.analysis.saturation`):
per-leg entry rates and crossing-time quantiles over seeds with intervals.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from jaxround.analysis.compare import mean_ci
from jaxround.analysis.metrics import arrived_in_all, class_metrics, mean_over_runs
from jaxround.analysis.saturation import saturation_report
from jaxround.apps.drivers import (
    DriverSpec,
    config_for,
    jax_driver,
    parse_driver,
    sumo_driver,
)
from jaxround.core.capacity import road_capacity
from jaxround.envs.rollout import run_until_left, vehicle_records
from jaxround.envs.roundabout import RoundaboutEnv, make
from jaxround.envs.slots import redo_on_overflow
from jaxround.envs.supported import check_jax_lanes
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.edges import ring_edge
from jaxround.scenario.schedule import make_schedule

COMPARED = (
    "mean_crossing_time_s", "co2_g_per_veh", "fuel_g_per_veh", "n_arrived",
    "conflicts_per_1000_veh",
)  # fmt: skip


def run_jax(
    cfg: ScenarioConfig,
    seeds: Sequence[int],
    penetration: float = 0.0,
    max_vehicles: int | str | None = None,
    driver: DriverSpec | None = None,
    cap_s: float | None = None,
    *,
    crossing_leaders: bool = True,
) -> list[dict[str, Any]]:
    """Run the schedules of `seeds` in JAX, all seeds in one vmapped batch,
    each until its vehicles have left or `cap_s` (default: the episode), with
    `max_vehicles` slots (None: the config's, else what the traffic needs),
    redone with more slots while any run's slots overflow
    (`jaxround.envs.slots.redo_on_overflow`); `crossing_leaders` as
    `jaxround.envs.roundabout.make` takes it.

    Returns:
        One ``{"records": VehicleRecords, "overflow": int, "end_s": float,
        "max_vehicles": int, "max_vehicles_tried": [int, ...]}`` per seed.
    """
    driver = parse_driver(None) if driver is None else driver
    driven = config_for(cfg, driver)
    numpy_schedules = [
        make_schedule(cfg, seed=s, penetration=penetration) for s in seeds
    ]
    keys = jax.random.split(jax.random.PRNGKey(0), len(seeds))

    def run_with(slots: int | str | None) -> tuple[RoundaboutEnv, Any]:
        """Every seed with `slots` vehicle slots, side by side."""
        env, params = make(
            driven, max_vehicles=slots, crossing_leaders=crossing_leaders
        )
        policy = jax_driver(env, params, driver)
        max_steps = None if cap_s is None else int(math.ceil(cap_s / env.dt))
        batch = jax.tree.map(
            lambda *xs: np.stack(xs),
            *[env.schedule_from_numpy(s) for s in numpy_schedules],
        )

        def one(schedule: Any, key: jax.Array) -> Any:
            return run_until_left(env, params, schedule, key, policy, max_steps)

        return env, jax.jit(jax.vmap(one))(batch, keys)

    first = make(driven, max_vehicles=max_vehicles, crossing_leaders=crossing_leaders)[
        0
    ]
    (env, states), tried = redo_on_overflow(
        run_with, lambda run: int(np.sum(run[1].stats.overflow)),
        max_vehicles=first.max_vehicles, road=road_capacity(first.network, driven),
        what="parity (JAX)",
    )  # fmt: skip
    out = []
    for i in range(len(seeds)):
        state = jax.tree.map(lambda x, i=i: x[i], states)
        lanes = state.lanes
        out.append(
            {
                "records": vehicle_records(env, state),
                "collisions": int(state.stats.collisions),
                "lane_changes": 0 if lanes is None else int(np.sum(lanes.changes)),
                "lane_seconds": None
                if lanes is None
                else dict(zip(env.network.lane_ids, lanes.lane_seconds.tolist())),
                "overflow": int(state.stats.overflow),
                "end_s": float(state.step) * env.dt,
                "max_vehicles": env.max_vehicles,
                "max_vehicles_tried": tried,
            }
        )
    return out


def per_vehicle_stats(abs_err: np.ndarray) -> dict[str, float | None]:
    """Median and 90th percentile of per-vehicle |crossing-time error|, exact share."""
    if not abs_err.size:
        return dict.fromkeys(
            ("per_vehicle_median_abs_err_s", "per_vehicle_p90_abs_err_s",
             "per_vehicle_exact_share"),
        )  # fmt: skip
    return {
        "per_vehicle_median_abs_err_s": float(np.median(abs_err)),
        "per_vehicle_p90_abs_err_s": float(np.percentile(abs_err, 90)),
        "per_vehicle_exact_share": float(np.mean(abs_err < 1e-6)),
    }


#: The metrics whose error `seed_errors` gives schedule by schedule.
SEED_COMPARED = ("mean_crossing_time_s", "co2_g_per_veh")


def seed_errors(
    jax_runs: Sequence[dict[str, Any]], sumo_runs: Sequence[dict[str, Any]]
) -> dict[str, dict[str, Any]]:
    """The signed relative error JAX / SUMO - 1 of each schedule, and their
    mean with a 95% t-interval over the schedules (None for one schedule).

    A schedule near capacity varies from run to run by more than the step
    differs from SUMO: the interval says what a parity row's seeds resolve.

    Args:
        jax_runs, sumo_runs: `class_metrics` of each schedule, in the same order.

    Returns:
        ``{metric: {"per_seed": [...], "mean": float, "ci95": [low, high]}}``
        for `SEED_COMPARED`; per-seed entries None where a run has no value.
    """
    out: dict[str, dict[str, Any]] = {}
    for key in SEED_COMPARED:
        errors = [
            _signed_error(j["all"][key], s["all"][key])
            for j, s in zip(jax_runs, sumo_runs, strict=True)
        ]
        known = np.array([e for e in errors if e is not None])
        interval = mean_ci(known)
        out[key] = {
            "per_seed": errors,
            "mean": float(known.mean()) if known.size else None,
            "ci95": None if interval is None else [interval[1], interval[2]],
        }
    return out


def _signed_error(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or b == 0 or not math.isfinite(a) or not math.isfinite(b):
        return None
    return float(a / b - 1.0)


def relative_error(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or b == 0:
        return None
    return float(abs(a - b) / abs(b))


def parity_report(
    cfg: ScenarioConfig,
    seeds: Sequence[int],
    workers: int | None = None,
    show_progress: bool = True,
    penetration: float = 0.0,
    controller: str | None = None,
    max_vehicles: int | str | None = None,
    drain_s: float | None = None,
    crossing_leaders: bool = True,
) -> dict[str, Any]:
    """The `jaxround parity --json` object for the schedules of `seeds`.

    Args:
        controller: the AVs' driver (`jaxround.apps.drivers`); None: uncontrolled
            (their vType).
        max_vehicles: JAX's vehicle slots M; None: the config's, else what
            the traffic needs. Runs whose slots overflow are redone with more;
            the report gives the M of the reported runs, every M tried and the
            slot overflow (vehicle-steps insertions waited for a slot: 0).
        drain_s: seconds after the demand horizon both simulators may go on
            (the cap); None: `DRAIN_S`.
        crossing_leaders: JAX's link leaders on crossing internal lanes
            (`jaxround.envs.roundabout.make`; on by default).

    Returns:
        The means of both simulators ("jax", "sumo": `class_metrics` over the
        vehicles arrived in both runs of each schedule, means over seeds),
        their relative errors, per-vehicle crossing-time errors, the runs
        that left vehicles outside at the cap ("outside_at_cap"), and
        "saturation" (`saturation_report`).

    Raises:
        ValueError: a bad controller spec, before anything runs.
        ConfigError: a two-lane scenario, which JAX does not run yet.
    """
    from jaxround.scenario.config import DRAIN_S
    from sumo_export.runner import run_many

    check_jax_lanes(cfg)  # before SUMO runs: the JAX side would refuse it
    driver = parse_driver(controller)
    cfg = cfg.with_overrides(penetration=penetration)
    drain_s = DRAIN_S if drain_s is None else drain_s
    cap_s = cfg.demand.duration_s + drain_s
    schedules = [make_schedule(cfg, seed=s, penetration=penetration) for s in seeds]
    sumo_runs = run_many(
        config_for(cfg, driver), schedules, workers=workers,
        controller=sumo_driver(driver), drain_s=drain_s,
    )  # fmt: skip
    jax_runs = run_jax(
        cfg, seeds, penetration, max_vehicles, driver=driver, cap_s=cap_s,
        crossing_leaders=crossing_leaders,
    )  # fmt: skip
    horizon = cfg.demand.duration_s
    sumo_records = [r.records for r in sumo_runs]
    jax_records = [r["records"] for r in jax_runs]
    # the same vehicles on both sides: those arrived in both runs of a schedule
    compared = [
        arrived_in_all([a, b]) for a, b in zip(jax_records, sumo_records, strict=True)
    ]

    def per_run(records: list[Any]) -> list[dict[str, Any]]:
        return [
            class_metrics(r, horizon, compared=c)
            for r, c in zip(records, compared, strict=True)
        ]

    sumo_runs_m, jax_runs_m = per_run(sumo_records), per_run(jax_records)
    sumo_m, jax_m = mean_over_runs(sumo_runs_m), mean_over_runs(jax_runs_m)
    errors = [
        np.abs(a.crossing_time_s[c] - b.crossing_time_s[c])
        for a, b, c in zip(sumo_records, jax_records, compared, strict=True)
    ]
    per_vehicle = np.concatenate(errors) if errors else np.zeros(0)

    def left_inside(records: Any) -> int:
        return int(np.sum(~np.isfinite(records.arrival_s)))

    outside = [
        {"sim": sim, "seed": seed, "not_arrived": left_inside(r)}
        for sim, runs in (("jax", jax_records), ("sumo", sumo_records))
        for seed, r in zip(seeds, runs, strict=True)
        if left_inside(r)
    ]

    return {
        "scenario": cfg.name,
        "seeds": list(seeds),
        "penetration": penetration,
        "controller": driver.spec,
        "jax": jax_m,
        "sumo": sumo_m,
        "rel_err": {
            k: relative_error(jax_m["all"][k], sumo_m["all"][k]) for k in COMPARED
        },
        "rel_err_by_seed": seed_errors(jax_runs_m, sumo_runs_m),
        **per_vehicle_stats(per_vehicle),
        "cap_s": cap_s,
        "jax_not_arrived": sum(left_inside(r) for r in jax_records),
        "sumo_not_arrived": sum(left_inside(r) for r in sumo_records),
        "n_compared": int(sum(c.sum() for c in compared)),
        "outside_at_cap": outside,
        "saturation": saturation_report(
            jax_records, sumo_records, compared, cfg.n_legs, horizon
        ),
        "max_vehicles": jax_runs[0]["max_vehicles"],
        "max_vehicles_tried": jax_runs[0]["max_vehicles_tried"],
        "jax_slot_overflow": int(sum(r["overflow"] for r in jax_runs)),
        "jax_collisions": int(sum(r["collisions"] for r in jax_runs)),
        "sumo_collisions": int(sum(r.collisions for r in sumo_runs)),
        "sumo_teleports": int(sum(r.teleports for r in sumo_runs)),
        "sumo_conflict_types": conflict_types(sumo_runs),
        **({} if cfg.network.single_lane else lane_comparison(
            cfg, schedules, jax_runs, sumo_runs
        )),
    }  # fmt: skip


def lane_figures(
    cfg: ScenarioConfig, n_vehicles: int, changes: int, seconds: list[dict[str, float]]
) -> dict[str, float | None]:
    """Lane changes per vehicle, and the inner ring lane's share of the time
    vehicles spent on the ring's lanes (normal ring edges, as SUMO's lane
    data counts them), over the runs of one simulator."""
    outer = inner = 0.0
    for run in seconds:
        for leg in range(cfg.n_legs):
            outer += run.get(f"{ring_edge(leg)}_0", 0.0)
            inner += run.get(f"{ring_edge(leg)}_1", 0.0)
    return {
        "lane_changes_per_veh": changes / max(n_vehicles, 1),
        "inner_ring_share": inner / (inner + outer) if inner + outer > 0 else None,
    }


def lane_comparison(
    cfg: ScenarioConfig,
    schedules: Sequence[Any],
    jax_runs: Sequence[dict[str, Any]],
    sumo_runs: Sequence[Any],
) -> dict[str, Any]:
    """`parity_report`'s figures of a roundabout with two-lane roads: both
    simulators' `lane_figures`, the relative error of the lane changes per
    vehicle and the difference of the inner ring lane's share (points)."""
    n = sum(s.n_vehicles for s in schedules)
    jax_lanes = lane_figures(
        cfg, n, sum(r["lane_changes"] for r in jax_runs),
        [r["lane_seconds"] or {} for r in jax_runs],
    )  # fmt: skip
    sumo_lanes = lane_figures(
        cfg, n, sum(r.lane_changes for r in sumo_runs),
        [r.lane_seconds or {} for r in sumo_runs],
    )  # fmt: skip
    share = (jax_lanes["inner_ring_share"], sumo_lanes["inner_ring_share"])
    return {
        "lanes": {"jax": jax_lanes, "sumo": sumo_lanes},
        "lane_changes_rel_err": relative_error(
            jax_lanes["lane_changes_per_veh"], sumo_lanes["lane_changes_per_veh"]
        ),
        "inner_ring_share_diff_points": None
        if None in share
        else 100.0 * abs(share[0] - share[1]),
    }


def conflict_types(runs: Sequence[Any]) -> dict[str, int]:
    """The SSM device's conflicts of SUMO runs by encounter type, summed."""
    total: dict[str, int] = {}
    for run in runs:
        for kind, count in (run.conflict_types or {}).items():
            total[kind] = total.get(kind, 0) + count
    return total
