"""Metrics shared by every report: crossing time, emissions, scores, queues.

Both simulators reduce a run to `VehicleRecords` (one row per scheduled
vehicle plus per-leg queue samples); `class_metrics` turns records into the
numbers of the paper's tables:

- crossing time (Eq. 4): arrival minus scheduled departure, so the time a
  vehicle waits to be inserted behind a queue counts too;
- consumption and emission scores (Eq. 5): fuel and CO2 per vehicle min-max
  normalised over all vehicles of the run (both classes share the scale), then
  averaged over the class;
- CO2 and fuel in g per vehicle, arrivals, throughput, queue length per leg.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jaxround.scenario.records import VehicleRecords

CLASSES = ("all", "hv", "av")


def min_max_scores(values: np.ndarray) -> np.ndarray:
    """The paper's Eq. 5 per vehicle: (x - min) / (max - min) over finite values.

    Args:
        values: float (N,), nan where a vehicle has no value.

    Returns:
        float (N,) in [0, 1], nan where `values` is nan; all 0 when max == min.
    """
    ok = np.isfinite(values)
    out = np.full(values.shape, np.nan)
    if not ok.any():
        return out
    lo, hi = values[ok].min(), values[ok].max()
    out[ok] = (values[ok] - lo) / (hi - lo) if hi > lo else 0.0
    return out


def class_metrics(records: VehicleRecords, horizon_s: float) -> dict[str, Any]:
    """Metrics per class: ``{"all": M, "hv": M, "av": M}``.

    Each M has ``n_vehicles, n_departed, n_arrived, mean_crossing_time_s,
    co2_g_per_veh, fuel_g_per_veh, consumption_score, emission_score,
    throughput_veh_per_h, mean_insertion_delay_s``; "all" also has
    ``queue_mean_veh`` and ``queue_max_veh`` (lists, one per leg). Means over
    an empty class are None.
    """
    consumption = min_max_scores(np.where(records.arrived, records.fuel_g, np.nan))
    emission = min_max_scores(np.where(records.arrived, records.co2_g, np.nan))
    masks = {
        "all": np.ones_like(records.is_av, dtype=bool),
        "hv": ~records.is_av,
        "av": records.is_av,
    }
    out: dict[str, Any] = {}
    for name, mask in masks.items():
        arrived = mask & records.arrived
        departed = mask & records.departed
        in_horizon = arrived & (records.arrival_s <= horizon_s)
        out[name] = {
            "n_vehicles": int(mask.sum()),
            "n_departed": int(departed.sum()),
            "n_arrived": int(arrived.sum()),
            "mean_crossing_time_s": _mean(records.crossing_time_s[arrived]),
            "co2_g_per_veh": _mean(records.co2_g[arrived]),
            "fuel_g_per_veh": _mean(records.fuel_g[arrived]),
            "consumption_score": _mean(consumption[arrived]),
            "emission_score": _mean(emission[arrived]),
            "throughput_veh_per_h": float(in_horizon.sum() * 3600.0 / horizon_s),
            "mean_insertion_delay_s": _mean(
                (records.depart_s - records.scheduled_depart_s)[departed]
            ),
        }
    out["all"]["queue_mean_veh"] = [float(x) for x in records.queue_mean_veh]
    out["all"]["queue_max_veh"] = [float(x) for x in records.queue_max_veh]
    return out


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
