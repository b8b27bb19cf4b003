"""SUMO's lane changes on a roundabout, recorded step by step for
`jaxround.apps.ring_lane_replay`.

SUMO 1.28 runs the scenario (libsumo, the settings of `jaxround sumo`, human
drivers); after each step every vehicle's lane, position, speed and
acceleration are read, and each vehicle is followed along the lane paths
(`jaxround.lanes.paths`), which tells the lane changes SUMO made in the
step; SUMO's reasons come from its ``--lanechange-output``.
"""

from __future__ import annotations

import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from jaxround.lanes.paths import LanePaths
from jaxround.lanes.traci import REQUEST_STEPS
from jaxround.lanes.tracking import PathTracker
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import Schedule


@dataclass
class StepRecord:
    """One SUMO step, after its lane changes. Arrays over the vehicles on
    the network (ids in ``ids``): the lane path and position along it before
    the step's changes, the lane change made (-1 right, +1 left, 0 none),
    speed, acceleration, speed factor, AV or not, inserted this step, and
    the lane index a TraCI request asked for in the step (-1: none)."""

    time: float
    ids: list[str]
    path: np.ndarray
    pos: np.ndarray
    change: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    speed_factor: np.ndarray
    is_av: np.ndarray
    new: np.ndarray
    request: np.ndarray


#: What a scripted lane policy gives before a step: lane indices by vehicle.
LanePolicy = Callable[[Any, list[str]], dict[str, int]]
#: How far the gap policy looks for leaders (m).
GAP_SIGHT_M = 100.0


def scripted_policy(name: str) -> LanePolicy:
    """The AVs' scripted lane requests: ``inner`` (lane 1) or ``outer``
    (lane 0) always, or ``gap:X``: on a two-lane edge, the other lane when
    its leader (within `GAP_SIGHT_M`) is more than X m further than this
    lane's. Human drivers are never asked."""
    import libsumo

    from sumo_export.scenario import AV_TYPE

    kind, _, margin = name.partition(":")
    if kind in ("inner", "outer") and not margin:
        lane = 1 if kind == "inner" else 0

        def always(vehicle: Any, ids: list[str]) -> dict[str, int]:
            return {v: lane for v in ids if vehicle.getTypeID(v) == AV_TYPE}

        return always
    try:
        margin_m = float(margin) if kind == "gap" else float("nan")
    except ValueError:
        margin_m = float("nan")
    if not margin_m >= 0:
        raise ValueError(f"lane policy {name!r}: expected inner, outer or gap:X (m)")

    def larger_gap(vehicle: Any, ids: list[str]) -> dict[str, int]:
        asked = {}
        for vid in ids:
            if vehicle.getTypeID(vid) != AV_TYPE:
                continue
            if libsumo.edge.getLaneNumber(vehicle.getRoadID(vid)) != 2:
                continue
            lane = vehicle.getLaneIndex(vid)
            leader = vehicle.getLeader(vid, GAP_SIGHT_M)
            own = leader[1] if leader and leader[0] else GAP_SIGHT_M
            side = vehicle.getLeftLeaders if lane == 0 else vehicle.getRightLeaders
            other = min((gap for _, gap in side(vid)), default=GAP_SIGHT_M)
            if other > own + margin_m:
                asked[vid] = 1 - lane
        return asked

    return larger_gap


def record_sumo(
    cfg: ScenarioConfig,
    paths: LanePaths,
    duration_s: float,
    schedule: Schedule,
    lane_policy: LanePolicy | None = None,
) -> tuple[list[StepRecord], dict[tuple[float, str], str]]:
    """Run the first ``duration_s`` seconds of ``schedule`` in SUMO.

    Args:
        lane_policy: called before every step with libsumo's ``vehicle``
            module and the vehicles on the network; each lane index it
            returns is sent as ``changeLane(id, index, duration)`` for
            this step only (`jaxround.lanes.traci.REQUEST_STEPS`)
            (lane-change mode left at SUMO's default, 1621).

    Returns the steps and SUMO's reason for each change, by (time, id).
    """
    import libsumo

    from sumo_export.runner import sumo_arguments
    from sumo_export.scenario import AV_TYPE, write_scenario

    steps: list[StepRecord] = []
    dt = cfg.simulation.dt_s
    with tempfile.TemporaryDirectory(prefix="jaxround-lanes-") as tmp:
        out = Path(tmp)
        files = write_scenario(cfg, schedule, out)
        changes_xml = out / "changes.xml"
        libsumo.start(
            sumo_arguments(files.sumocfg, out / "trips.xml", out / "stats.xml")
            + ["--lanechange-output", str(changes_xml)]
        )
        tracker = PathTracker(paths)
        route_of = {}
        try:
            vehicle = libsumo.vehicle
            ids: list[str] = []
            for _ in tqdm(range(int(round(duration_s / dt))), desc="SUMO", leave=False):
                asked = lane_policy(vehicle, ids) if lane_policy else {}
                for vid, index in asked.items():
                    vehicle.changeLane(vid, index, REQUEST_STEPS * dt)
                libsumo.simulationStep()
                ids = list(vehicle.getIDList())
                new = np.array([vid not in tracker.state for vid in ids], bool)
                rows = []
                for vid, is_new in zip(ids, new, strict=True):
                    if is_new:
                        o, d = (int(x) for x in vehicle.getRouteID(vid).split("_")[1:])
                        route_of[vid] = int(paths.route_index[o, d])
                    before, _, change = tracker.step(
                        vid, vehicle.getLaneID(vid), route_of[vid]
                    )
                    lane = tracker.index[vehicle.getLaneID(vid)]
                    own = (
                        lane
                        if change == 0
                        else (paths.lane_right if change > 0 else paths.lane_left)[lane]
                    )
                    rows.append((
                        before, paths.lane_offset[before, own]
                        + vehicle.getLanePosition(vid), change,
                        vehicle.getSpeed(vid), vehicle.getAcceleration(vid),
                        vehicle.getSpeedFactor(vid),
                        vehicle.getTypeID(vid) == AV_TYPE,
                    ))  # fmt: skip
                for vid in libsumo.simulation.getArrivedIDList():
                    tracker.state.pop(vid, None)
                columns = list(zip(*rows, strict=True)) if rows else [()] * 7
                steps.append(StepRecord(
                    time=libsumo.simulation.getTime(), ids=ids,
                    path=np.array(columns[0], np.int32), pos=np.array(columns[1]),
                    change=np.array(columns[2], np.int32),
                    speed=np.array(columns[3]), accel=np.array(columns[4]),
                    speed_factor=np.array(columns[5]),
                    is_av=np.array(columns[6], bool), new=new,
                    request=np.array([asked.get(v, -1) for v in ids], np.int32),
                ))  # fmt: skip
        finally:
            libsumo.close()
        # the output's time is the step's start, the records' its end
        reasons = {
            (float(c.get("time")) + dt, c.get("id")): c.get("reason", "")
            for c in ET.parse(changes_xml).getroot().iter("change")
        }
    return steps, reasons
