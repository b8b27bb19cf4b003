"""A policy against a baseline on the same schedules: paired differences.

Both runs of a pair drive the same scheduled vehicles (same departures,
routes and classes), so each vehicle's crossing time and CO2 can be compared
with itself. `paired_difference` gives the mean difference (policy minus
baseline) with two 95% confidence intervals:

- over schedules (seeds): a t-interval of the per-seed differences of the
  means; the honest one, since the vehicles of one run are not independent;
- over vehicles: a t-interval of the per-vehicle differences, pooled over
  the seeds; narrower, and optimistic for the same reason.

A vehicle counts when it arrived in both runs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxround.scenario.records import VehicleRecords

#: Two-sided 95% quantiles of Student's t for 1..30 degrees of freedom.
_T95 = (
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228,
    2.201, 2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086,
    2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042,
)  # fmt: skip
#: Metrics compared: name in the result -> `VehicleRecords` attribute.
METRICS = {
    "crossing_time_s": "crossing_time_s",
    "co2_g": "co2_g",
    "conflicts_per_1000_veh": "conflicts_per_1000",
}
#: Vehicle classes: name -> mask of `VehicleRecords.is_av`, None for all.
CLASSES = {"all": None, "hv": False, "av": True}


def t95(dof: int) -> float:
    """The two-sided 95% quantile of Student's t with `dof` degrees of freedom."""
    if dof < 1:
        raise ValueError(f"t95: {dof} degrees of freedom, expected >= 1")
    return _T95[dof - 1] if dof <= len(_T95) else 1.960


def mean_ci(values: np.ndarray) -> tuple[float, float, float] | None:
    """(mean, low, high): the mean with its 95% t-interval; None for < 2 values."""
    values = np.asarray(values, np.float64)
    if values.size < 2:
        return None
    mean = float(values.mean())
    half = t95(values.size - 1) * float(values.std(ddof=1)) / math.sqrt(values.size)
    return mean, mean - half, mean + half


def paired_difference(
    policy: Sequence[VehicleRecords],
    baseline: Sequence[VehicleRecords],
    vehicle_class: str = "all",
) -> dict[str, Any]:
    """Policy minus baseline, per metric, over runs of the same schedules.

    Args:
        policy: one `VehicleRecords` per schedule, with the policy driving.
        baseline: the same schedules, in the same order, with the baseline.
        vehicle_class: "all", "hv" or "av".

    Returns:
        ``{metric: {"baseline", "policy", "diff", "rel_diff", "ci95_seeds",
        "ci95_vehicles", "per_seed_diff", "n_vehicles"}}`` for metrics
        crossing_time_s, co2_g and conflicts_per_1000_veh (None where a run
        did not count conflicts); intervals are ``[low, high]`` of the
        difference (None where there are too few values).

    Raises:
        ValueError: the runs do not pair up (counts, or other vehicles).
    """
    if len(policy) != len(baseline) or not policy:
        raise ValueError(
            f"paired_difference: {len(policy)} policy runs against "
            f"{len(baseline)} baseline runs; expected the same number, at least 1"
        )
    if vehicle_class not in CLASSES:
        raise ValueError(f"vehicle_class {vehicle_class!r}, expected one of {CLASSES}")
    out: dict[str, Any] = {}
    for name, attr in METRICS.items():
        seed_diff, seed_base, seed_pol, pooled = [], [], [], []
        for a, b in zip(policy, baseline, strict=True):
            if not np.array_equal(a.is_av, b.is_av):
                raise ValueError("paired_difference: the runs hold other vehicles")
            mask = a.arrived & b.arrived
            if CLASSES[vehicle_class] is not None:
                mask &= a.is_av == CLASSES[vehicle_class]
            values_a, values_b = getattr(a, attr), getattr(b, attr)
            if not mask.any() or values_a is None or values_b is None:
                continue
            va, vb = values_a[mask], values_b[mask]
            pooled.append(va - vb)
            seed_pol.append(float(va.mean()))
            seed_base.append(float(vb.mean()))
            seed_diff.append(float((va - vb).mean()))
        if not pooled:
            out[name] = None
            continue
        diffs = np.concatenate(pooled)
        base = float(np.mean(seed_base))
        by_seed = mean_ci(np.asarray(seed_diff))
        by_vehicle = mean_ci(diffs)
        out[name] = {
            "baseline": base,
            "policy": float(np.mean(seed_pol)),
            "diff": float(np.mean(seed_diff)),
            "rel_diff": float(np.mean(seed_diff)) / base if base else None,
            "ci95_seeds": None if by_seed is None else [by_seed[1], by_seed[2]],
            "ci95_vehicles": None if by_vehicle is None else list(by_vehicle[1:]),
            "per_seed_diff": seed_diff,
            "n_vehicles": int(diffs.size),
        }
    return out
