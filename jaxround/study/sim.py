"""One ride in SUMO: the background traffic, the policy's AVs and the ego.

The ride runs the scenario's own schedule (same seed for every participant)
with one more vehicle, the ego, inserted in the schedule at the end of the
warm-up on its route (an arterial entry and a left-turn exit by default).
SUMO writes it into the route file like any other vehicle
(`sumo_export.scenario.write_scenario`), so the policy's observer
(`sumo_export.traffic.SumoObserver`) sees it as a human driver, which it is.

SUMO steps at ``step_s`` (0.1 s: 10 Hz) instead of the scenario's ``dt_s``;
on one-lane roads the human drivers' and AVs' action step stays 0.5 s (their
vTypes' action step length, `sumo_export.scenario.action_step`; on two-lane
roads it is the step, `ride_config`), and the policy acts every
``dt_s / step_s`` steps through `sumo_export.controller.PolicyController`,
as it was trained.

A ride is a number of passes (``passes``): each time the ego leaves the
network it is sent in again from its entry on the same route, under the
same id, among the traffic that went on meanwhile (SUMO's ``vehicle.add``),
so the AVs' observer keeps seeing it as the same human driver. The ride
ends after the last pass or at its time limit.

The participant drives the ego's longitudinal motion: the pedals set an
acceleration, its integral is commanded with ``vehicle.setSpeed`` and the ego
follows its lanes (no steering); on two-lane roads a turn signal asks SUMO
for the lane beside (`jaxround.study.ego_lanes`). Its speed mode is 32: all
of SUMO's checks off, right of way inside junctions included (MSVehicle's
speed mode bits, SUMO's TraCI `setSpeedMode`), so a misjudged gap becomes a
collision, which SUMO detects (``--collision.check-junctions``, overlap only:
``--collision.mingap-factor 0``) and reports through
``simulation.getCollisions``, and the other drivers react to the ego as to
any vehicle.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from jaxround.scenario.config import load_config
from jaxround.scenario.edges import route_edges
from jaxround.study.ego_lanes import EgoLanes
from jaxround.study.ride_setup import (
    EGO_SPEED_FACTOR,
    RideSpec,
    ride_config,
    ride_schedule,
    sumo_command,
)
from sumo_export.scenario import HV_TYPE, route_id, vehicle_id, write_scenario

#: Ego acceleration at full throttle and deceleration at full brake, m/s^2.
EGO_ACCEL_MPS2 = 3.0
EGO_BRAKE_MPS2 = 8.0
#: Deceleration with neither pedal (rolling resistance, engine braking), m/s^2.
EGO_COAST_MPS2 = 0.4
EGO_MAX_SPEED_MPS = 20.0
#: SUMO speed mode of the ego: every check off, junction right of way too.
EGO_SPEED_MODE = 32
#: Simulated seconds of warm-up between two progress reports.
PROGRESS_EVERY_S = 5.0
#: How far ahead the vehicle ahead is looked for, m.
LEADER_LOOKAHEAD_M = 100.0


def ego_acceleration(throttle: float, brake: float) -> float:
    """The ego's acceleration for pedal positions in [0, 1], m/s^2."""
    return EGO_ACCEL_MPS2 * throttle - EGO_BRAKE_MPS2 * brake - EGO_COAST_MPS2


class RideSimulation:
    """A running SUMO of one ride, in this process (libsumo: one per process).

    Args:
        spec: the ride.
        workdir: where the scenario files are written.

    Attributes:
        trace: one dict per ride step (``ride_steps`` columns without timings).
        events: collisions and lane changes, as ``ride_events`` rows.
        lanes: the ego's turn signal and lanes (`EgoLanes`).
        ego_entered_s, ego_arrived_s: simulated times of the first entry and
            of the last pass's exit, None until they happen.
        crossings: crossing time of each pass done (entry to exit), s.
    """

    def __init__(self, spec: RideSpec, workdir: Path) -> None:
        import libsumo

        self.libsumo = libsumo
        self.spec = spec
        cfg = load_config(spec.config)
        self.cfg, self.schedule, ego_index = ride_schedule(cfg, spec)
        self.ego_id = vehicle_id(ego_index)
        self.ego_min_gap = cfg.drivers.hv.min_gap
        self.policy_every = round(cfg.simulation.dt_s / spec.step_s)
        self.controller = None
        if spec.share is not None and spec.policy is not None:
            from jaxround.apps.drivers import parse_driver, sumo_driver

            factory = sumo_driver(parse_driver(spec.policy))  # None: uncontrolled
            if factory is not None:
                self.controller = factory(self.cfg, self.schedule)
        files = write_scenario(
            ride_config(self.cfg, spec.step_s), self.schedule, workdir
        )
        self.net_file = files.net
        self.route = route_edges(spec.ego_origin, spec.ego_destination, cfg.n_legs)
        libsumo.start(sumo_command(files.sumocfg))
        self.steps = 0
        self.time_s = 0.0
        self.ego_entered_s: float | None = None
        self.ego_arrived_s: float | None = None
        self.ego_in_network = False
        self.pass_entered_s: float | None = None
        self.crossings: list[float] = []
        self.ego_speed = 0.0
        self.ego_pose: tuple[float, float, float] | None = None
        self.vehicle_ids: tuple[str, ...] = ()
        self.trace: list[dict[str, Any]] = []
        self.events: list[dict[str, Any]] = []
        self._contacts: set[str] = set()
        self.lanes = EgoLanes(libsumo, self.ego_id, spec.step_s, self.events)

    @property
    def ego_on_road(self) -> bool:
        return self.ego_in_network

    @property
    def current_pass(self) -> int:
        """The pass being driven (or waited for), 1 to ``spec.passes``."""
        return min(len(self.crossings) + 1, self.spec.passes)

    def warm_up(self, on_progress: Callable[[float], None] | None = None) -> None:
        """Step as fast as SUMO goes to just before the ego's departure.

        Args:
            on_progress: called with the share done (0-1) every
                `PROGRESS_EVERY_S` simulated seconds.
        """
        last = self.spec.warmup_s - self.spec.step_s + 1e-6
        every = max(1, round(PROGRESS_EVERY_S / self.spec.step_s))
        while self.time_s + self.spec.step_s <= last:
            self._advance()
            self.act()
            if on_progress is not None and self.steps % every == 0:
                on_progress(min(self.time_s / max(last, 1e-9), 1.0))

    def step(self, throttle: float, brake: float) -> int:
        """One real-time step: command the ego, step SUMO, read the ego.

        The policy acts afterwards (`act`), once the step's frame is out:
        its commands take effect in the next step either way.

        Args:
            throttle: pedal position in [0, 1].
            brake: pedal position in [0, 1].

        Returns:
            the time in SUMO's step, ns.
        """
        if self.ego_on_road:
            accel = ego_acceleration(throttle, brake)
            speed = min(
                max(self.ego_speed + accel * self.spec.step_s, 0.0), EGO_MAX_SPEED_MPS
            )
            self.libsumo.vehicle.setSpeed(self.ego_id, speed)
            self.lanes.request(self.time_s)
        sumo_ns = self._advance()
        self._read_ego(throttle, brake)
        return sumo_ns

    def ask_lane(self, direction: str) -> None:
        """The participant's turn signal, ``"left"`` or ``"right"``; ignored
        while the ego is not on the roads."""
        if self.ego_on_road:
            self.lanes.ask(direction, self.time_s)

    def act(self) -> int:
        """Let the policy act on the state after the last step, when it is
        its turn (every ``dt_s / step_s`` steps); returns its time, ns."""
        if self.controller is None or self.steps % self.policy_every != 0:
            return 0
        t0 = time.perf_counter_ns()
        self.controller(self.libsumo, self.time_s)
        return time.perf_counter_ns() - t0

    def _advance(self) -> int:
        t0 = time.perf_counter_ns()
        self.libsumo.simulation.step()
        self.steps += 1
        self.time_s = self.libsumo.simulation.getTime()
        return time.perf_counter_ns() - t0

    def _read_ego(self, throttle: float, brake: float) -> None:
        veh = self.libsumo.vehicle
        self.vehicle_ids = veh.getIDList()
        row: dict[str, Any] = {
            "time_s": round(self.time_s, 3),
            "on_road": 0,
            "throttle": throttle,
            "brake": brake,
        }
        self.ego_in_network = self.ego_id in self.vehicle_ids
        if self.ego_in_network:
            if self.pass_entered_s is None:
                self.pass_entered_s = self.time_s
                if self.ego_entered_s is None:
                    self.ego_entered_s = self.time_s
                veh.setSpeedMode(self.ego_id, EGO_SPEED_MODE)
                self.lanes.entered()
            x, y = veh.getPosition(self.ego_id)
            self.ego_pose = (x, y, veh.getAngle(self.ego_id))
            self.ego_speed = veh.getSpeed(self.ego_id)
            row.update(
                on_road=1,
                x_m=x,
                y_m=y,
                speed_mps=self.ego_speed,
                accel_mps2=veh.getAcceleration(self.ego_id),
            )
            row.update(self._gap_to_leader())
            self._record_collisions()
            self.lanes.read(self.time_s)
        elif self.pass_entered_s is not None and self._ego_arrived():  # it left
            self.crossings.append(round(self.time_s - self.pass_entered_s, 3))
            self.pass_entered_s = None
            self.ego_pose = None
            self.lanes.view = None
            if len(self.crossings) < self.spec.passes:
                self._send_ego_again()
            else:
                self.ego_arrived_s = self.time_s
        self.trace.append(row)

    def _ego_arrived(self) -> bool:
        """The ego left the network in this step (not a teleport, after which
        it comes back under its id)."""
        return self.ego_id in self.libsumo.simulation.getArrivedIDList()

    def _send_ego_again(self) -> None:
        """The next pass: the ego from its entry again, as it first departed."""
        veh = self.libsumo.vehicle
        route = route_id(self.spec.ego_origin, self.spec.ego_destination)
        veh.add(self.ego_id, route, typeID=HV_TYPE, depart="now", departLane="first",
                departPos="base", departSpeed="max")  # fmt: skip
        veh.setSpeedFactor(self.ego_id, EGO_SPEED_FACTOR)

    def _gap_to_leader(self) -> dict[str, float | None]:
        """Bumper gap to the vehicle ahead and the time to collide with it."""
        veh = self.libsumo.vehicle
        leader = veh.getLeader(self.ego_id, LEADER_LOOKAHEAD_M)
        if not leader or not leader[0]:
            return {"gap_m": None, "ttc_s": None}
        leader_id, gap = leader
        gap_m = gap + self.ego_min_gap  # getLeader's gap leaves minGap out
        closing = self.ego_speed - veh.getSpeed(leader_id)
        ttc = max(gap_m, 0.0) / closing if closing > 1e-6 else None
        return {"gap_m": gap_m, "ttc_s": ttc}

    def _record_collisions(self) -> None:
        """A collision event when the ego first touches another vehicle."""
        now = set()
        for c in self.libsumo.simulation.getCollisions():
            if self.ego_id not in (c.collider, c.victim):
                continue
            other = c.victim if c.collider == self.ego_id else c.collider
            now.add(other)
            if other not in self._contacts:
                role = "hit" if c.collider == self.ego_id else "was hit by"
                self.events.append(
                    {
                        "time_s": round(self.time_s, 3),
                        "kind": "collision",
                        "other": self.vehicle_class(other),
                        "detail": f"{c.type}: the ego {role} a vehicle",
                    }
                )
        self._contacts = now

    def vehicle_class(self, vid: str) -> str:
        """'hv' or 'av' for a vehicle of the schedule (the ego: 'hv')."""
        try:
            return "av" if self.schedule.is_av[int(vid[1:])] else "hv"
        except (ValueError, IndexError):
            return "unknown"

    @property
    def collisions(self) -> int:
        return sum(e["kind"] == "collision" for e in self.events)

    def ego_lanes(self) -> list[str]:
        """The lanes of the ego's route, road by road from the right."""
        count = self.libsumo.edge.getLaneNumber
        return [f"{edge}_{i}" for edge in self.route for i in range(count(edge))]

    def close(self) -> None:
        with contextlib.suppress(Exception):  # a simulation that failed to start
            self.libsumo.close()
