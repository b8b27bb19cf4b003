"""JAX against SUMO on the same schedules, with interactions (real SUMO)."""

from __future__ import annotations

import pytest

from jaxround.apps.parity import parity_report
from tests.conftest import small_config

pytestmark = pytest.mark.sumo


def test_default_roundabout_matches_sumo_on_a_busy_quarter_hour() -> None:
    # the default scenario's demand rate (1540 veh/h) for 15 minutes
    cfg = small_config("milan", n_vehicles=385, duration_s=900.0)
    report = parity_report(cfg, [0], show_progress=False)
    err = report["rel_err"]
    assert report["jax"]["all"]["n_arrived"] == report["sumo"]["all"]["n_arrived"]
    assert err["mean_crossing_time_s"] < 0.03, err
    assert err["co2_g_per_veh"] < 0.03, err
    assert report["per_vehicle_median_abs_err_s"] <= 1.0
    assert report["per_vehicle_exact_share"] > 0.4  # 0.50 measured
    assert report["jax_slot_overflow"] == 0 and report["sumo_collisions"] == 0
    # by default the slots the traffic needs, far fewer than the road's 76
    assert report["max_vehicles"] < 76
    assert report["max_vehicles_tried"] == [report["max_vehicles"]]
