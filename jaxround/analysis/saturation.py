"""Parity past capacity: what two simulators should share once queues grow.

Past capacity a small difference (one insertion a step earlier, one speed a
little higher) reorders a queue, and every vehicle behind it then crosses at
another time: per-vehicle errors grow as in any chaotic system, even when
both simulators carry the same traffic. What they should share is the
traffic itself: how many vehicles each leg lets in per hour, and the
distribution of crossing times. `saturation_report` gives both per seed and
their mean over seeds with a 95% t-interval, for each simulator and for the
paired difference (same schedule, JAX minus SUMO).

Every figure is over the same vehicles in both simulators: entry rates count
insertions within the demand horizon (each simulator's own, a rate), and the
crossing-time quantiles are over the vehicles that arrived in both runs of a
schedule.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxround.analysis.compare import mean_ci
from jaxround.scenario.records import VehicleRecords

#: Crossing-time quantiles reported (percent).
QUANTILES = (10, 50, 90)


def entry_rates(records: VehicleRecords, n_legs: int, horizon_s: float) -> np.ndarray:
    """float (n_legs,): vehicles inserted on each leg per hour, within the
    demand horizon."""
    entered = records.departed & (records.depart_s <= horizon_s)
    counts = np.bincount(records.origin[entered].astype(int), minlength=n_legs)
    return counts[:n_legs] * 3600.0 / horizon_s


def crossing_quantiles(records: VehicleRecords, compared: np.ndarray) -> np.ndarray:
    """float (len(QUANTILES),): crossing-time quantiles (s) of the `compared`
    vehicles (nan if none)."""
    times = records.crossing_time_s[compared]
    if not times.size:
        return np.full(len(QUANTILES), np.nan)
    return np.percentile(times, QUANTILES)


def interval(values: np.ndarray) -> dict[str, Any]:
    """``{"mean", "ci95"}`` over seeds (axis 0); ci95 is None for one seed.

    Args:
        values: float (S,) or (S, K): one row per seed.
    """
    values = np.asarray(values, np.float64)
    flat = values.reshape(values.shape[0], -1)
    means, cis = [], []
    for column in flat.T:
        column = column[np.isfinite(column)]
        ci = mean_ci(column)
        means.append(float(column.mean()) if column.size else None)
        cis.append(None if ci is None else [ci[1], ci[2]])
    if values.ndim == 1:
        return {"mean": means[0], "ci95": cis[0]}
    return {"mean": means, "ci95": cis}


def saturation_report(
    jax_runs: Sequence[VehicleRecords],
    sumo_runs: Sequence[VehicleRecords],
    compared: Sequence[np.ndarray],
    n_legs: int,
    horizon_s: float,
) -> dict[str, Any]:
    """Entry rates per leg and crossing-time quantiles, per simulator and
    JAX minus SUMO, each as mean and 95% interval over seeds.

    Args:
        jax_runs, sumo_runs: one `VehicleRecords` per seed, the same schedules
            in the same order.
        compared: per seed, bool (N,) the vehicles arrived in both runs.
        n_legs: legs of the roundabout.
        horizon_s: the demand horizon.

    Returns:
        ``{"quantiles": [10, 50, 90], "entry_rate_veh_per_h": {"jax", "sumo",
        "diff": {"mean": [per leg], "ci95": [[low, high] per leg],
        "per_seed": [[per leg] per seed]}}, "crossing_time_quantiles_s":
        {same, per quantile}}``.
    """
    rates = {
        "jax": np.array([entry_rates(r, n_legs, horizon_s) for r in jax_runs]),
        "sumo": np.array([entry_rates(r, n_legs, horizon_s) for r in sumo_runs]),
    }
    quantiles = {
        "jax": np.array(
            [crossing_quantiles(r, c) for r, c in zip(jax_runs, compared, strict=True)]
        ),
        "sumo": np.array(
            [crossing_quantiles(r, c) for r, c in zip(sumo_runs, compared, strict=True)]
        ),
    }

    def summary(per_sim: dict[str, np.ndarray]) -> dict[str, Any]:
        per_sim = {**per_sim, "diff": per_sim["jax"] - per_sim["sumo"]}
        return {
            name: {**interval(values), "per_seed": values.tolist()}
            for name, values in per_sim.items()
        }

    return {
        "quantiles": list(QUANTILES),
        "entry_rate_veh_per_h": summary(rates),
        "crossing_time_quantiles_s": summary(quantiles),
    }


def saturation_rows(report: dict[str, Any]) -> list[list[str]]:
    """Rows of `SATURATION_COLUMNS` for the printed parity report."""

    def cell(entry: dict[str, Any], i: int) -> str:
        mean, ci = entry["mean"][i], entry["ci95"][i]
        if mean is None:
            return "-"
        return f"{mean:.1f}" if ci is None else f"{mean:.1f} [{ci[0]:.1f}, {ci[1]:.1f}]"

    rows = []
    rates = report["entry_rate_veh_per_h"]
    for leg in range(len(rates["jax"]["mean"])):
        rows.append(
            [f"entries/h, leg {leg}"] + [cell(rates[k], leg) for k in SIMS_AND_DIFF]
        )
    times = report["crossing_time_quantiles_s"]
    for i, q in enumerate(report["quantiles"]):
        rows.append(
            [f"crossing time p{q} (s)"] + [cell(times[k], i) for k in SIMS_AND_DIFF]
        )
    return rows


SIMS_AND_DIFF = ("jax", "sumo", "diff")
#: Columns of `saturation_rows`: mean over seeds [95% interval].
SATURATION_COLUMNS = ("measure", "JAX", "SUMO", "JAX - SUMO")

__all__ = [
    "QUANTILES",
    "SATURATION_COLUMNS",
    "crossing_quantiles",
    "entry_rates",
    "interval",
    "saturation_report",
    "saturation_rows",
]
