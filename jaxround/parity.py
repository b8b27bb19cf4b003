"""JAX against SUMO on the same HV-only departure schedules.

`parity_report` runs every seed's schedule in SUMO (parallel processes) and in
the JAX environment (one vmapped, jitted batch), and compares the metrics and
each vehicle's crossing time.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from jaxround.config import ScenarioConfig
from jaxround.env import make
from jaxround.metrics import class_metrics, mean_over_runs
from jaxround.rollout import make_episode_runner, vehicle_records
from jaxround.schedule import make_schedule

COMPARED = ("mean_crossing_time_s", "co2_g_per_veh", "fuel_g_per_veh", "n_arrived")


def run_jax(
    cfg: ScenarioConfig,
    seeds: Sequence[int],
    penetration: float = 0.0,
    max_vehicles: int = 32,
) -> list[dict[str, Any]]:
    """Run the schedules of `seeds` in JAX, all seeds in one vmapped batch.

    Returns:
        One ``{"records": VehicleRecords, "overflow": int}`` per seed.
    """
    env, params = make(cfg, max_vehicles=max_vehicles)
    schedules = [
        env.schedule_from_numpy(make_schedule(cfg, seed=s, penetration=penetration))
        for s in seeds
    ]
    batch = jax.tree.map(lambda *xs: np.stack(xs), *schedules)
    runner = make_episode_runner(env)
    keys = jax.random.split(jax.random.PRNGKey(0), len(seeds))
    states = jax.vmap(runner, in_axes=(None, 0, 0))(params, batch, keys)
    out = []
    for i in range(len(seeds)):
        state = jax.tree.map(lambda x, i=i: x[i], states)
        out.append(
            {"records": vehicle_records(env, state), "overflow": int(state.overflow)}
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
) -> dict[str, Any]:
    """The `jaxround parity --json` object for the schedules of `seeds`.

    With `penetration` > 0 the AVs drive uncontrolled (their IDM vType) in
    both simulators.
    """
    from sumo_export.runner import run_many

    cfg = cfg.with_overrides(penetration=penetration)
    schedules = [make_schedule(cfg, seed=s, penetration=penetration) for s in seeds]
    sumo_runs = run_many(cfg, schedules, workers=workers)
    jax_runs = run_jax(cfg, seeds, penetration=penetration)
    horizon = cfg.demand.duration_s
    sumo_m = mean_over_runs([class_metrics(r.records, horizon) for r in sumo_runs])
    jax_m = mean_over_runs([class_metrics(r["records"], horizon) for r in jax_runs])
    errors = []
    for s_run, j_run in zip(sumo_runs, jax_runs, strict=True):
        a = s_run.records.crossing_time_s
        b = j_run["records"].crossing_time_s
        both = np.isfinite(a) & np.isfinite(b)
        errors.append(np.abs(a[both] - b[both]))
    per_vehicle = np.concatenate(errors) if errors else np.zeros(0)
    return {
        "scenario": cfg.name,
        "seeds": list(seeds),
        "penetration": penetration,
        "jax": jax_m,
        "sumo": sumo_m,
        "rel_err": {
            k: relative_error(jax_m["all"][k], sumo_m["all"][k]) for k in COMPARED
        },
        **per_vehicle_stats(per_vehicle),
        "jax_slot_overflow": int(sum(r["overflow"] for r in jax_runs)),
        "sumo_collisions": int(sum(r.collisions for r in sumo_runs)),
    }
