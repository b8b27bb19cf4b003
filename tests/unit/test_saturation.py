"""Parity past capacity: entry rates and crossing-time quantiles, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from jaxround.analysis.saturation import (
    crossing_quantiles,
    entry_rates,
    saturation_report,
)
from jaxround.scenario.records import VehicleRecords

NAN = np.nan


def records(depart: list[float], arrival: list[float]) -> VehicleRecords:
    """Four vehicles from legs 0, 0, 1, 2, scheduled at 0 s."""
    return VehicleRecords(
        is_av=np.zeros(4, bool),
        origin=np.array([0, 0, 1, 2]),
        scheduled_depart_s=np.zeros(4),
        depart_s=np.asarray(depart, np.float64),
        arrival_s=np.asarray(arrival, np.float64),
        co2_g=np.ones(4),
        fuel_g=np.ones(4),
        queue_mean_veh=np.zeros(3),
        queue_max_veh=np.zeros(3),
    )


def test_entry_rates_count_insertions_within_the_horizon() -> None:
    # horizon 1800 s: vehicle 1 enters after it, vehicle 3 never
    r = records([0.0, 1900.0, 10.0, NAN], [30.0, NAN, 40.0, NAN])
    np.testing.assert_allclose(entry_rates(r, 3, 1800.0), [2.0, 2.0, 0.0])


def test_quantiles_and_intervals_over_seeds() -> None:
    both = np.array([True, False, True, True])
    a = records([0.0, 0.0, 0.0, 0.0], [10.0, NAN, 20.0, 30.0])
    np.testing.assert_allclose(crossing_quantiles(a, both), [12.0, 20.0, 28.0])
    b = records([0.0, 0.0, 0.0, 0.0], [12.0, 99.0, 22.0, 32.0])
    c = records([0.0, 0.0, 0.0, NAN], [10.0, NAN, 20.0, NAN])
    report = saturation_report([a, b], [b, a], [both, both & c.arrived], 3, 3600.0)
    rates = report["entry_rate_veh_per_h"]
    assert rates["jax"]["mean"] == [2.0, 1.0, 1.0]
    assert rates["diff"]["mean"] == [0.0, 0.0, 0.0]
    median = report["crossing_time_quantiles_s"]["diff"]
    # seed 0: JAX a, SUMO b over vehicles 0, 2, 3: medians 20 and 22 -> -2;
    # seed 1: JAX b, SUMO a over vehicles 0 and 2: 17 - 15 -> +2
    assert median["per_seed"][0][1] == pytest.approx(-2.0)
    assert median["per_seed"][1][1] == pytest.approx(2.0)
    assert median["mean"][1] == pytest.approx(0.0)
    low, high = median["ci95"][1]
    assert low == pytest.approx(-12.706 * 2.0) and high == pytest.approx(25.412)
