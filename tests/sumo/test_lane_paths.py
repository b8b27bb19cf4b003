"""Lane paths (`jaxround.lanes.paths`) against SUMO 1.28's own vehicles.

Steady flows on every route of a two-lane roundabout, run in libsumo with
the scenario's human drivers; every vehicle is followed step by step as a
(path, position along the path): inserted on `depart_path` of its lane,
each step either on the next lanes of its path or, after a lane change, on
the path `change_path` names, and its position along the path advances by
exactly its speed times the step (SUMO's Euler update) through junctions
and lane changes, which proves the paths' offsets and that a change keeps
the position on the lane. Every vehicle arrives on a complete path.

Networks: configs/two_lane.yaml, the same with two-lane exits, and the
held-out five-leg roundabout of `tests.sumo.two_lane_networks`.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from jaxround.lanes.paths import LEFT, RIGHT, LanePaths, lane_paths
from jaxround.scenario.config import ScenarioConfig, load_config
from jaxround.scenario.edges import route_edges
from jaxround.sumo_files.binaries import sumo_binary
from jaxround.sumo_files.compile import compile_network
from jaxround.sumo_files.netconvert import network_file
from sumo_export.scenario import HV_TYPE, vtype_xml
from tests.sumo.two_lane_networks import five_legs, two_lane_exits

pytestmark = pytest.mark.sumo

#: SUMO writes positions in doubles; the path offsets are sums of lane lengths.
POSITION_TOLERANCE_M = 1e-6


def flows(cfg: ScenarioConfig, per_hour: float, end_s: float) -> str:
    """One flow per route, ids ``f<origin>_<exit>``, on SUMO's best lane."""
    n = cfg.n_legs
    return "".join(
        f'<flow id="f{o}_{d}" type="{HV_TYPE}" begin="0" end="{end_s}" '
        f'vehsPerHour="{per_hour}" departLane="best" departSpeed="max">'
        f'<route edges="{" ".join(route_edges(o, d, n))}"/></flow>'
        for o in range(n)
        for d in range(n)
        if o != d
    )


def follow_vehicles(
    tmp_path: Path, cfg: ScenarioConfig, per_hour: float, end_s: float
) -> tuple[LanePaths, Counter]:
    """Run the flows in libsumo and follow every vehicle along the paths.

    Returns the paths and a tally: steps checked, changes by kind
    ("normal"/"internal", "right"/"left"), vehicles that drove a path that
    does not reach their exit, vehicles arrived.
    """
    import libsumo

    net = network_file(cfg, tmp_path)
    paths = lane_paths(net, cfg.n_legs)
    lane = {lid: k for k, lid in enumerate(paths.lane_ids)}
    edge = [lid.rsplit("_", 1)[0] for lid in paths.lane_ids]
    dt = cfg.simulation.dt_s
    rou = tmp_path / "flows.rou.xml"
    rou.write_text(
        f"<routes>{vtype_xml(HV_TYPE, cfg.drivers.hv, dt)}"
        f"{flows(cfg, per_hour, end_s)}</routes>"
    )
    libsumo.start(
        [sumo_binary("sumo"), "-n", str(net), "-r", str(rou), "--step-length",
         str(dt), "--no-step-log", "true", "--no-warnings", "true", "--seed", "1"]
    )  # fmt: skip
    state: dict[str, tuple[int, int, int, float]] = {}  # route, path, k, s
    tally: Counter = Counter()
    try:
        for _ in range(int(round(2 * end_s / dt))):
            libsumo.simulationStep()
            for vid in libsumo.simulation.getArrivedIDList():
                route, path, _, _ = state.pop(vid)
                assert paths.path_complete[path], f"{vid} arrived off its path"
                tally["arrived"] += 1
            for vid in libsumo.vehicle.getIDList():
                lane_now = lane[libsumo.vehicle.getLaneID(vid)]
                pos_on_lane = libsumo.vehicle.getLanePosition(vid)
                if vid not in state:
                    o, d = (int(x) for x in vid[1:].split(".")[0].split("_"))
                    route = int(paths.route_index[o, d])
                    path = int(paths.depart_path[route, paths.lane_index[lane_now]])
                    assert paths.path_lanes[path, 0] == lane_now
                    state[vid] = (route, path, 0, pos_on_lane)
                    continue
                route, path, _, s = state[vid]
                # the path's lane on the vehicle's edge (its own lane unless
                # it has just changed)
                k = next(
                    k for k, x in enumerate(paths.path_lanes[path])
                    if x >= 0 and edge[x] == edge[lane_now]
                )  # fmt: skip
                on_path = int(paths.path_lanes[path, k])
                moved = paths.path_lane_start[path, k] + pos_on_lane - s
                expected = libsumo.vehicle.getSpeed(vid) * dt
                assert abs(moved - expected) < POSITION_TOLERANCE_M, (
                    f"{vid} on {paths.lane_ids[lane_now]}: moved {moved} m "
                    f"along path {paths.path_lane_ids(path)}, speed x dt {expected}"
                )
                tally["steps"] += 1
                if on_path != lane_now:
                    side = LEFT if paths.lane_left[on_path] == lane_now else RIGHT
                    assert (paths.lane_right, paths.lane_left)[side][
                        on_path
                    ] == lane_now, f"{vid}: {paths.lane_ids[lane_now]} off its path"
                    new = int(paths.change_path[path, k, side])
                    assert new >= 0, (
                        f"{vid} changed on {paths.lane_ids[on_path]}, "
                        "where the paths allow no change"
                    )
                    assert paths.path_lanes[new, k] == lane_now
                    kind = "internal" if paths.lane_internal[lane_now] else "normal"
                    tally[f"{kind} {('right', 'left')[side]}"] += 1
                    if not paths.path_complete[path]:
                        tally["left a dead-end path"] += 1
                    path = new
                s = paths.path_lane_start[path, k] + pos_on_lane
                state[vid] = (route, path, k, s)
    finally:
        libsumo.close()
    assert not state, f"{len(state)} vehicles still driving"
    return paths, tally


#: Per network: whether some paths end on the ring (one-lane exits), and
#: whether the ring's junctions have two-lane internal edges to change on.
NETWORKS = {
    "two_lane": (lambda: load_config("two_lane"), True, True),
    "two_lane_exits": (two_lane_exits, False, False),
    "five_legs": (five_legs, True, True),
}


@pytest.mark.parametrize("name", list(NETWORKS))
def test_sumo_vehicles_stay_on_the_paths(tmp_path: Path, name: str) -> None:
    config, dead_ends, internal_changes = NETWORKS[name]
    paths, tally = follow_vehicles(tmp_path, config(), per_hour=200.0, end_s=400.0)
    assert tally["arrived"] > 250 and tally["steps"] > 15_000
    # changes both ways; off every path that ends before the exit
    assert tally["normal left"] > 100 and tally["normal right"] > 100
    assert (tally["left a dead-end path"] > 100) == dead_ends
    assert (tally["internal left"] + tally["internal right"] > 0) == internal_changes
    assert (~paths.path_complete).any() == dead_ends


def test_two_lane_paths_and_links(tmp_path: Path) -> None:
    """two_lane.yaml: two paths a route, the inner one ending on the ring
    edge before the exit; changes allowed on the entries, the ring and its
    through junction lanes, not on the entries' junction lanes; the left
    entry lane's link gives way to both ring lanes, the right one's to the
    outer ring lane only (the junction's response bits)."""
    paths = lane_paths(network_file(load_config("two_lane"), tmp_path))
    ids = paths.lane_ids
    assert paths.n_paths == 2 * len(paths.route_od)
    for r, (o, d) in enumerate(paths.route_od):
        outer, inner = paths.depart_path[r]
        assert paths.path_complete[outer] and not paths.path_complete[inner]
        assert all(
            ids[lane].endswith("_0") for lane in paths.path_lanes[outer] if lane >= 0
        )
        assert paths.path_lane_ids(inner)[-1] == f"ring_{(d - 1) % 4}_1"
        for k, lane in enumerate(paths.path_lanes[outer]):
            if lane < 0:
                continue
            entry_junction = ids[lane].startswith(f":c{o}_")
            can_change = paths.change_path[outer, k, LEFT] >= 0
            exit_link = k == np.sum(paths.path_lanes[outer] >= 0) - 2
            lane_count_one = ids[lane].startswith("out_")
            assert can_change == (
                not entry_junction and not exit_link and not lane_count_one
            )
    foes = {
        ids[k]: sorted(ids[f] for f in row if f >= 0)
        for k, row in enumerate(paths.link_foes)
    }
    assert foes[":c0_0_0"] == [":c0_3_0"]
    assert foes[":c0_0_1"] == [":c0_3_0", ":c0_3_1"]
    assert foes[":c0_3_0"] == foes[":c0_3_1"] == foes[":c0_2_0"] == []


def test_two_lane_exits_inner_exit_gives_way(tmp_path: Path) -> None:
    """With two-lane exits every path is complete, and the inner lane's exit
    gives way at an internal junction to the outer lane going on round."""
    paths = lane_paths(network_file(two_lane_exits(), tmp_path))
    assert paths.path_complete.all()
    first_exit = paths.path_lane_ids(paths.depart_path[paths.route_index[0, 1], 1])
    assert first_exit == ["in_0_1", ":c0_0_1", "ring_0_1", ":c1_4_0", ":c1_6_0",
                          "out_1_1"]  # fmt: skip
    lane = paths.lane_ids.index(":c1_6_0")
    assert paths.lane_link_state[lane] == "m"
    foes = [paths.lane_ids[f] for f in paths.link_foes[lane] if f >= 0]
    going_round = paths.path_lane_ids(paths.depart_path[paths.route_index[0, 2], 0])
    assert foes == [":c1_3_0"] and ":c1_3_0" in going_round


@pytest.mark.parametrize("config", ["milan", "three_leg", "six_leg"])
def test_single_lane_paths_are_the_routes(tmp_path: Path, config: str) -> None:
    """On one-lane roundabouts a route is one path, lane for lane the route
    the single-lane step drives, with no change anywhere."""
    cfg = load_config(config)
    net = network_file(cfg, tmp_path)
    paths, compiled = lane_paths(net), compile_network(net)
    assert paths.n_paths == compiled.n_routes
    assert (paths.path_route == np.arange(compiled.n_routes)).all()
    for r in range(compiled.n_routes):
        assert paths.path_lane_ids(r) == [
            compiled.lane_ids[k] for k in compiled.route_lanes[r] if k >= 0
        ]
        np.testing.assert_allclose(paths.path_length[r], compiled.route_length[r])
    assert (paths.change_path < 0).all()
    assert (paths.route_index == compiled.route_index).all()
