"""SUMO's strategic lane table, `jaxround.lanes.best_lanes`, against SUMO 1.28.

Each route of a network is driven by one vehicle alone (the next one is
added when the last has left), and at every step `libsumo.vehicle.getBestLanes`
is compared with the module's rows: lengths within 0.01 m, offsets,
`allowsContinuation` and the continuation lanes exactly. On a normal edge the
rows are the current edge's (`route_rows`); on an internal lane SUMO keeps
the table built on the edge before and restricts the next edge's rows to the
lanes the internal edge leads to (`internal_lane_rows`).

Networks: configs/two_lane.yaml (four legs, one-lane exits), the same with
two-lane exits (the inner ring lane's exit link is minor: the priority
cut-back of `updateBestLanes` shortens it), and a five-leg roundabout with
one- and two-lane entries and exits, not used while writing the module. The
look-ahead window is checked with a slow vType on routes it does not cover:
three laps of two_lane.yaml's ring (the 8-edge / 200 m rule) and a 2.9 km
entry (the 4-edge / 3,000 m rule).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import sumolib

from jaxround.lanes.best_lanes import (
    LaneRow,
    LookAheadDriver,
    internal_lane_rows,
    route_rows,
    scenario_best_lanes,
    scenario_routes,
)
from jaxround.scenario.config import ScenarioConfig, config_from_dict, load_config
from jaxround.scenario.edges import in_edge, out_edge, ring_edge
from jaxround.sumo_files.binaries import sumo_binary
from jaxround.sumo_files.netconvert import network_file
from sumo_export.scenario import HV_TYPE, vtype_xml
from tests.conftest import builtin_dict
from tests.sumo.two_lane_networks import five_legs, two_lane_exits

pytestmark = pytest.mark.sumo

LENGTH_TOLERANCE_M = 0.01

#: A vType so slow that its braking distance leaves the look-ahead to the
#: fixed 200 m and 3,000 m (SUMO's passenger defaults otherwise).
SLOW_VTYPE = '<vType id="slow" maxSpeed="5" speedDev="0" sigma="0"/>'
SLOW_DRIVER = LookAheadDriver(max_speed=5.0)


@dataclass(frozen=True)
class Reading:
    """`getBestLanes` of the vehicle of route `route` at one step."""

    route: int
    route_index: int  # `getRouteIndex`: the last normal route edge entered
    road: str
    rows: tuple[tuple[Any, ...], ...]


def drive_alone(
    workdir: Path,
    net: Path,
    routes: list[list[str]],
    vtype: str,
    type_id: str,
    step_length: float,
) -> list[Reading]:
    """Each route driven by one vehicle alone, `getBestLanes` at every step."""
    import libsumo

    rou = workdir / "alone.rou.xml"
    rou.write_text(
        "<routes>\n" + vtype + "\n"
        + "".join(f'<route id="r{r}" edges="{" ".join(route)}"/>\n'
                  for r, route in enumerate(routes))
        + "</routes>\n"
    )  # fmt: skip
    libsumo.start(
        [sumo_binary("sumo"), "-n", str(net), "-r", str(rou),
         "--step-length", str(step_length), "--no-step-log", "true",
         "--no-warnings", "true"]
    )  # fmt: skip
    readings = []
    try:
        for r in range(len(routes)):
            vid = f"v{r}"
            libsumo.vehicle.add(vid, f"r{r}", typeID=type_id, departLane="best",
                                departSpeed="max")  # fmt: skip
            for _ in range(10_000):
                libsumo.simulationStep()
                if vid in libsumo.simulation.getArrivedIDList():
                    break
                if vid in libsumo.vehicle.getIDList():
                    readings.append(Reading(
                        r, libsumo.vehicle.getRouteIndex(vid),
                        libsumo.vehicle.getRoadID(vid),
                        tuple(libsumo.vehicle.getBestLanes(vid)),
                    ))  # fmt: skip
            else:
                raise AssertionError(f"{vid} did not arrive")
    finally:
        libsumo.close()
    return readings


def mismatch(got: tuple[tuple[Any, ...], ...], expected: list[LaneRow]) -> str | None:
    """Why SUMO's rows differ from the module's, or None if they agree.

    A `getBestLanes` row: (laneID, length, occupation, bestLaneOffset,
    allowsContinuation, nextLanes); nextLanes starts with the lane itself.
    """
    if [g[0] for g in got] != [e.lane_id for e in expected]:
        return f"lanes {[g[0] for g in got]} != {[e.lane_id for e in expected]}"
    for g, e in zip(got, expected, strict=True):
        lane_id, length, _occupation, offset, allows, next_lanes = g
        if abs(length - e.length) > LENGTH_TOLERANCE_M:
            return f"{lane_id}: length {length} != {e.length}"
        if (offset, allows, tuple(next_lanes)) != (
            e.best_lane_offset,
            e.allows_continuation,
            e.continuations,
        ):
            return f"{lane_id}: {g} != {e}"
    return None


@dataclass(frozen=True)
class Drive:
    """A network, its routes, what SUMO returned and what the module says."""

    net: sumolib.net.Net
    routes: list[list[str]]
    readings: list[Reading]
    driver: LookAheadDriver

    def normal_and_internal(self) -> tuple[list[Reading], list[Reading]]:
        normal = [x for x in self.readings if not x.road.startswith(":")]
        return normal, [x for x in self.readings if x.road.startswith(":")]

    def check(self) -> tuple[int, int]:
        """Compare every reading; the numbers of normal and internal readings."""
        expected = [route_rows(self.net, route, self.driver) for route in self.routes]
        normal, internal = self.normal_and_internal()
        wrong = []
        for x in normal:
            assert x.road == self.routes[x.route][x.route_index]
            why = mismatch(x.rows, expected[x.route][x.route_index])
            if why:
                wrong.append(f"route {x.route} on {x.road}: {why}")
        for x in internal:
            rows = internal_lane_rows(self.net, self.routes[x.route], x.route_index,
                                      x.road, self.driver)  # fmt: skip
            why = mismatch(x.rows, rows)
            if why:
                wrong.append(f"route {x.route} on {x.road}: {why}")
        assert not wrong, f"{len(wrong)} of {len(self.readings)} readings differ:\n" + (
            "\n".join(wrong[:10])
        )
        visited = {(x.route, x.route_index) for x in normal}
        assert visited == {
            (r, k) for r, route in enumerate(self.routes) for k in range(len(route))
        }
        return len(normal), len(internal)


def scenario_drive(tmp_path: Path, cfg: ScenarioConfig) -> Drive:
    """Every route of the scenario, by its human drivers' vType at its step."""
    path = network_file(cfg, tmp_path)
    routes = scenario_routes(cfg.n_legs)
    dt = cfg.simulation.dt_s
    vtype = vtype_xml(HV_TYPE, cfg.drivers.hv, dt)
    readings = drive_alone(tmp_path, path, routes, vtype, HV_TYPE, dt)
    net = sumolib.net.readNet(str(path), withInternal=True)
    return Drive(net, routes, readings, LookAheadDriver.from_config(cfg.drivers.hv, dt))


def test_two_lane_yaml_rows_match_sumo(tmp_path: Path) -> None:
    """configs/two_lane.yaml: the inner lane (1) of every entry and ring edge
    ahead of the exit points right (-1) with a shorter length; the one-lane
    exits are left from the outer lane only, so nothing is cut back."""
    cfg = load_config("two_lane")
    n_normal, n_internal = scenario_drive(tmp_path, cfg).check()
    assert n_normal > 400 and n_internal > 80
    arrays = scenario_best_lanes(cfg, network_file(cfg, tmp_path))
    assert arrays.length.shape == (12, 5, 2)
    assert arrays.continuation.shape == (12, 5, 2, 5)
    for r, route in enumerate(arrays.route_edge_ids):
        last = len(route) - 1
        assert (arrays.best_lane_offset[r, :last, 1] == -1).all()
        assert (arrays.length[r, :last, 1] < arrays.length[r, :last, 0]).all()
        assert not arrays.allows_continuation[r, last - 1, 1]
        assert arrays.n_lanes[r, last] == 1
        assert (arrays.n_lanes[r, last + 1 :] == 0).all()
        # the outer lane's continuation runs to the exit, lane 0 all along
        assert (arrays.continuation[r, 0, 0, : last + 1] == 0).all()
    net = sumolib.net.readNet(str(network_file(cfg, tmp_path)))
    driver = LookAheadDriver.from_config(cfg.drivers.hv, cfg.simulation.dt_s)
    for r, route in enumerate(arrays.route_edge_ids):
        for k, rows in enumerate(route_rows(net, route, driver)):
            for z, row in enumerate(rows):
                assert arrays.length[r, k, z] == row.length
                assert arrays.best_lane_offset[r, k, z] == row.best_lane_offset
                assert arrays.allows_continuation[r, k, z] == row.allows_continuation
                ids = [
                    f"{route[k + j]}_{i}"
                    for j, i in enumerate(arrays.continuation[r, k, z])
                    if i >= 0
                ]
                assert tuple(ids) == row.continuations


def test_two_lane_exits_cut_the_inner_lane_back(tmp_path: Path) -> None:
    """Two-lane exits joined lane to lane: the inner ring lane leads on to
    the exit's left lane over a minor link (`m`) while the outer one's is
    major (`M`), so on the last ring edge the inner lane, though it
    continues, keeps only its own length and points right."""
    cfg = two_lane_exits()
    drive = scenario_drive(tmp_path, cfg)
    drive.check()
    for route in drive.routes:
        last_ring = route[-2]
        inner = route_rows(drive.net, route, drive.driver)[-2][1]
        assert inner.allows_continuation and inner.continuations[-1] == f"{route[-1]}_1"
        assert inner.length == drive.net.getEdge(last_ring).getLength()
        assert inner.best_lane_offset == -1


def test_five_legs_mixed_lanes_match_sumo(tmp_path: Path) -> None:
    """A geometry not used while writing the module: five legs, one- and
    two-lane entries and exits (20 routes of up to 6 edges). A one-lane
    entry's internal lane shows the one ring lane it leads to; the inner
    lane is cut back before the two-lane exits of legs 1 and 4."""
    drive = scenario_drive(tmp_path, five_legs())
    n_normal, n_internal = drive.check()
    assert len(drive.routes) == 20 and n_normal > 500 and n_internal > 100
    entry, ring = drive.net.getEdge(in_edge(2)), drive.net.getEdge(ring_edge(2))
    via = entry.getOutgoing()[ring][0].getViaLaneID().rpartition("_")[0]
    _, internal = drive.normal_and_internal()
    on_via = {tuple(row[0] for row in x.rows) for x in internal if x.road == via}
    assert on_via == {(f"{ring_edge(2)}_0",)}
    cut_before = set()
    for route in drive.routes:
        for k, rows in enumerate(route_rows(drive.net, route, drive.driver)):
            edge_length = drive.net.getEdge(route[k]).getLength()
            if any(len(row.continuations) > 1 and row.length == edge_length
                   for row in rows):  # fmt: skip
                cut_before.add(route[k + 1])
    assert cut_before == {out_edge(1), out_edge(4)}


@pytest.mark.parametrize(
    ("leg_length", "route"),
    [
        # three laps: from the entry 9 edges (8 ring edges) are seen, 227.5 m
        (None, [in_edge(0)] + [ring_edge(i % 4) for i in range(13)] + [out_edge(1)]),
        # a 2.9 km entry: 8 edges (3,010.32 m) are seen; the 3,000 m ends the
        # window, not maxBrakeDist (2,902.99 m), which would end it at 5
        (2900.0, [in_edge(0)] + [ring_edge(i % 4) for i in range(9)] + [out_edge(1)]),
    ],
    ids=["laps", "long_entry"],
)
def test_look_ahead_window(
    tmp_path: Path, leg_length: float | None, route: list[str]
) -> None:
    """On routes longer than the window, the entry's rows are SUMO's with
    the window (both lanes lead as far as it looks: offset 0), not those of
    the whole route (the inner lane ends before the exit: offset -1). On
    the internal lanes after the entry SUMO shows the rows of the table
    built on the entry, which here differ from the next edge's own."""
    d = builtin_dict("two_lane")
    if leg_length is not None:
        d["network"]["legs"][0]["length_m"] = leg_length
    path = network_file(config_from_dict(d), tmp_path)
    readings = drive_alone(tmp_path, path, [route], SLOW_VTYPE, "slow", 1.0)
    net = sumolib.net.readNet(str(path), withInternal=True)
    Drive(net, [route], readings, SLOW_DRIVER).check()
    windowed = route_rows(net, route, SLOW_DRIVER)[0]
    whole = route_rows(net, route, LookAheadDriver(max_speed=1e6))[0]
    assert [row.best_lane_offset for row in windowed] == [0, 0]
    assert [row.best_lane_offset for row in whole] == [0, -1]
