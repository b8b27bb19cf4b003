"""A vehicle that would slow below what crossing its entry needs stops at
its line instead (SUMO's ``vSafeMin`` in ``MSVehicle::processLinkApproaches``),
also when the slowing comes from a link leader at the merge beyond the
entry: the entry's pass speed is set before the exit link's leaders are met.

Two vehicles on two_lane.yaml, in both simulators: a ring vehicle from the
south leg to the north exit, and one from the east leg's left lane to the
west exit 5.5 s after it, which meets the ring vehicle on the inner through
lane (the merge foe of its internal lane) 5.3 m before its line. SUMO slows
it to the stop at the line (2.84 m/s); JAX followed the merge leader
instead (3.48 m/s) and entered a step sooner. The step runs with the
crossing's link leaders (`crossing_leaders=True`): once on the junction the
entering vehicle meets the ring vehicle, which changed to the outer lane,
on the crossing, as SUMO's does.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxround.analysis.episode_movie import rollout_states
from jaxround.core.geometry import locate
from jaxround.envs.roundabout import make
from jaxround.scenario.config import config_from_dict
from jaxround.scenario.schedule import Schedule
from sumo_export.runner import run_schedule
from tests.conftest import builtin_dict

pytestmark = pytest.mark.sumo

#: Steps compared: the entering vehicle's approach, and its entry.
STEPS = 40
#: The entering vehicle's id (the second to depart).
ENTERING = "v00001"


def two_vehicles():
    d = builtin_dict("two_lane")
    d["demand"].update(n_vehicles=2, duration_s=60.0)
    d["simulation"]["max_vehicles"] = 8
    cfg = config_from_dict(d)
    schedule = Schedule(
        depart_s=np.array([0.0, 5.5]),
        origin=np.array([3, 0], np.int32),  # south, east
        destination=np.array([1, 2], np.int32),  # north, west
        speed_factor=np.ones(2),
        av_rank=np.array([0, 1], np.int32),
        penetration=0.0,
    )
    return cfg, schedule


def test_a_merge_leader_beyond_the_entry_stops_the_vehicle_at_its_line() -> None:
    cfg, schedule = two_vehicles()
    sumo: dict[float, tuple[str, float]] = {}

    def record(libsumo, t: float) -> None:
        if ENTERING in libsumo.vehicle.getIDList():
            v = libsumo.vehicle
            sumo[round(t, 1)] = (v.getLaneID(ENTERING), v.getSpeed(ENTERING))

    run_schedule(cfg, schedule, controller=record)
    env, params = make(cfg, crossing_leaders=True)
    states = rollout_states(
        env, params, jax.random.PRNGKey(0), STEPS, every=1,
        schedule=env.schedule_from_numpy(schedule),
    )  # fmt: skip
    lane_ids = env.network.lane_ids
    compared = 0
    for k in range(STEPS):
        t = round((k + 1) * env.dt, 1)  # the state after step k + 1
        on = np.asarray(states.active[k]) & (np.asarray(states.vid[k]) == 1)
        if t not in sumo or not on.any():
            continue
        slot = int(np.argmax(on))
        route, pos = states.route[k, slot], states.pos[k, slot]
        _, lane, _ = locate(env.net, route[None], pos[None])
        sumo_lane, sumo_speed = sumo[t]
        assert lane_ids[int(lane[0])] == sumo_lane, t
        assert float(states.speed[k, slot]) == pytest.approx(sumo_speed, abs=0.03), t
        compared += 1
    assert compared > 10
    # the step where the merge leader is still short of the merge: a stop at
    # the line in both, not the follow speed
    assert sumo[14.5] == ("in_0_1", pytest.approx(2.84, abs=0.01))
