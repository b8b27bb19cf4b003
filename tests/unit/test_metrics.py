"""Metrics against values computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from jaxround.analysis.metrics import (
    VehicleRecords,
    arrived_in_all,
    class_metrics,
    mean_over_runs,
    min_max_scores,
    sweep_scale,
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


def test_lane_changes_per_vehicle_by_class() -> None:
    """Over the compared vehicles of each class: the AV that never arrived
    (3 changes) is left out, as its crossing time is; None on one-lane roads
    and over a class with none compared."""
    assert (
        class_metrics(records(), horizon_s=36.0)["all"]["lane_changes_per_veh"] is None
    )
    r = VehicleRecords(**{**records().__dict__, "lane_changes": np.array([1, 2, 0, 3])})
    m = class_metrics(r, horizon_s=36.0)
    assert m["all"]["lane_changes_per_veh"] == pytest.approx(1.0)
    assert m["hv"]["lane_changes_per_veh"] == pytest.approx(1.5)
    assert m["av"]["lane_changes_per_veh"] == pytest.approx(0.0)
    only_hv = np.array([True, True, False, False])
    m = class_metrics(r, horizon_s=36.0, compared=only_hv)
    assert m["av"]["lane_changes_per_veh"] is None
    assert m["all"]["lane_changes_per_veh"] == pytest.approx(1.5)


def test_mean_over_runs() -> None:
    a = {"all": {"x": 1.0, "y": None, "q": [1.0, 3.0]}}
    b = {"all": {"x": 3.0, "y": 4.0, "q": [3.0, 5.0]}}
    assert mean_over_runs([a, b]) == {"all": {"x": 2.0, "y": 4.0, "q": [2.0, 4.0]}}


def test_means_over_the_vehicles_arrived_in_every_run() -> None:
    """The second run leaves HV 0 outside at its cap: both runs' means are
    then over HV 1 and AV 2 alone, each run's own arrivals still counted."""
    a = records()
    b = VehicleRecords(**{**a.__dict__, "arrival_s": np.array([NAN, 50.0, 45.0, NAN])})
    both = arrived_in_all([a, b])
    np.testing.assert_array_equal(both, [False, True, True, False])
    ma = class_metrics(a, horizon_s=36.0, compared=both)
    mb = class_metrics(b, horizon_s=36.0, compared=both)
    # crossing times over vehicles 1 and 2: a: 30, 15; b: 40, 25
    assert ma["all"]["mean_crossing_time_s"] == pytest.approx(22.5)
    assert mb["all"]["mean_crossing_time_s"] == pytest.approx(32.5)
    assert ma["hv"]["co2_g_per_veh"] == pytest.approx(90.0)
    assert ma["all"]["n_compared"] == mb["all"]["n_compared"] == 2
    # insertion delays over the same two: vehicle 1 waited 2 s, vehicle 2 none
    assert ma["all"]["mean_insertion_delay_s"] == pytest.approx(1.0)
    assert (ma["all"]["n_arrived"], mb["all"]["n_arrived"]) == (3, 2)
    assert (ma["all"]["n_not_arrived"], mb["all"]["n_not_arrived"]) == (1, 2)
    with pytest.raises(ValueError, match="must have arrived"):
        class_metrics(b, horizon_s=36.0, compared=a.arrived)
    other = VehicleRecords(**{**a.__dict__, "is_av": np.ones(4, bool)})
    with pytest.raises(ValueError, match="other vehicles"):
        arrived_in_all([a, other])


def test_one_score_scale_over_a_sweep() -> None:
    """Two hand-made runs, the second emitting less: on the sweep's scale its
    scores are lower, as its grams are; each on its own scale they are not."""
    dirty = records()  # CO2 50, 90, 60; fuel 16, 30, 23
    clean = VehicleRecords(
        **{
            **dirty.__dict__,
            "co2_g": np.array([40.0, 44.0, 48.0, NAN]),
            "fuel_g": np.array([13.0, 14.0, 16.0, NAN]),
        }
    )
    scale = sweep_scale([dirty, clean])
    assert scale.co2_g == (40.0, 90.0) and scale.fuel_g == (13.0, 30.0)
    d = class_metrics(dirty, horizon_s=36.0, scale=scale)
    c = class_metrics(clean, horizon_s=36.0, scale=scale)
    # CO2 on 40..90: dirty HVs 0.2, 1.0 -> 0.6; clean HVs 0, 0.08 -> 0.04
    assert d["hv"]["emission_score"] == pytest.approx(0.6)
    assert c["hv"]["emission_score"] == pytest.approx(0.04)
    # fuel on 13..30: clean AV (16 g) 3/17, dirty AV (23 g) 10/17
    assert c["av"]["consumption_score"] == pytest.approx(3 / 17)
    assert d["av"]["consumption_score"] == pytest.approx(10 / 17)
    # per run: the clean run's HVs score 0, 0.5 -> 0.25, the dirty run's 0.5
    # (lower, yet not on the same scale: the cleaner AV scores 1 against 0.25)
    own = class_metrics(clean, horizon_s=36.0)
    assert own["hv"]["emission_score"] == pytest.approx(0.25)
    assert own["av"]["emission_score"] == pytest.approx(1.0)
    assert sweep_scale([]) is None


def human_drivers(co2_g: list[float]) -> VehicleRecords:
    """Five human drivers, all arrived, with these grams of CO2."""
    n = len(co2_g)
    co2 = np.asarray(co2_g)
    return VehicleRecords(
        is_av=np.zeros(n, bool),
        origin=np.zeros(n, int),
        scheduled_depart_s=np.arange(n, dtype=float),
        depart_s=np.arange(n, dtype=float),
        arrival_s=np.arange(n, dtype=float) + 20.0,
        co2_g=co2,
        fuel_g=co2 / 3.0,
        queue_mean_veh=np.zeros(4),
        queue_max_veh=np.zeros(4),
    )


def test_one_scale_over_both_simulators_puts_scores_where_grams_are() -> None:
    # 0% AVs: CO2 per vehicle 52.0 g in JAX, 52.4 g in SUMO (0.8% apart),
    # but SUMO's extremes lie wider (one vehicle 20 g, one 72 g)
    runs = {
        "jax": human_drivers([40.0, 50.0, 52.0, 54.0, 64.0]),
        "sumo": human_drivers([20.0, 56.0, 57.0, 57.0, 72.0]),
    }
    grams = {"jax": 52.0, "sumo": 52.4}

    def scores(scale_of: dict[str, object]) -> dict[str, float]:
        out = {}
        for sim, run in runs.items():
            m = class_metrics(run, 3600.0, scale=scale_of[sim])
            assert m["hv"]["co2_g_per_veh"] == pytest.approx(grams[sim])
            out[sim] = m["hv"]["emission_score"]
        return out

    # each simulator on its own scale: 0.50 against 0.62, 24% apart
    own = scores({sim: sweep_scale([run]) for sim, run in runs.items()})
    assert abs(own["sumo"] / own["jax"] - 1) > 0.2
    # one scale over the runs of both: as close as the grams
    joint = sweep_scale(runs.values(), over="joint")
    assert joint.over == "joint" and joint.co2_g == (20.0, 72.0)
    both = scores({sim: joint for sim in runs})
    assert abs(both["sumo"] / both["jax"] - 1) < 0.02
