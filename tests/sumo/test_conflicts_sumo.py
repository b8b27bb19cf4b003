"""Near-conflicts: SUMO's SSM device against the JAX count on the same
schedules (real SUMO)."""

from __future__ import annotations

from typing import Any

import pytest

from jaxround.apps.conflict_sweep import conflicts_agree
from jaxround.apps.drivers import with_av_numbers
from jaxround.apps.parity import parity_report
from tests.conftest import small_config

pytestmark = pytest.mark.sumo


@pytest.fixture(scope="module")
def reports() -> dict[str, dict[str, Any]]:
    """A busy quarter hour at Milan's rate, every vehicle an AV: their own
    vType, and a 0.5 s time gap with no impatience (the setting with the
    most conflicts)."""
    cfg = small_config("milan", n_vehicles=385, duration_s=900.0)
    short = with_av_numbers(cfg, {"tau": 0.5, "impatience": 0.0})
    return {
        name: parity_report(setting, [0], show_progress=False, penetration=1.0)
        for name, setting in (("own", cfg), ("short", short))
    }


def test_short_time_gaps_give_the_same_conflicts_in_both(
    reports: dict[str, dict[str, Any]],
) -> None:
    report = reports["short"]
    jax_value = report["jax"]["all"]["conflicts_per_1000_veh"]
    sumo_value = report["sumo"]["all"]["conflicts_per_1000_veh"]
    assert sumo_value > 50.0, sumo_value  # about 280 per 1,000 at full demand
    assert conflicts_agree(jax_value, sumo_value), (jax_value, sumo_value)
    # every conflict SUMO wrote is a following one, written by both vehicles
    types = report["sumo_conflict_types"]
    assert set(types) <= {"following_follower", "following_leader"}, types
    assert types["following_follower"] == types["following_leader"]
    sumo_av = report["sumo"]["av"]
    assert sumo_av["min_ttc_s"] is not None and sumo_av["min_ttc_s"] <= 1.5 + 1e-9
    assert report["rel_err"]["mean_crossing_time_s"] < 0.02


def test_the_av_vtype_has_far_fewer_conflicts(
    reports: dict[str, dict[str, Any]],
) -> None:
    own, short = reports["own"], reports["short"]
    for sim in ("jax", "sumo"):
        few = own[sim]["all"]["conflicts_per_1000_veh"]
        many = short[sim]["all"]["conflicts_per_1000_veh"]
        assert few < many / 5, (sim, few, many)
