"""Metrics against values computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from jaxround.analysis.metrics import (
    VehicleRecords,
    class_metrics,
    mean_over_runs,
    min_max_scores,
)

NAN = np.nan


def records() -> VehicleRecords:
    # Four vehicles: two HVs, two AVs; the last AV never arrives.
    return VehicleRecords(
        is_av=np.array([False, False, True, True]),
        origin=np.array([0, 1, 0, 1]),
        scheduled_depart_s=np.array([0.0, 10.0, 20.0, 30.0]),
        depart_s=np.array([0.0, 12.0, 20.0, 30.0]),
        arrival_s=np.array([20.0, 40.0, 35.0, NAN]),
        co2_g=np.array([50.0, 90.0, 60.0, NAN]),
        fuel_g=np.array([16.0, 30.0, 23.0, NAN]),
        queue_mean_veh=np.array([1.0, 2.0]),
        queue_max_veh=np.array([2.0, 3.0]),
    )


def test_min_max_scores() -> None:
    np.testing.assert_allclose(
        min_max_scores(np.array([50.0, 90.0, 60.0, NAN])), [0.0, 1.0, 0.25, NAN]
    )
    np.testing.assert_array_equal(min_max_scores(np.array([3.0, 3.0])), [0.0, 0.0])


def test_class_metrics_by_hand() -> None:
    m = class_metrics(records(), horizon_s=36.0)
    # crossing times: 20, 30 (HV), 15 (AV); the unarrived AV is left out.
    assert m["all"]["mean_crossing_time_s"] == pytest.approx((20 + 30 + 15) / 3)
    assert m["hv"]["mean_crossing_time_s"] == pytest.approx(25.0)
    assert m["av"]["mean_crossing_time_s"] == pytest.approx(15.0)
    assert m["av"]["n_vehicles"] == 2 and m["av"]["n_arrived"] == 1
    assert m["all"]["n_departed"] == 4 and m["all"]["n_arrived"] == 3
    assert m["hv"]["co2_g_per_veh"] == pytest.approx(70.0)
    assert m["hv"]["fuel_g_per_veh"] == pytest.approx(23.0)
    # emission score over all arrived vehicles: 0, 1, 0.25.
    assert m["hv"]["emission_score"] == pytest.approx(0.5)
    assert m["av"]["emission_score"] == pytest.approx(0.25)
    # consumption: fuel 16, 30, 23 -> 0, 1, 0.5.
    assert m["av"]["consumption_score"] == pytest.approx(0.5)
    # arrivals by t = 36 s: 20 and 35 -> 2 in 36 s = 200 veh/h.
    assert m["all"]["throughput_veh_per_h"] == pytest.approx(200.0)
    assert m["hv"]["mean_insertion_delay_s"] == pytest.approx(1.0)
    assert m["all"]["queue_mean_veh"] == pytest.approx([1.0, 2.0])
    assert m["all"]["queue_max_veh"] == pytest.approx([2.0, 3.0])


def test_empty_class_is_none() -> None:
    r = records()
    r = VehicleRecords(**{**r.__dict__, "is_av": np.zeros(4, dtype=bool)})
    m = class_metrics(r, horizon_s=36.0)
    assert m["av"]["n_vehicles"] == 0
    assert m["av"]["mean_crossing_time_s"] is None
    assert m["av"]["emission_score"] is None


def test_mean_over_runs() -> None:
    a = {"all": {"x": 1.0, "y": None, "q": [1.0, 3.0]}}
    b = {"all": {"x": 3.0, "y": 4.0, "q": [3.0, 5.0]}}
    assert mean_over_runs([a, b]) == {"all": {"x": 2.0, "y": 4.0, "q": [2.0, 4.0]}}
