"""The study on two-lane roads, in the real SUMO: the ego's turn signal, the
lane changes it records, the AVs' scripted drivers and a ring that keeps
flowing at the study's 10 Hz."""

from __future__ import annotations

from pathlib import Path

import pytest

from jaxround.scenario.config import load_config
from jaxround.study.cli import check_av_driver
from jaxround.study.ego_lanes import route_side
from jaxround.study.frames import ride_frame
from jaxround.study.load import write_standin_policy
from jaxround.study.ride_setup import ride_config
from jaxround.study.sim import RideSimulation, RideSpec

pytestmark = pytest.mark.sumo


def spec(**changes: object) -> RideSpec:
    values = dict(ride_id="lanes", config="two_lane", share=None, policy=None,
                  seed=0, warmup_s=0.0, ride_s=60.0, step_s=0.1, ego_origin=0,
                  ego_destination=3)  # fmt: skip
    values.update(changes)
    return RideSpec(**values)


def road_of(sim: RideSimulation) -> str:
    return sim.libsumo.vehicle.getRoadID(sim.ego_id) if sim.ego_on_road else ""


def test_two_lane_rides_step_the_drivers_at_the_ride_step() -> None:
    two_lane, milan = load_config("two_lane"), load_config("milan")
    ride = ride_config(two_lane, 0.1)
    assert ride.simulation.dt_s == 0.1
    assert ride.drivers.hv.action_step_length == 0.1
    assert ride.drivers.av.action_step_length == 0.1
    assert ride.drivers.hv.tau == two_lane.drivers.hv.tau
    kept = ride_config(milan, 0.1).drivers
    assert kept.hv.action_step_length == milan.drivers.hv.action_step_length


def test_the_turn_signal_moves_the_ego_and_the_route_brings_it_back(
    tmp_path: Path,
) -> None:
    """On the empty two-lane roundabout: left asked on the entry, the ego
    takes the inner lanes; before its exit SUMO moves it right for its
    route (the exit is one lane); it arrives."""
    sim = RideSimulation(spec(), tmp_path)
    views, asked = [], False
    try:
        sim.warm_up()
        for step in range(600):
            if road_of(sim).startswith("in_") and not asked:
                sim.ask_lane("left")
                asked = True
            sim.step(0.3, 0.0)
            frame = ride_frame(sim, step, 0)
            if frame["lane"] is not None:
                views.append((road_of(sim), tuple(frame["lane"])))
            if sim.ego_arrived_s is not None:
                break
    finally:
        sim.close()
    assert sim.ego_arrived_s is not None and sim.collisions == 0
    changes = [e["detail"] for e in sim.events if e["kind"] == "lane_change"]
    assert len(changes) == 2
    assert changes[0] == "left to in_0_1, asked for"
    assert changes[1].startswith("right to ")  # on the ring or into its junction
    assert changes[1].endswith("_0, for the route")
    lanes_seen = {view for _, view in views}
    assert (0, 2, 0, 0) in lanes_seen and (1, 2, 0, 0) in lanes_seen
    assert all(view[1] == 1 for road, view in views if road.startswith("out_"))


def test_the_route_side_is_where_the_lane_ends_before_the_route_goes_on() -> None:
    # vehicle.getBestLanes on the last ring road before a one-lane exit, as
    # SUMO 1.28 gave it for a vehicle on the inner lane (lane id, length
    # that leads on, occupation, offset to the best lane, continues, next)
    best = (("ring_2_0", 107.2, 0.0, 0, True, ("out_3_0",)),
            ("ring_2_1", 17.2, 0.0, -1, False, ()))  # fmt: skip
    assert route_side(best, "ring_2_1") == -1
    assert route_side(best, "ring_2_0") == 0
    # a lane that leads on though another is better: no hint yet
    entry = (("in_0_0", 232.0, 0.0, 0, True, ()), ("in_0_1", 142.0, 0.0, -1, True, ()))
    assert route_side(entry, "in_0_1") == 0


def test_a_signal_with_no_lane_there_ends_and_changes_nothing(tmp_path: Path) -> None:
    sim = RideSimulation(spec(config="milan"), tmp_path)
    try:
        sim.warm_up()
        while not sim.ego_on_road:
            sim.step(0.3, 0.0)
        sim.ask_lane("left")
        assert sim.lanes.signal == 1
        sim.step(0.3, 0.0)
        assert sim.lanes.signal == 0
        assert ride_frame(sim, 0, 0)["lane"][:2] == [0, 1]
    finally:
        sim.close()
    assert not [e for e in sim.events if e["kind"] == "lane_change"]


def test_scripted_avs_ask_for_lanes_and_the_ring_keeps_flowing(tmp_path: Path) -> None:
    """Half the traffic AVs under a scripted lane rule; after four minutes at
    10 Hz the ring still moves (0 of 35 vehicles still on it; with the
    drivers' 0.5 s action step SUMO 1.28 held 23 of 81 still, docs/study.md)."""
    sim = RideSimulation(
        spec(share=0.5, policy="eco+gap:10", seed=6, warmup_s=240.0), tmp_path
    )
    try:
        sim.warm_up()
        veh = sim.libsumo.vehicle
        ids = veh.getIDList()
        still = [v for v in ids if veh.getSpeed(v) < 0.1
                 and veh.getRoadID(v).startswith(("ring_", ":c"))]  # fmt: skip
        report = sim.controller.report()
    finally:
        sim.close()
    assert report["lane_requests"] > 0 and report["commands"] > 0
    assert len(still) <= 8, f"{len(still)} of {len(ids)} vehicles still on the ring"


def test_the_av_driver_is_checked_against_the_roads(tmp_path: Path) -> None:
    two_lane = load_config("two_lane")
    check_av_driver("uncontrolled", two_lane)
    check_av_driver("eco+gap:10", two_lane)
    milan_policy = write_standin_policy(tmp_path, load_config("milan"))
    with pytest.raises(ValueError, match="trained on scenario 'milan'"):
        check_av_driver(str(milan_policy), two_lane)
    with pytest.raises(ValueError, match="gap:x"):
        check_av_driver("eco+gap:x", two_lane)
    data = two_lane.to_dict()
    data["network"]["legs"][1]["exit_lanes"] = 2
    from jaxround.scenario.config import config_from_dict

    two_lane_exit = config_from_dict(data)
    check_av_driver("uncontrolled", two_lane_exit)  # SUMO alone drives them
    with pytest.raises(ValueError, match=r"legs\[1\]\.exit_lanes: 2"):
        check_av_driver("eco", two_lane_exit)
