"""SUMO 1.28's hold on a wanted change to the left entry lane
(`jaxround.apps.lane_hold_probe`, docs/lc2013-map.md section 12): the
vehicles that alone hold it are bound through the entry's junction on the
ring, the foes of the left entry lane's link."""

from __future__ import annotations

import pytest

from jaxround.apps.lane_hold_probe import held_steps, holders
from jaxround.scenario.config import load_config

pytestmark = pytest.mark.sumo


def test_the_vehicles_that_hold_a_change_are_through_going_foes() -> None:
    cfg = load_config("two_lane")
    rows = held_steps(cfg, 150.0)
    assert rows, "no held change in 150 s of two_lane.yaml (SUMO 1.28 holds some)"
    firsts = {}  # each held vehicle's first held step at least 10 m from its line
    for h in rows:
        if h.seen > 10.0:
            firsts.setdefault(h.vehicle, h)
    found = 0
    for held in list(firsts.values())[:4]:
        result = holders(cfg, held.step, held.vehicle)
        assert result.with_all, "the replayed step is not the held one"
        assert not result.alone, "held with nobody else on the network"
        leg = int(held.lane.split("_")[1])
        before = f"ring_{(leg - 1) % len(cfg.network.legs)}"
        for route in result.sufficient.values():
            assert before in route
            assert route[route.index(before) + 1] == f"ring_{leg}"
            found += 1
    assert found > 0, "no vehicle found that alone holds a change"
