"""A two-lane roundabout in real SUMO: netconvert's lane-to-lane joins at
its junctions, a short run in which vehicles arrive and change lanes."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import sumolib

from jaxround.core.network import NetworkError
from jaxround.scenario.config import config_from_dict, load_config
from jaxround.scenario.edges import in_edge, out_edge, ring_edge
from jaxround.scenario.schedule import make_schedule
from jaxround.sumo_files.compile import compile_network
from jaxround.sumo_files.netconvert import network_file
from sumo_export.runner import run_schedule
from tests.conftest import builtin_dict, small_config

pytestmark = pytest.mark.sumo


def joins(net: sumolib.net.Net, a: str, b: str) -> dict[int, tuple[int, str]]:
    """{lane of edge a: (lane of edge b, link state)} of the joins from a to b."""
    conns = net.getEdge(a).getOutgoing().get(net.getEdge(b), [])
    return {c.getFromLane().getIndex(): (c.getToLane().getIndex(), c.getState())
            for c in conns}  # fmt: skip


def link(net: sumolib.net.Net, a: str, lane: int, b: str):
    """The connection from lane `lane` of edge a to edge b."""
    (conn,) = [
        c for c in net.getEdge(a).getLane(lane).getOutgoing() if c.getTo().getID() == b
    ]
    return conn


def test_two_lane_network_joins(tmp_path: Path) -> None:
    """configs/two_lane.yaml: a two-lane ring, two-lane entries and one-lane
    exits, joined as netconvert joins them."""
    cfg = load_config("two_lane")
    path = network_file(cfg, tmp_path)
    net = sumolib.net.readNet(str(path), withInternal=True)
    n = cfg.n_legs
    for i in range(n):
        j = (i + 1) % n
        ring, after = ring_edge(i), ring_edge(j)
        assert net.getEdge(in_edge(i)).getLaneNumber() == 2
        assert net.getEdge(ring).getLaneNumber() == 2
        assert net.getEdge(out_edge(i)).getLaneNumber() == 1
        # each entry lane enters the ring on its own lane, giving way
        assert joins(net, in_edge(j), after) == {0: (0, "m"), 1: (1, "m")}
        # each ring lane goes on round on its own lane, with priority
        assert joins(net, ring, after) == {0: (0, "M"), 1: (1, "M")}
        # a one-lane exit is left from the outer lane: the inner lane's
        # vehicles change to it first
        assert joins(net, ring, out_edge(j)) == {0: (0, "M")}
        # the outer entry lane gives way to the outer ring lane, the inner
        # entry lane to both, whose paths it crosses
        node = net.getNode(f"c{j}")
        outer_on, inner_on = (link(net, ring, k, after) for k in (0, 1))
        outer_in, inner_in = (link(net, in_edge(j), k, after) for k in (0, 1))
        assert node.forbids(outer_on, outer_in) and not node.forbids(inner_on, outer_in)
        assert node.forbids(outer_on, inner_in) and node.forbids(inner_on, inner_in)
    with pytest.raises(NetworkError, match="several lanes"):
        compile_network(path, n)


def test_two_lane_exits_are_joined_lane_to_lane(tmp_path: Path) -> None:
    """Two-lane exits: the outer ring lane leaves to the exit's right lane,
    the inner one to its left lane, giving way to the outer lane going on."""
    d = builtin_dict("two_lane")
    for leg in d["network"]["legs"]:
        leg["exit_lanes"] = 2
    cfg = config_from_dict(d)
    net = sumolib.net.readNet(str(network_file(cfg, tmp_path)), withInternal=True)
    for i in range(cfg.n_legs):
        j = (i + 1) % cfg.n_legs
        ring, after = ring_edge(i), ring_edge(j)
        assert joins(net, ring, out_edge(j)) == {0: (0, "M"), 1: (1, "m")}
        assert joins(net, ring, after) == {0: (0, "M"), 1: (1, "M")}
        node = net.getNode(f"c{j}")
        outer_on = link(net, ring, 0, after)
        assert node.forbids(outer_on, link(net, ring, 1, out_edge(j)))
    assert (tmp_path / f"{cfg.name}.net.xml").is_file()


def test_two_lane_roundabout_runs_in_sumo(tmp_path: Path) -> None:
    """1,800 veh/h (below capacity), half AVs: every vehicle arrives, none
    collides or teleports, and vehicles use both entry lanes and leave the
    inner ring lane for the one-lane exits."""
    cfg = small_config("two_lane", n_vehicles=200, duration_s=400.0)
    run = run_schedule(cfg, make_schedule(cfg, seed=0, penetration=0.5), tmp_path)
    assert run.records.arrived.all()
    assert run.collisions == 0 and run.teleports == 0
    changes = list(ET.parse(tmp_path / "lanechange.xml").getroot().iter("change"))
    assert run.lane_changes == len(changes) > 0
    moves = {(c.get("from"), c.get("to")) for c in changes}
    assert any(a.startswith("in_") and a.endswith("_0") for a, _ in moves)
    assert any(a.startswith("ring_") and a.endswith("_1") for a, _ in moves)
    assert (tmp_path / "two_lane.rou.xml").read_text().count('departLane="best"') == 200


def test_the_jax_environment_needs_the_lane_changer() -> None:
    """Built by hand from a single-lane network and without a lane changer,
    `RoundaboutEnv` refuses a config with two-lane roads, naming `make`."""
    from jaxround.envs.roundabout import RoundaboutEnv

    milan = compile_network(network_file(load_config("milan")), 4)
    with pytest.raises(ValueError, match="has two-lane roads: build its environment"):
        RoundaboutEnv(load_config("two_lane"), milan, max_vehicles=8)


def test_sumo_sweep_summarises_a_two_lane_run() -> None:
    """`jaxround sumo`'s sweep, SUMO only, runs the two-lane roundabout."""
    from sumo_export.evaluate import sumo_sweep

    cfg = small_config("two_lane", n_vehicles=120, duration_s=300.0)
    mean = sumo_sweep(cfg, [0.5], [0], workers=1, show_progress=False)[0.5]["mean"]
    assert mean["all"]["n_arrived"] == 120
    assert mean["collisions"] == 0 and mean["teleports"] == 0


def test_capacity_sweep_below_capacity() -> None:
    """`python -m jaxround.apps.sumo_capacity`: at 600 veh/h, a quarter of
    the two-lane roundabout's capacity, all are let in at once."""
    from jaxround.apps.sumo_capacity import capacity_sweep, table

    (row,) = capacity_sweep(load_config("two_lane"), [600], seeds=[100], workers=1)
    assert row["demand"] == 600 and row["entered_share"] == 1.0
    assert row["insertion_wait_s"] < 1.0 and row["largest_queue_veh"] < 10
    assert row["lane_changes_per_vehicle"] > 0
    assert row["collisions"] == 0 and row["teleports"] == 0
    assert table([row]).splitlines()[2].startswith("| 600 | 600 | 1.000 |")
