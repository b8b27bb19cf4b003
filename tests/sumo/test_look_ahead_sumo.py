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
- *Room for a blocker that wants the other way* (`jaxround.lanes.blockers`):
  a vehicle that must leave its lane, blocked by one beside it that wants
  into that lane, keeps room for it before its lane's end and brakes,
  beyond its decel if it must, to stop before that room
  (``saveBlockerLength``, ``_patchSpeed``).
- *The speed that crosses an opened entry* (`jaxround.core.dynamics`): a
  vehicle that has its entry drives at least at ``vSafeMin`` whatever its
  lane-change wish asks (``executeMove``: ``max(finalizeSpeed(vSafe),
  vSafeMin)``).
- *A vehicle turning off leads twice* (`jaxround.core.neighbours`): while
  its back is still on the lane both leave, on that lane and as a
  same-source link leader from where the internal lanes part; the nearer
  counts.
- *How far upstream a change looks for its follower*
  (`jaxround.lanes.ring_neighbours.follower_on`): as far as the target
  lane's braking distance at the fastest speed factor departed so far.
- *Room only for a blocker that fits* (`jaxround.lanes.blockers`).
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


def test_two_lane_at_half_avs_steps_as_sumo_for_39_s() -> None:
    # two_lane.yaml's hour at 50% AVs, its first 39.5 s, with the crossing's
    # link leaders: at 18 s an AV on the outer ring lane follows a vehicle
    # turning off to the exit beside it; SUMO measures the gap to the point
    # where the two internal lanes part, on each lane
    # (MSLink::computeDistToDivergence, same source), 0.072 m shorter than
    # the step's position for position (until 2026-12-02: 7.9164 m/s against
    # SUMO's 7.9128), and so while the vehicle's back is still on the lane
    # both leave (at 34 s: 5.1000 against 5.0989). At 30.5 s an AV on the
    # inner ring lane that must leave at the next exit, blocked by an AV on
    # the outer lane that wants the inner one, brakes to stop 10.1 m before
    # its lane's end (until 2026-12-02, later: 5.8913 m/s against SUMO's
    # 3.6850); at 38.5 s another, with less room ahead, keeps none for a
    # blocker beside it that would not fit (3.4027 against 4.0755). At 31 s
    # a human driver on the right entry lane, its cooperative wish to the
    # left held back at the entry, drives onto the open entry at the speed
    # that crosses it in time (vSafeMin) and not at half of it (until then:
    # 0.6146 m/s against SUMO's 1.2291). At 38 s a vehicle crossing the
    # outer ring lane from the left entry leads one on the ring (4.2359
    # against 4.1725 without the crossing's link leaders), and an AV that
    # wants the outer lane asks the vehicle on the entry to let it in, not
    # the nearer one on the ring before, which SUMO's search for followers
    # does not reach (7.5142 against 8.3123 at 38.5 s)
    n_hour = load_config("two_lane").demand.n_vehicles
    worst, compared = worst_speed_error(
        78,
        crossing_leaders=True,
        scenario=builtin_hour("two_lane"),
        n_hour=n_hour,
        first=32,
        penetration=0.5,
    )
    assert worst < 1e-3, worst
    assert compared > 500
