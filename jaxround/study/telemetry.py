"""A ride's trace summed up: gaps, time to collision, hard brakings, delays."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

#: A deceleration at or beyond this is a hard braking, m/s^2 (about 0.4 g,
#: the threshold naturalistic-driving studies commonly use).
HARD_BRAKING_MPS2 = 4.0


def percentile(values: Sequence[float], q: float) -> float | None:
    """The q-th percentile (linear interpolation, NumPy's default); None if empty."""
    if len(values) == 0:
        return None
    return float(np.percentile(np.asarray(values, np.float64), q))


def hard_brakings(trace: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """One ``ride_events`` row per hard braking: where the ego's deceleration
    first reaches `HARD_BRAKING_MPS2` after being below it."""
    events = []
    braking = False
    for row in trace:
        accel = row.get("accel_mps2")
        hard = accel is not None and accel <= -HARD_BRAKING_MPS2
        if hard and not braking:
            events.append(
                {
                    "time_s": row["time_s"],
                    "kind": "hard_braking",
                    "other": None,
                    "detail": f"{-accel:.1f} m/s^2",
                }
            )
        braking = hard
    return events


def _min_of(trace: Sequence[dict[str, Any]], key: str) -> float | None:
    values = [row[key] for row in trace if row.get(key) is not None]
    return float(min(values)) if values else None


def summarize(
    trace: Sequence[dict[str, Any]],
    events: Sequence[dict[str, Any]],
    entered_s: float | None,
    crossings: Sequence[float],
    late_steps: int,
) -> dict[str, Any]:
    """The ``rides`` columns that a ride process computes.

    Args:
        trace: one row per step (``ride_steps`` columns, timings included).
        events: its collision and hard-braking events.
        entered_s: simulated time the ego first entered (None: it never did).
        crossings: crossing time of each pass it finished (entry to exit), s.
        late_steps: steps that started more than a step late.

    Returns:
        steps, ego_entered_s, crossing_time_s (the mean over the passes
        finished), min_gap_m, min_ttc_s,
        hard_brakings, collisions, late_steps, compute_median_ms,
        compute_p99_ms.
    """
    compute = [
        r["sumo_ms"] + r["policy_ms"] + r["frame_ms"]
        for r in trace
        if r.get("frame_ms") is not None
    ]
    crossing = round(float(np.mean(crossings)), 3) if len(crossings) else None
    return {
        "steps": len(trace),
        "ego_entered_s": entered_s,
        "crossing_time_s": crossing,
        "min_gap_m": _min_of(trace, "gap_m"),
        "min_ttc_s": _min_of(trace, "ttc_s"),
        "hard_brakings": sum(e["kind"] == "hard_braking" for e in events),
        "collisions": sum(e["kind"] == "collision" for e in events),
        "late_steps": late_steps,
        "compute_median_ms": percentile(compute, 50),
        "compute_p99_ms": percentile(compute, 99),
    }


def server_figures(
    delays_ms: Sequence[float], latencies_ms: Sequence[float], frames_dropped: int
) -> dict[str, Any]:
    """The ``rides`` columns that the server adds: its delay per step and the
    browser's input-to-frame latency."""
    return {
        "delay_median_ms": percentile(delays_ms, 50),
        "delay_p99_ms": percentile(delays_ms, 99),
        "latency_median_ms": percentile(latencies_ms, 50),
        "latency_samples": len(latencies_ms),
        "frames_dropped": frames_dropped,
    }
