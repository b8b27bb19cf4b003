"""TraCI lane requests in JAX against SUMO 1.28 on the two-lane roundabout,
decision by decision (`jaxround.apps.ring_lane_replay`): half the vehicles
are AVs, and before every step SUMO's AVs are sent
``changeLane(id, lane, step)`` by a scripted policy (lane-change mode left
at SUMO's default, 1621); the JAX changer gets the same requests.

Measured (schedule seed 2, 300 s, 2026-11-27): always the inner lane, 65
of SUMO's 65 changes made in the same step (53 of them TraCI's), 2
vehicles moved by JAX alone; without the requests in JAX, 10 of 65 and
45. Always the outer lane: 110 of 116, 29 (without: 106, 97).
"""

from __future__ import annotations

from typing import Any

import pytest

from jaxround.apps.ring_lane_record import record_sumo
from jaxround.apps.ring_lane_replay import replay
from jaxround.scenario.config import load_config
from jaxround.scenario.schedule import make_schedule
from sumo_export.scenario import AV_TYPE
from tests.sumo.test_ring_changer import tables_for

pytestmark = pytest.mark.sumo


def always(lane: int):
    def policy(vehicle: Any, ids: list[str]) -> dict[str, int]:
        return {vid: lane for vid in ids if vehicle.getTypeID(vid) == AV_TYPE}

    return policy


@pytest.mark.parametrize("lane", [1, 0], ids=["inner", "outer"])
def test_requested_lanes_change_as_in_sumo(lane: int) -> None:
    cfg = load_config("two_lane")
    tables = tables_for(cfg)
    schedule = make_schedule(cfg, 2, penetration=0.5)
    steps, reasons = record_sumo(
        cfg, tables.paths, 300.0, schedule, lane_policy=always(lane)
    )
    assert sum(int((s.request >= 0).sum()) for s in steps) > 1000
    tally = replay(cfg, tables, steps, reasons)["tally"]
    if lane == 1:
        asked = sum(
            n for k, n in tally.items() if k.startswith("sumo ") and "traci" in k
        )
        assert asked > 30
        assert tally["matched"] >= 0.95 * tally["sumo"]
        assert tally["jax only, vehicles"] <= 5
    else:
        assert tally["matched"] >= 0.9 * tally["sumo"]
        assert tally["jax only, vehicles"] <= 0.35 * tally["sumo"]
