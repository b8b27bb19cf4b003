"""TraCI lane requests in JAX against SUMO 1.28 on the two-lane roundabout,
decision by decision (`jaxround.apps.ring_lane_replay`): half the vehicles
are AVs, and before every step SUMO's AVs are sent
``changeLane(id, lane, half a step)`` by a scripted policy
(`ring_lane_record.scripted_policy`; lane-change mode left at SUMO's
default, 1621); the JAX changer gets the same requests.

Measured (schedule seed 2, 300 s, 2026-11-27): always the inner lane, 65
of SUMO's 65 changes made in the same step (54 of them TraCI's), 2
vehicles moved by JAX alone; without the requests in JAX, 10 of 65 and
45. Always the outer lane: 110 of 116, 27 (without: 106, 97). The other
lane when its leader is 10 m further: 769 of 794 (421 TraCI's), 81 (most
of them section 12's known gaps, about 10 with a request on a junction's
internal lane).
"""

from __future__ import annotations

import pytest

from jaxround.apps.ring_lane_record import record_sumo, scripted_policy
from jaxround.apps.ring_lane_replay import replay, tables_for
from jaxround.scenario.config import load_config
from jaxround.scenario.schedule import make_schedule

pytestmark = pytest.mark.sumo

#: policy -> (least TraCI changes, least share of SUMO's changes matched,
#: most vehicles moved by JAX alone as a share of SUMO's changes)
BOUNDS = {
    "inner": (30, 0.95, 0.08),
    "outer": (0, 0.9, 0.35),
    "gap:10": (200, 0.9, 0.25),
}


@pytest.mark.parametrize("policy", list(BOUNDS))
def test_requested_lanes_change_as_in_sumo(policy: str) -> None:
    cfg = load_config("two_lane")
    tables = tables_for(cfg)
    schedule = make_schedule(cfg, 2, penetration=0.5)
    steps, reasons = record_sumo(
        cfg, tables.paths, 300.0, schedule, lane_policy=scripted_policy(policy)
    )
    assert sum(int((s.request >= 0).sum()) for s in steps) > 500
    tally = replay(cfg, tables, steps, reasons)["tally"]
    least_traci, least_matched, most_alone = BOUNDS[policy]
    by_request = [n for k, n in tally.items() if k.startswith("sumo ") and "traci" in k]
    assert sum(by_request) >= least_traci
    assert tally["matched"] >= least_matched * tally["sumo"]
    assert tally["jax only, vehicles"] <= most_alone * tally["sumo"]
