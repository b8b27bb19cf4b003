"""Metrics shared by every report: crossing time, emissions, scores, queues.

Both simulators reduce a run to `VehicleRecords` (one row per scheduled
vehicle plus per-leg queue samples); `class_metrics` turns records into the
numbers of the paper's tables:

- crossing time (Eq. 4): arrival minus scheduled departure, so the time a
  vehicle waits to be inserted behind a queue counts too;
- consumption and emission scores (Eq. 5): fuel and CO2 per vehicle min-max
  normalised, then averaged over the class. The minimum and maximum are taken
  over every run a table compares (`sweep_scale`, "sweep": one scale, so rows
  of a sweep can be compared, the paper's reading) or over the run's own
  vehicles (no `scale`, "run": both classes of the run share it, rows of
  different runs do not);
- CO2 and fuel in g per vehicle, arrivals, throughput, queue length per leg.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from jaxround.scenario.records import VehicleRecords

CLASSES = ("all", "hv", "av")
#: Eq. 5's scales: one over every run compared, or each run its own.
SCORE_SCALES = ("sweep", "run")


@dataclass(frozen=True)
class ScoreScale:
    """Eq. 5's (min, max) of fuel and of CO2 per vehicle, g.

    Attributes:
        over: the runs the bounds were taken over: "sweep" (every run of a
            table) or "joint" (every run of JAX and SUMO together).
    """

    fuel_g: tuple[float, float]
    co2_g: tuple[float, float]
    over: str = "sweep"


def sweep_scale(
    runs: Iterable[VehicleRecords], over: str = "sweep"
) -> ScoreScale | None:
    """Eq. 5's minimum and maximum over the arrived vehicles of every run
    (None if none arrived); `over` names those runs (`ScoreScale.over`)."""
    fuel, co2 = [], []
    for records in runs:
        fuel.append(records.fuel_g[records.arrived & np.isfinite(records.fuel_g)])
        co2.append(records.co2_g[records.arrived & np.isfinite(records.co2_g)])
    fuel_all, co2_all = np.concatenate(fuel or [[]]), np.concatenate(co2 or [[]])
    if not fuel_all.size or not co2_all.size:
        return None
    return ScoreScale(
        fuel_g=(float(fuel_all.min()), float(fuel_all.max())),
        co2_g=(float(co2_all.min()), float(co2_all.max())),
        over=over,
    )


def min_max_scores(
    values: np.ndarray, bounds: tuple[float, float] | None = None
) -> np.ndarray:
    """The paper's Eq. 5 per vehicle: (x - min) / (max - min).

    Args:
        values: float (N,), nan where a vehicle has no value.
        bounds: (min, max) to use; None: those of the finite `values`.

    Returns:
        float (N,), in [0, 1] when the bounds hold every value; nan where
        `values` is nan; all 0 when max == min.
    """
    ok = np.isfinite(values)
    out = np.full(values.shape, np.nan)
    if not ok.any():
        return out
    lo, hi = (values[ok].min(), values[ok].max()) if bounds is None else bounds
    out[ok] = (values[ok] - lo) / (hi - lo) if hi > lo else 0.0
    return out


def class_metrics(
    records: VehicleRecords,
    horizon_s: float,
    *,
    compared: np.ndarray | None = None,
    scale: ScoreScale | None = None,
) -> dict[str, Any]:
    """Metrics per class: ``{"all": M, "hv": M, "av": M}``.

    Each M has ``n_vehicles, n_departed, n_arrived, n_not_arrived, n_compared,
    mean_crossing_time_s, co2_g_per_veh, fuel_g_per_veh, consumption_score,
    emission_score, throughput_veh_per_h, mean_insertion_delay_s`` and the
    near-conflicts (`safety_metrics`: ``conflicts_per_1000_veh, min_ttc_s,
    max_drac_mps2``, over every vehicle of the class) and
    ``lane_changes_per_veh`` (over the compared vehicles; None on roads of
    one lane, `VehicleRecords.lane_changes`); "all" also has
    ``queue_mean_veh`` and ``queue_max_veh`` (lists, one per leg).
    Means over an empty class are None.

    Args:
        records: one run.
        horizon_s: the demand horizon (throughput counts arrivals before it).
        compared: bool (N,) the vehicles the means (crossing time, CO2, fuel,
            scores, insertion delay) are taken over, those arrived in every
            run compared (`arrived_in_all`); None: this run's arrived
            vehicles (its departed ones for the insertion delay).
        scale: Eq. 5's bounds (`sweep_scale`); None: this run's own.

    Raises:
        ValueError: `compared` holds a vehicle that did not arrive.
    """
    # insertion delays over the departed vehicles, or the compared ones
    delayed = records.departed if compared is None else compared
    if compared is None:
        compared = records.arrived
    elif np.any(compared & ~records.arrived):
        raise ValueError("class_metrics: compared vehicles must have arrived")
    fuel = np.where(records.arrived, records.fuel_g, np.nan)
    co2 = np.where(records.arrived, records.co2_g, np.nan)
    consumption = min_max_scores(fuel, None if scale is None else scale.fuel_g)
    emission = min_max_scores(co2, None if scale is None else scale.co2_g)
    masks = {
        "all": np.ones_like(records.is_av, dtype=bool),
        "hv": ~records.is_av,
        "av": records.is_av,
    }
    out: dict[str, Any] = {}
    for name, mask in masks.items():
        arrived = mask & records.arrived
        mean_over = mask & compared
        departed = mask & records.departed
        in_horizon = arrived & (records.arrival_s <= horizon_s)
        out[name] = {
            "n_vehicles": int(mask.sum()),
            "n_departed": int(departed.sum()),
            "n_arrived": int(arrived.sum()),
            "n_not_arrived": int((mask & ~records.arrived).sum()),
            "n_compared": int(mean_over.sum()),
            "mean_crossing_time_s": _mean(records.crossing_time_s[mean_over]),
            "co2_g_per_veh": _mean(records.co2_g[mean_over]),
            "fuel_g_per_veh": _mean(records.fuel_g[mean_over]),
            "consumption_score": _mean(consumption[mean_over]),
            "emission_score": _mean(emission[mean_over]),
            "throughput_veh_per_h": float(in_horizon.sum() * 3600.0 / horizon_s),
            "mean_insertion_delay_s": _mean(
                (records.depart_s - records.scheduled_depart_s)[mask & delayed]
            ),
            **safety_metrics(records, mask),
            "lane_changes_per_veh": None
            if records.lane_changes is None
            else _mean(records.lane_changes[mean_over].astype(np.float64)),
        }
    out["all"]["queue_mean_veh"] = [float(x) for x in records.queue_mean_veh]
    out["all"]["queue_max_veh"] = [float(x) for x in records.queue_max_veh]
    return out


def safety_metrics(records: VehicleRecords, mask: np.ndarray) -> dict[str, Any]:
    """Near-conflicts of the vehicles in `mask`, bool (N,): conflicts per
    1,000 of them (each conflict counts for both vehicles of the pair, as
    SUMO's SSM device writes it), the smallest TTC (s) and largest DRAC
    (m/s^2) among their conflicts; None where the run did not count them,
    and for TTC and DRAC where there was no conflict."""
    if records.conflicts is None:
        return dict.fromkeys(("conflicts_per_1000_veh", "min_ttc_s", "max_drac_mps2"))
    n = int(mask.sum())
    ttc = records.min_ttc_s[mask & np.isfinite(records.min_ttc_s)]
    drac = records.max_drac_mps2[mask & np.isfinite(records.max_drac_mps2)]
    return {
        "conflicts_per_1000_veh": (
            float(records.conflicts[mask].sum() * 1000.0 / n) if n else None
        ),
        "min_ttc_s": float(ttc.min()) if ttc.size else None,
        "max_drac_mps2": float(drac.max()) if drac.size else None,
    }


def arrived_in_all(runs: Iterable[VehicleRecords]) -> np.ndarray:
    """bool (N,): the vehicles that arrived in every run (runs of one schedule).

    Raises:
        ValueError: no runs, or runs of different vehicles.
    """
    runs = list(runs)
    if not runs:
        raise ValueError("arrived_in_all: no runs")
    both = np.ones(runs[0].is_av.shape, bool)
    for records in runs:
        if not np.array_equal(records.is_av, runs[0].is_av):
            raise ValueError("arrived_in_all: the runs hold other vehicles")
        both &= records.arrived
    return both


def mean_over_runs(per_run: list[dict[str, Any]]) -> dict[str, Any]:
    """Average metric dicts of several runs key by key (None where every run has None).

    Lists are averaged element-wise; a key with None in some runs is averaged
    over the runs that have a value.
    """
    first = per_run[0]
    out: dict[str, Any] = {}
    for key, value in first.items():
        values = [r[key] for r in per_run]
        if isinstance(value, dict):
            out[key] = mean_over_runs(values)
        elif (
            isinstance(value, list)
            or value is None
            and any(isinstance(v, list) for v in values)
        ):
            arrays = [np.asarray(v, dtype=float) for v in values if v is not None]
            out[key] = np.mean(arrays, axis=0).tolist() if arrays else None
        else:
            present = [float(v) for v in values if v is not None]
            out[key] = float(np.mean(present)) if present else None
    return out


def _mean(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else None
