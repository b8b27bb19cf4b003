"""Two rules of SUMO's step about what a vehicle sees ahead, step for step
against SUMO 1.28 (real SUMO from PyPI), with `test_turn_order`'s
comparison of the first vehicles of an hour.

- *How far the look-ahead walks* (`jaxround.core.planning.look_ahead_reach`):
  ``MSVehicle::planMoveInternal`` stops walking the lanes ahead after a
  link once it has seen past its braking distance and enough normal
  metres; leaders, limits and link leaders beyond do not count.
- *Where a vehicle turning off leads* (`jaxround.core.geometry.project`,
  `NetArrays.lane_diverge`): as a same-source link leader, measured to the
  point where the two internal lanes part, on each lane
  (``MSLink::computeDistToDivergence``).
"""

from __future__ import annotations

from collections.abc import Callable

import pytest

from jaxround.scenario.config import ScenarioConfig, config_from_dict, load_config
from tests.conftest import builtin_dict
from tests.sumo.test_turn_order import worst_speed_error

pytestmark = pytest.mark.sumo


def builtin_hour(name: str) -> Callable[[int], ScenarioConfig]:
    """A built-in scenario with `n_vehicles` in its hour, `max_vehicles` 32."""

    def scenario(n_vehicles: int) -> ScenarioConfig:
        d = builtin_dict(name)
        d["demand"]["n_vehicles"] = n_vehicles
        d["simulation"]["max_vehicles"] = 32
        return config_from_dict(d)

    return scenario


def test_the_look_ahead_stops_where_sumos_walk_does() -> None:
    # the held-out hour's first 27 s (2,300 vehicles in it, 22 depart by
    # then): at 14.5 s a vehicle on the left entry's internal lane
    # accelerates freely in SUMO; the step followed a vehicle merging 78 m
    # ahead at the next leg, beyond the lane where SUMO's look-ahead stops
    # (until 2026-12-02: 8.8455 m/s against SUMO's 8.8991)
    worst, compared = worst_speed_error(
        54,
        crossing_leaders=False,
        scenario=builtin_hour("held_out/five_leg_two_lane"),
        n_hour=2300,
        first=22,
    )
    assert worst < 1e-3, worst
    assert compared > 300


def test_a_vehicle_turning_off_leads_as_sumos_same_source_foe() -> None:
    # two_lane.yaml's hour at 50% AVs, its first 30 s: at 18 s an AV on the
    # outer ring lane follows a vehicle turning off to the exit beside it;
    # SUMO measures the gap to the point where the two internal lanes part,
    # on each lane (MSLink::computeDistToDivergence, same source), 0.072 m
    # shorter than the step's position for position (until 2026-12-02:
    # 7.9164 m/s against SUMO's 7.9128)
    n_hour = load_config("two_lane").demand.n_vehicles
    worst, compared = worst_speed_error(
        60,
        crossing_leaders=False,
        scenario=builtin_hour("two_lane"),
        n_hour=n_hour,
        first=23,
        penetration=0.5,
    )
    assert worst < 1e-3, worst
    assert compared > 300
