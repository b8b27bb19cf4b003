"""A study ride in the real SUMO: the ego in the schedule, its pedals, collisions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jaxround.scenario.config import load_config
from jaxround.scenario.schedule import make_schedule
from jaxround.study.frames import ride_frame
from jaxround.study.sim import (
    EGO_ACCEL_MPS2,
    EGO_BRAKE_MPS2,
    EGO_COAST_MPS2,
    EGO_SPEED_FACTOR,
    RideSimulation,
    RideSpec,
    ride_schedule,
)
from jaxround.study.telemetry import hard_brakings

pytestmark = pytest.mark.sumo


def spec(**changes: object) -> RideSpec:
    values = dict(ride_id="test", config="milan", share=None, policy=None, seed=0,
                  warmup_s=0.0, ride_s=60.0, step_s=0.1, ego_origin=0,
                  ego_destination=3)  # fmt: skip
    values.update(changes)
    return RideSpec(**values)


def test_the_ego_joins_the_schedule_in_departure_order_and_is_never_an_av() -> None:
    cfg = load_config("milan")
    ride_cfg, schedule, k = ride_schedule(cfg, spec(share=0.8, warmup_s=60.0))
    base = make_schedule(cfg, seed=0, penetration=0.8)
    assert schedule.n_vehicles == base.n_vehicles + 1
    assert ride_cfg.demand.n_vehicles == base.n_vehicles + 1
    assert np.all(np.diff(schedule.depart_s) >= 0)  # SUMO drops unsorted vehicles
    assert schedule.depart_s[k] == 60.0
    assert (schedule.origin[k], schedule.destination[k]) == (0, 3)
    assert not schedule.is_av[k]
    others = np.delete(np.arange(schedule.n_vehicles), k)
    assert np.array_equal(schedule.is_av[others], base.is_av)


def drive_until(sim: RideSimulation, throttle: float, brake: float, steps: int) -> None:
    for _ in range(steps):
        sim.step(throttle, brake)
        if sim.ego_arrived_s is not None:
            return


def test_the_pedals_set_the_ego_speed_and_it_crosses(tmp_path: Path) -> None:
    sim = RideSimulation(spec(), tmp_path)
    try:
        sim.warm_up()
        drive_until(sim, 0.0, 0.0, 1)
        assert sim.ego_on_road
        leg_limit = load_config("milan").network.legs[0].speed_limit_mps
        assert sim.ego_speed == pytest.approx(EGO_SPEED_FACTOR * leg_limit, abs=0.05)
        v0 = sim.ego_speed
        drive_until(sim, 1.0, 0.0, 10)  # 1 s of full throttle
        expected = v0 + (EGO_ACCEL_MPS2 - EGO_COAST_MPS2) * 1.0
        assert sim.ego_speed == pytest.approx(expected, abs=1e-6)
        drive_until(sim, 0.0, 1.0, 5)  # half a second of full brake
        expected -= (EGO_BRAKE_MPS2 + EGO_COAST_MPS2) * 0.5
        assert sim.ego_speed == pytest.approx(expected, abs=1e-6)
        assert len(hard_brakings(sim.trace)) == 1
        drive_until(sim, 0.6, 0.0, 400)
        assert sim.ego_arrived_s is not None
        assert sim.ego_arrived_s - sim.ego_entered_s > 5.0
        assert sim.collisions == 0  # alone on the roads
    finally:
        sim.close()


def test_a_misjudged_gap_is_a_recorded_collision_and_the_ride_goes_on(
    tmp_path: Path,
) -> None:
    """Full throttle into the ring among human drivers (seed 0): the ego's
    checks are off, so it hits someone; SUMO records it, nothing stops."""
    sim = RideSimulation(spec(share=0.0, warmup_s=30.0), tmp_path)
    try:
        sim.warm_up()
        drive_until(sim, 1.0, 0.0, 600)
        assert sim.collisions >= 1
        collisions = [e for e in sim.events if e["kind"] == "collision"]
        assert {e["other"] for e in collisions} == {"hv"}
        assert sim.ego_arrived_s is not None  # the ride went on to the exit
        frame = ride_frame(sim, step=0, input_seq=3)
        assert frame["collisions"] == sim.collisions
        assert frame["ego"] is None  # it has left
    finally:
        sim.close()


def test_each_pass_sends_the_ego_in_again_until_the_last(tmp_path: Path) -> None:
    sim = RideSimulation(spec(passes=3), tmp_path)
    try:
        sim.warm_up()
        entries, was_on_road = 0, False
        for step in range(1500):
            sim.step(1.0, 0.0)
            entries += sim.ego_on_road and not was_on_road
            was_on_road = sim.ego_on_road
            frame = ride_frame(sim, step, 0)
            assert (frame["pass"], frame["passes"]) == (sim.current_pass, 3)
            assert (frame["ego"] is None) == (not sim.ego_on_road)
            if sim.ego_arrived_s is not None:
                break
        assert entries == 3 and len(sim.crossings) == 3
        assert all(c > 5.0 for c in sim.crossings)
        on_road_s = sum(row["on_road"] for row in sim.trace) * 0.1
        assert on_road_s == pytest.approx(sum(sim.crossings), abs=0.35)
        assert sim.ego_arrived_s is not None and frame["ego"] is None
    finally:
        sim.close()
