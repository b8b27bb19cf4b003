"""Lane paths: a multi-lane roundabout's routes as fixed lane sequences.

The single-lane step keeps a vehicle as (route, position along the route),
with one lane sequence per route (`jaxround.core.network`). On a roundabout
with parallel lanes a route is driven on one of several lane sequences, and
a lane change moves the vehicle from one to another. A **path** is such a
sequence: for each edge of the route (internal junction edges included) one
lane, each lane joined to the next by SUMO's connections, so a vehicle that
does not change lanes stays on its path from insertion to arrival. A path
that reaches a lane with no connection to the route's next edge ends there
(the vehicle must change before the lane ends; `complete` is False).

A vehicle is then (path, position along the path). A lane change at route
position k (an edge with a lane changer) moves it to the path that takes the
neighbouring lane there and keeps lane from it on, at the same position on
the lane (the lanes of a normal edge, and of an internal edge whose lanes
may be changed between, have one length in SUMO's networks):
``pos' = pos - lane_start[p, k] + lane_start[p', k]``. The single-lane
networks have one path per route, equal to the route.

Built once per network, in numpy, from the `.net.xml` SUMO runs. SUMO's
rules followed: which lanes lead on (``<connection>``); which edges let a
vehicle change lanes (``MSEdge::allowsLaneChanging``: on an internal edge
only if no lane is entered by a minor, equal, stop, all-way-stop or
dead-end link; ``MSLaneChanger::MSLaneChanger``: never between internal
lanes of different lengths or with the same predecessor); which links an
internal lane's link yields to (the junction's ``<request response=...>``,
link i's bit j counted from the right, links in ``intLanes`` order).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sumolib

from jaxround.core.network import NetworkError
from jaxround.scenario.edges import route_edges

#: Link states (``LinkState`` letters) that forbid changing lanes on the
#: internal edge they enter (``MSEdge::allowsLaneChanging``): minor, equal,
#: stop, all-way stop, dead end.
NO_CHANGE_LINK_STATES = frozenset("m=swd")

RIGHT, LEFT = 0, 1


@dataclass(frozen=True)
class LanePaths:
    """The lane paths of a roundabout. L lanes, R routes, P paths, K edges
    per route (internal edges included), Z most lanes of an edge, F most
    links one link yields to.

    Attributes:
        n_legs: number of legs.
        lane_ids: SUMO lane ids, length L.
        lane_length: float (L,) metres.
        lane_internal: bool (L,) a junction (internal) lane.
        lane_index: int (L,) index within its edge (0 rightmost).
        lane_right, lane_left: int (L,) the same edge's lane to the right and
            to the left, -1 if none.
        lane_link_state: the state letter of the link entering each internal
            lane ('' for normal lanes), length L.
        link_foes: int (L, F) for an internal lane, the internal lanes of the
            links its link must yield to (the junction's response), -1 padded.
        route_od: int (R, 2) origin and exit leg of each route.
        route_index: int (n_legs, n_legs) route of (origin, exit), -1 on the
            diagonal (`jaxround.core.network.CompiledNetwork`'s numbering).
        path_route: int (P,) the route each path drives.
        path_lanes: int (P, K) lane at each route position, -1 past the end.
        path_lane_start: float (P, K) where each lane starts along the path,
            nan past the end.
        path_length: float (P,) metres to the path's last lane's end.
        path_complete: bool (P,) the path reaches the route's last edge.
        lane_offset: float (P, L) where lane l starts along path p, nan if
            the path does not take it.
        change_path: int (P, K, 2) the path a vehicle at route position k
            moves to by changing right (0) or left (1), -1 where SUMO lets
            no vehicle change that way there.
        depart_path: int (R, Z) the path of a vehicle inserted on lane z of
            the route's first edge, -1 where the edge has no lane z.
    """

    n_legs: int
    lane_ids: tuple[str, ...]
    lane_length: np.ndarray
    lane_internal: np.ndarray
    lane_index: np.ndarray
    lane_right: np.ndarray
    lane_left: np.ndarray
    lane_link_state: tuple[str, ...]
    link_foes: np.ndarray
    route_od: np.ndarray
    route_index: np.ndarray
    path_route: np.ndarray
    path_lanes: np.ndarray
    path_lane_start: np.ndarray
    path_length: np.ndarray
    path_complete: np.ndarray
    lane_offset: np.ndarray
    change_path: np.ndarray
    depart_path: np.ndarray

    @property
    def n_paths(self) -> int:
        return int(self.path_route.shape[0])

    def path_lane_ids(self, path: int) -> list[str]:
        """The SUMO lane ids of a path, in driving order."""
        return [self.lane_ids[k] for k in self.path_lanes[path] if k >= 0]


def lane_paths(net_file: str | Path, n_legs: int | None = None) -> LanePaths:
    """Read a `.net.xml` written by `jaxround.sumo_files.netconvert`.

    Raises:
        NetworkError: no such file, an edge of a route missing, or a route
            whose edges are not joined by any connection.
    """
    path = Path(net_file)
    if not path.is_file():
        raise NetworkError(f"{path}: no such network file")
    net = sumolib.net.readNet(str(path), withInternal=True)
    edges = {e.getID(): e for e in net.getEdges(withInternal=True)}
    if n_legs is None:
        n_legs = sum(1 for eid in edges if eid.startswith("in_"))

    lane_ids: list[str] = [
        ln.getID() for e in net.getEdges(withInternal=True) for ln in e.getLanes()
    ]
    index = {lid: k for k, lid in enumerate(lane_ids)}
    lanes = [net.getLane(lid) for lid in lane_ids]
    n_lanes = len(lanes)
    lane_internal = np.array([ln.getEdge().getFunction() == "internal" for ln in lanes])
    lane_index = np.array([ln.getIndex() for ln in lanes], np.int32)
    lane_right = -np.ones(n_lanes, np.int32)
    lane_left = -np.ones(n_lanes, np.int32)
    for k, ln in enumerate(lanes):
        siblings = ln.getEdge().getLanes()
        if ln.getIndex() > 0:
            lane_right[k] = index[siblings[ln.getIndex() - 1].getID()]
        if ln.getIndex() + 1 < len(siblings):
            lane_left[k] = index[siblings[ln.getIndex() + 1].getID()]

    link_state = [""] * n_lanes
    predecessor = -np.ones(n_lanes, np.int32)  # of an internal lane: the lane
    for e in net.getEdges(withInternal=True):  # whose link it is
        for ln in e.getLanes():
            for conn in ln.getOutgoing():
                if conn.getViaLaneID():
                    link_state[index[conn.getViaLaneID()]] = conn.getState()
                    predecessor[index[conn.getViaLaneID()]] = index[ln.getID()]
    link_foes = _link_foes(path, index)

    route_od, route_index, route_edge_ids = _routes(n_legs, edges, path)
    graphs = [_RouteLanes(names, net, index) for names in route_edge_ids]
    sequences: list[tuple[int, list[int]]] = [
        (r, seq) for r, graph in enumerate(graphs) for seq in graph.paths(lanes)
    ]

    k_max = max(len(seq) for _, seq in sequences)
    n_paths = len(sequences)
    path_route = np.array([r for r, _ in sequences], np.int32)
    path_lanes = -np.ones((n_paths, k_max), np.int32)
    path_lane_start = np.full((n_paths, k_max), np.nan)
    path_length = np.zeros(n_paths)
    path_complete = np.zeros(n_paths, bool)
    lane_offset = np.full((n_paths, n_lanes), np.nan)
    lane_length = np.array([ln.getLength() for ln in lanes], np.float64)
    for p, (r, seq) in enumerate(sequences):
        pos = 0.0
        for k, lane in enumerate(seq):
            path_lanes[p, k] = lane
            path_lane_start[p, k] = pos
            lane_offset[p, lane] = pos
            pos += lane_length[lane]
        path_length[p] = pos
        path_complete[p] = graphs[r].arrives(seq[-1])

    changeable = _changeable(lanes, index, link_state, predecessor)
    change_path = -np.ones((n_paths, k_max, 2), np.int32)
    for p, (r, seq) in enumerate(sequences):
        for k, lane in enumerate(seq):
            for side, neighbour in ((RIGHT, lane_right[lane]), (LEFT, lane_left[lane])):
                if neighbour < 0 or not changeable[lane, lane_index[neighbour]]:
                    continue
                change_path[p, k, side] = graphs[r].keep_lane_path(
                    sequences, r, int(neighbour)
                )

    z_max = max(len(e.getLanes()) for e in edges.values())
    depart_path = -np.ones((len(route_od), z_max), np.int32)
    for r, names in enumerate(route_edge_ids):
        for z, ln in enumerate(edges[names[0]].getLanes()):
            depart_path[r, z] = graphs[r].keep_lane_path(
                sequences, r, index[ln.getID()]
            )

    return LanePaths(
        n_legs=n_legs,
        lane_ids=tuple(lane_ids),
        lane_length=lane_length,
        lane_internal=lane_internal,
        lane_index=lane_index,
        lane_right=lane_right,
        lane_left=lane_left,
        lane_link_state=tuple(link_state),
        link_foes=link_foes,
        route_od=np.asarray(route_od, np.int32),
        route_index=route_index,
        path_route=path_route,
        path_lanes=path_lanes,
        path_lane_start=path_lane_start,
        path_length=path_length,
        path_complete=path_complete,
        lane_offset=lane_offset,
        change_path=change_path,
        depart_path=depart_path,
    )


def _routes(
    n_legs: int, edges: dict, path: Path
) -> tuple[list[tuple[int, int]], np.ndarray, list[list[str]]]:
    """Each route's (origin, exit), the route index table, and its normal
    edges' ids."""
    route_od: list[tuple[int, int]] = []
    route_index = -np.ones((n_legs, n_legs), np.int32)
    route_edge_ids: list[list[str]] = []
    for o in range(n_legs):
        for d in range(n_legs):
            if o == d:
                continue
            names = route_edges(o, d, n_legs)
            for name in names:
                if name not in edges:
                    raise NetworkError(
                        f"{path}: edge {name!r} missing; not a jaxround roundabout"
                    )
            for a, b in zip(names, names[1:], strict=False):
                if not edges[a].getOutgoing().get(edges[b]):
                    raise NetworkError(f"{path}: no connection from {a} to {b}")
            route_index[o, d] = len(route_od)
            route_od.append((o, d))
            route_edge_ids.append(names)
    return route_od, route_index, route_edge_ids


class _RouteLanes:
    """The lanes one route can drive and how they join: each lane's
    successors on the route (a connection's first internal lane, an internal
    lane's next lane, internal junctions included), and predecessors."""

    def __init__(self, names: list[str], net, index: dict[str, int]) -> None:
        edges = {name: net.getEdge(name) for name in names}
        self.last = {index[ln.getID()] for ln in edges[names[-1]].getLanes()}
        self.first = [index[ln.getID()] for ln in edges[names[0]].getLanes()]
        self.edge_of: dict[int, int] = {}  # normal lane -> route edge index
        self.succ: dict[int, list[int]] = {}
        self.pred: dict[int, list[int]] = {}
        todo = []
        for e, name in enumerate(names):
            for ln in edges[name].getLanes():
                self.edge_of[index[ln.getID()]] = e
                todo.append((ln, e + 1))
        while todo:
            ln, target = todo.pop()
            lane = index[ln.getID()]
            if lane in self.succ:
                continue
            self.succ[lane] = []
            if target == len(names):
                continue
            for conn in ln.getOutgoing():
                if conn.getTo().getID() != names[target]:
                    continue
                nxt = conn.getViaLaneID() or conn.getToLane().getID()
                self.succ[lane].append(index[nxt])
                self.pred.setdefault(index[nxt], []).append(lane)
                if conn.getViaLaneID():
                    todo.append((net.getLane(nxt), target))

    def arrives(self, lane: int) -> bool:
        return lane in self.last

    def forward(self, lane: int) -> list[list[int]]:
        """Every lane sequence from `lane` on without changing, to the route's
        end or a lane that does not lead on; the rightmost branch first."""
        nxt = sorted(self.succ.get(lane, []))
        if not nxt:
            return [[lane]]
        return [[lane, *rest] for n in nxt for rest in self.forward(n)]

    def backward(self, lane: int, lanes: list) -> list[int]:
        """Lanes before `lane` that lead to it without changing, in driving
        order (the rightmost where several do). A lane no lane leads to is
        reached by a change: the lanes before it are its neighbour's, whose
        edge position it shares (lanes of a changing edge have one length)."""
        seq: list[int] = []
        while lane in self.pred:
            lane = min(self.pred[lane])
            seq.insert(0, lane)
        if lane in self.first or lane not in self.edge_of:
            return seq
        siblings = [
            s
            for s in self.edge_of
            if self.edge_of[s] == self.edge_of[lane] and s != lane
        ]
        reached = [s for s in siblings if s in self.pred]
        if not reached:
            return seq
        near = min(
            reached, key=lambda s: abs(lanes[s].getIndex() - lanes[lane].getIndex())
        )
        return self.backward(near, lanes) + seq

    def paths(self, lanes: list) -> list[list[int]]:
        """The route's distinct paths; every lane it can drive is on one."""
        found: list[list[int]] = []
        for lane in sorted(self.succ, key=lambda k: (self.edge_of.get(k, -1), k)):
            if any(lane in seq for seq in found):
                continue
            before = self.backward(lane, lanes)
            for after in self.forward(lane):
                if before + after not in found:
                    found.append(before + after)
        return found

    def keep_lane_path(
        self, sequences: list[tuple[int, list[int]]], route: int, lane: int
    ) -> int:
        """The path of `route` that takes `lane` and keeps lane from there on
        (its rightmost branch where a lane leads to several)."""
        tail = self.forward(lane)[0]
        for p, (r, seq) in enumerate(sequences):
            if r == route and lane in seq and seq[seq.index(lane) :] == tail:
                return p
        return -1


def _changeable(
    lanes: list, index: dict[str, int], link_state: list[str], predecessor: np.ndarray
) -> np.ndarray:
    """bool (L, Z): whether a vehicle on lane l may change to lane z of its edge."""
    z_max = max(len(ln.getEdge().getLanes()) for ln in lanes)
    ok = np.zeros((len(lanes), z_max), bool)
    for k, ln in enumerate(lanes):
        edge = ln.getEdge()
        siblings = edge.getLanes()
        if len(siblings) < 2:
            continue
        internal = edge.getFunction() == "internal"
        if internal and any(
            link_state[index[s.getID()]] in NO_CHANGE_LINK_STATES for s in siblings
        ):
            continue
        for other in siblings:
            if other is ln:
                continue
            if internal and (
                other.getLength() != ln.getLength()
                or predecessor[index[other.getID()]] == predecessor[k]
            ):
                continue
            ok[k, other.getIndex()] = True
    return ok


def _link_foes(path: Path, index: dict[str, int]) -> np.ndarray:
    """int (L, F): the internal lanes whose links each internal lane's link
    yields to, from each junction's ``<request response=...>``."""
    foes: dict[int, list[int]] = {}
    for junction in ET.parse(path).getroot().iter("junction"):
        internal = junction.get("intLanes", "").split()
        for request in junction.iter("request"):
            link = int(request.get("index"))
            response = request.get("response", "")[::-1]
            if link >= len(internal):
                continue
            foes[index[internal[link]]] = [
                index[internal[j]]
                for j, bit in enumerate(response)
                if bit == "1" and j < len(internal)
            ]
    width = max((len(v) for v in foes.values()), default=0)
    out = -np.ones((len(index), max(width, 1)), np.int32)
    for lane, lane_foes in foes.items():
        out[lane, : len(lane_foes)] = lane_foes
    return out
