"""SUMO 1.28's lane changer: the order of its decisions and where it lets
vehicles change, as docs/lc2013-map.md states them for the JAX port.

- Within an edge the vehicles decide front to back (`MSLaneChanger::change`
  picks the candidate with the largest position), and a vehicle that has
  just changed is already the target-lane leader of those behind it in the
  same step.
- On the two-lane roundabout of configs/two_lane.yaml a lone vehicle that
  passes two or more ring junctions moves to the left entry lane
  (`cooperative`, the roundabout bonus of `MSLCHelper::getRoundaboutDistBonus`
  and `_wantsChange`'s VARIANT_15) and back to the outer ring lane on the
  last ring edge before its exit (`strategic|urgent`); one taking the first
  exit stays on the right lane.
- Changes happen on the ring's internal (junction) lanes, which enter with
  priority and are of equal length, never on the entry's internal lanes,
  which give way (`MSEdge::allowsLaneChanging`, `MSLaneChanger`'s
  constructor).
"""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import sumolib

from jaxround.apps.lane_parity import two_lane_road
from jaxround.scenario.config import load_config
from jaxround.scenario.edges import in_edge, ring_edge, route_edges
from jaxround.sumo_files.binaries import sumo_binary
from jaxround.sumo_files.netconvert import network_file

pytestmark = pytest.mark.sumo

LENGTH = 5.0  # the default passenger vType's length
VTYPE = '<vType id="t" carFollowModel="IDM" speedDev="0"/>'


def lane_changes(
    tmp_path: Path, net: Path, routes: str, step: float, end: float, seed: int = 1
) -> list[dict[str, str]]:
    """Run `routes` (XML body) on `net` until `end` s; SUMO's lane changes."""
    rou, out = tmp_path / "r.rou.xml", tmp_path / "lc.xml"
    rou.write_text(f"<routes>{routes}</routes>")
    subprocess.run(
        [sumo_binary("sumo"), "-n", str(net), "-r", str(rou),
         "--step-length", str(step), "--end", str(end), "--seed", str(seed),
         "--no-step-log", "true", "--no-warnings", "true", "--precision", "6",
         "--lanechange-output", str(out)],
        check=True, capture_output=True,
    )  # fmt: skip
    return [c.attrib for c in ET.parse(out).getroot().iter("change")]


def test_front_vehicle_decides_first_and_is_seen_behind(tmp_path: Path) -> None:
    """Two cars 30 m apart on the right lane, both of which must change
    left at their first decision (t = 1 s). The front one (A) changes
    first and sees no one on the left lane; the one behind (B) changes in
    the same step with A as its target-lane leader, at the gap from A's new
    position (`getRealLeader`'s hopped vehicle). Back to front, A would
    have had B as its follower instead."""
    net = two_lane_road(tmp_path, 250.0, left_only=True)
    routes = (
        VTYPE + '<route id="r" edges="e1 e2"/>'
        '<vehicle id="A" type="t" route="r" depart="0" departLane="0" '
        'departPos="200" departSpeed="13.89"/>'
        '<vehicle id="B" type="t" route="r" depart="0" departLane="0" '
        'departPos="170" departSpeed="13.89"/>'
    )
    a, b = lane_changes(tmp_path, net, routes, 1.0, 5)
    assert (a["id"], b["id"]) == ("A", "B")
    assert float(a["time"]) == float(b["time"]) == 1.0
    assert a["to"] == b["to"] == "e1_1"
    assert a["followerGap"] == "None" and a["leaderGap"] == "None"
    # leaderGap is written with B's minGap added: front-to-back bumper gap
    gap = float(a["pos"]) - LENGTH - float(b["pos"])
    assert float(b["leaderGap"]) == pytest.approx(gap, abs=1e-4)


def test_lone_vehicle_lanes_on_the_two_lane_roundabout(tmp_path: Path) -> None:
    """From the east leg (0), one vehicle a minute to the first, second and
    third exit, alone on the roundabout (step 0.5 s)."""
    net = network_file(load_config("two_lane"), tmp_path)
    routes = VTYPE + "".join(
        f'<vehicle id="to{d}" type="t" depart="{60 * (d - 1)}" departLane="best" '
        f'departSpeed="max"><route edges="{" ".join(route_edges(0, d, 4))}"/>'
        "</vehicle>"
        for d in (1, 2, 3)
    )
    changes = lane_changes(tmp_path, net, routes, 0.5, 240)
    by_id: dict[str, list[dict[str, str]]] = {}
    for c in changes:
        by_id.setdefault(c["id"], []).append(c)
    assert "to1" not in by_id  # one ring edge: no bonus, stays right
    for d in (2, 3):
        left, right = by_id[f"to{d}"]
        # at its first decision, the step after its insertion
        assert float(left["time"]) == 60 * (d - 1) + 0.5
        assert (left["from"], left["to"]) == (f"{in_edge(0)}_0", f"{in_edge(0)}_1")
        assert left["reason"] == "cooperative"
        # on the last ring edge before the exit, not before
        last = ring_edge(d - 1)
        assert (right["from"], right["to"]) == (f"{last}_1", f"{last}_0")
        assert right["reason"] == "strategic|urgent"


def test_changes_on_the_ring_internal_lanes_only(tmp_path: Path) -> None:
    """Steady flows on every route for 15 min: some changes happen on the
    internal lanes that carry the ring through a junction (two lanes of
    equal length, entered with priority); none on the entries' internal
    lanes (entered giving way, lanes of different lengths)."""
    path = network_file(load_config("two_lane"), tmp_path)
    net = sumolib.net.readNet(str(path), withInternal=True)
    ring_through, entry = set(), set()
    for i in range(4):
        nxt = ring_edge((i + 1) % 4)
        for e, kind in ((ring_edge(i), ring_through), (in_edge((i + 1) % 4), entry)):
            for c in net.getEdge(e).getOutgoing()[net.getEdge(nxt)]:
                kind.add(c.getViaLaneID().rsplit("_", 1)[0])
    for e in ring_through:
        lanes = net.getEdge(e).getLanes()
        assert len(lanes) == 2 and lanes[0].getLength() == lanes[1].getLength()
    flows = VTYPE + "".join(
        f'<flow id="f{o}{d}" type="t" begin="0" end="900" '
        f'vehsPerHour="{260 if o in (0, 2) else 130}" departLane="best" '
        f'departSpeed="max"><route edges="{" ".join(route_edges(o, d, 4))}"/></flow>'
        for o in range(4)
        for d in range(4)
        if o != d
    )
    changes = lane_changes(tmp_path, path, flows, 0.5, 1200)
    internal = {c["from"].rsplit("_", 1)[0] for c in changes if c["from"][0] == ":"}
    assert internal and internal <= ring_through
    assert not internal & entry
