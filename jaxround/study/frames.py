"""What the browser draws after a step, built from a running ride.

A frame is plain JSON data, one per step (`ride_frame`, `frame_bytes`); the
ride's lanes for the mini-map come with its ``ready`` message (`ego_lanes`).
"""

from __future__ import annotations

import json
from typing import Any

from jaxround.study.sim import RideSimulation


def ride_frame(sim: RideSimulation, step: int, input_seq: int) -> dict[str, Any]:
    """What the browser draws after this step (plain data).

    ``cars``: flat [number, x, y, angle, ...] of the other vehicles
    (SUMO's front-bumper position, m, and heading, degrees clockwise from
    north); ``ego``: [x, y, angle, speed] or None while it is not on the
    roads (before it enters, between passes, after the last); ``pass`` of
    ``passes``: the pass being driven; ``lane``: the ego's lane, its road's
    lanes, its turn signal and the side its route needs it on
    (`jaxround.study.ego_lanes.EgoLanes.view`), or None inside a junction
    or off the roads. Nothing tells an AV from a human driver.
    """
    veh = sim.libsumo.vehicle
    cars: list[float] = []
    for vid in sim.vehicle_ids:
        if vid == sim.ego_id:
            continue
        x, y = veh.getPosition(vid)
        cars += (int(vid[1:]), round(x, 2), round(y, 2), round(veh.getAngle(vid), 1))
    ego = None
    if sim.ego_pose is not None:
        x, y, angle = sim.ego_pose
        ego = [round(x, 2), round(y, 2), round(angle, 1), round(sim.ego_speed, 2)]
    return {
        "type": "frame",
        "step": step,
        "t": round(sim.time_s, 2),
        "seq": input_seq,
        "pass": sim.current_pass,
        "passes": sim.spec.passes,
        "ego": ego,
        "lane": sim.lanes.view,
        "cars": cars,
        "collisions": sim.collisions,
    }


def frame_bytes(frame: dict[str, Any]) -> bytes:
    """A frame as compact JSON."""
    return json.dumps(frame, separators=(",", ":"), allow_nan=False).encode()
