"""Three rules of SUMO's step that decide where a queue at a two-lane entry
goes, step for step against SUMO 1.28 (real SUMO from PyPI).

The held-out five-leg roundabout with traffic from two legs only: leg 0's
two-lane entry against the ring traffic from leg 4's one-lane entry.

- *How far a vehicle looks ahead for the end of its lane path*
  (`jaxround.core.planning.look_ahead_reach`): the first vehicle, alone on the
  inner ring lane at a speed factor of 1.12, brakes for the end of that lane
  where SUMO's look-ahead reaches it, and not while it is on a junction's
  internal lane, where the walk stops sooner (the step braked there too
  until 2026-11-29: 0.06 m/s slower at 16.5 s, 0.25 m behind at 18 s).
- *Where it stops at that end* (`jaxround.core.planning.lane_limits`): at
  the distance seen, as ``planMoveInternal``'s dead end calls
  ``stopSpeed(seen)``, not 0.1 m before it (until 2026-12-02 the same
  vehicle braked about 1% harder from 14 s on: 0.009 m/s slower at 25.5 s).
- *The order in which edges take their lane-change turns*
  (`jaxround.lanes.active_lanes`): at 26 s a vehicle waiting on the left
  entry lane, whose urgent wish to the right the roundabout bonus turns off
  once the ring vehicle beside it has changed right in the same step, stops
  in JAX where SUMO's drives on if the entry's edge takes its turn before
  the ring's (until 2026-11-29, in lane-table order: 0 m/s against 1.03).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import numpy as np
import pytest

from jaxround.analysis.episode_movie import rollout_states
from jaxround.core.geometry import locate
from jaxround.envs.roundabout import make
from jaxround.scenario.config import ScenarioConfig, config_from_dict
from jaxround.scenario.schedule import Schedule, make_schedule
from sumo_export.runner import run_schedule
from tests.conftest import builtin_dict

pytestmark = pytest.mark.sumo

#: Steps compared: the first 31 s (then a vehicle on a left entry's crossing
#: 45 m ahead of one from leg 4, a link leader the step leaves out by
#: default, slows it in SUMO by 0.07 m/s).
STEPS = 62
#: With the crossing's link leaders (``make(cfg, crossing_leaders=True)``):
#: the first 36 s.
STEPS_CROSSING = 72


#: The schedule's vehicles that depart within the steps compared.
FIRST = 24


def two_legs(n_vehicles: int) -> ScenarioConfig:
    d = builtin_dict("held_out/five_leg_two_lane")
    d["demand"].update(
        n_vehicles=n_vehicles,
        origin_share=[0.5, 0.0, 0.0, 0.0, 0.5],
        od=[
            [0.0, 0.25, 0.25, 0.25, 0.25],
            [0.0, 0.0, 0.34, 0.33, 0.33],
            [0.34, 0.33, 0.0, 0.0, 0.33],
            [0.25, 0.25, 0.25, 0.0, 0.25],
            [0.0, 0.34, 0.33, 0.33, 0.0],
        ],
    )
    d["simulation"]["max_vehicles"] = 32
    return config_from_dict(d)


def worst_speed_error(
    steps: int,
    crossing_leaders: bool,
    scenario: Callable[[int], ScenarioConfig] = two_legs,
    n_hour: int = 1400,
    first: int = FIRST,
    penetration: float = 0.0,
) -> tuple[float, int]:
    """The first `first` vehicles of the scenario's hour (`n_hour` in it; the
    next departs after the steps compared; the hour's AVs at `penetration`),
    alone in both simulators for ``steps``: the largest speed difference
    (m/s) and the vehicle-steps compared, every vehicle on SUMO's lane and
    within 5 cm of its position."""
    full = make_schedule(scenario(n_hour), seed=0, penetration=penetration)
    assert full.depart_s[first] > steps * 0.5
    cfg = scenario(first)
    is_av = full.is_av[:first]
    schedule = Schedule(
        depart_s=full.depart_s[:first], origin=full.origin[:first],
        destination=full.destination[:first], speed_factor=full.speed_factor[:first],
        av_rank=np.where(is_av, 0, first).astype(np.int32),  # those AVs, exactly
        penetration=1.0 if is_av.any() else 0.0,
    )  # fmt: skip
    sumo: dict[float, dict[str, tuple[str, float, float]]] = {}

    def record(libsumo, t: float) -> None:
        v = libsumo.vehicle
        sumo[round(t, 1)] = {
            vid: (v.getLaneID(vid), v.getLanePosition(vid), v.getSpeed(vid))
            for vid in v.getIDList()
        }

    run_schedule(cfg, schedule, controller=record, drain_s=0.0)
    env, params = make(cfg, crossing_leaders=crossing_leaders)
    states = rollout_states(
        env, params, jax.random.PRNGKey(0), steps, every=1,
        schedule=env.schedule_from_numpy(schedule),
    )  # fmt: skip
    lane_ids = env.network.lane_ids
    compared, worst = 0, 0.0
    for k in range(states.step.shape[0]):
        t = round(float(states.step[k]) * env.dt, 1)
        theirs = sumo.get(round(t + env.dt, 1))  # SUMO's record of the same state
        if theirs is None:
            continue
        on = np.flatnonzero(np.asarray(states.active[k]))
        _, lane, pos = locate(env.net, states.route[k, on], states.pos[k, on])
        assert len(on) == len(theirs), t
        for n, slot in enumerate(on):
            their_lane, their_pos, their_speed = theirs[
                f"v{int(states.vid[k, slot]):05d}"
            ]
            assert lane_ids[int(lane[n])] == their_lane, t
            assert float(pos[n]) == pytest.approx(their_pos, abs=0.05), t
            error = abs(float(states.speed[k, slot]) - their_speed)
            worst = max(worst, error)
            compared += 1
    return worst, compared


def test_a_two_lane_entry_against_ring_traffic_steps_as_sumo_does() -> None:
    worst, compared = worst_speed_error(STEPS, crossing_leaders=False)
    assert worst < 1e-3, worst  # float32 against SUMO's doubles: 2e-4
    assert compared > 300  # vehicle-steps: some 20 vehicles by 31 s


def test_the_crossings_link_leaders_step_as_sumo_does() -> None:
    # at 31.5 s a ring vehicle 45 m before the crossing slows for a vehicle
    # on the left entry's internal lane; the speed that binds is the stop
    # before its own link into the junction, 1 m before a major link
    # (until 2026-12-02 0.1 m: 6.2929 m/s against SUMO's 6.2875)
    worst, compared = worst_speed_error(STEPS_CROSSING, crossing_leaders=True)
    assert worst < 1e-3, worst
    assert compared > 350
