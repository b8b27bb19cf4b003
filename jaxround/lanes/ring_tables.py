"""What LC2013 reads of a roundabout's network, per lane path, built once.

`jaxround.lanes.ring_changer` decides lane changes of vehicles kept as
(path, position along the path) (`jaxround.lanes.paths`). Everything it
reads that depends only on the network and the route is tabled here, in
numpy, per path position k (the lane the path takes there) and per lane z
of that lane's edge:

- SUMO's `LaneQ` rows (`jaxround.lanes.best_lanes`): on a normal edge the
  rows `updateBestLanes` builds on entering it, on an internal edge the next
  edge's rows restricted to the lanes it leads to; and the lanes whose
  occupation makes a row's `nextOccupation` (``bestContinuations[1:]``,
  where on an internal lane SUMO's first entry is a null lane, so the next
  normal lane counts).
- `MSLCHelper::getRoundaboutDistBonus`'s static part, per own lane z and
  direction: how many roundabout junctions lie ahead (0 where the bonus is
  0 whatever the traffic), the lengths walked, the distance in the
  roundabout, and the lanes whose occupation is summed for the outer (best)
  and the inner lane, those on the vehicle's own edge discounted by the
  share still ahead of it. Internal edges next to a ring edge count as
  roundabout edges, as `NLEdgeControlBuilder::build` marks them. SUMO
  1.28's compiled function differs from the 2023 source in three ways
  (docs/lc2013-map.md section 4, "As 1.28 computes it"): no bonus
  to the left where the left lane's continuation is longer than the
  vehicle's own; none of the traffic's jam factor to the right while the
  vehicle is on the roundabout (`bonus_unjammed`); and no exception for an
  empty roundabout.
- For followers (`MSLane::getFollowersOnConsecutive`): each lane's
  upstream lanes, up to three links back, with the distance from their
  start to the lane's start and whether a minor link lies between.

Shapes: L lanes, P paths, K path positions, Z lanes of an edge, C lanes of
a continuation, U upstream lanes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sumolib

from jaxround.lanes.best_lanes import (
    LookAheadDriver,
    internal_lane_rows,
    route_rows,
)
from jaxround.lanes.paths import LanePaths, lane_paths
from jaxround.lanes.ring_network import internal_lanes
from jaxround.scenario.edges import route_edges

#: `getRoundaboutDistBonus` looks no further (m).
BONUS_LOOK_AHEAD_M = 300.0
#: Upstream links searched for followers.
UPSTREAM_HOPS = 3


@dataclass(frozen=True)
class RingLanes:
    """The lane paths and the tables above. Lane ids are indices into
    ``paths.lane_ids``; -1 pads.

    Attributes:
        paths: the network's `LanePaths`.
        lane_speed: float (L,) speed limit.
        lane_roundabout: bool (L,) on a roundabout edge (internal ones too).
        edge_lanes: int (P, K, Z) the lanes of the edge at path position k.
        laneq_length, laneq_offset, laneq_ends_in_links: (P, K, Z) float, int,
            bool: `LaneQ.length`, `bestLaneOffset`, and whether its last
            continuation lane has links on.
        laneq_next: int (P, K, Z, C) the lanes of `nextOccupation`.
        bonus_junctions: int (P, K, Z, 2) roundabout junctions ahead, right (0)
            and left (1); 0 where the bonus is 0 anyway.
        bonus_seen: float (P, K, Z, 2) lengths walked before the last lane of
            the first loop (the bonus is 0 if that minus the position > 300 m).
        bonus_distance: float (P, K, Z, 2) `distanceInRoundabout`.
        bonus_unjammed: bool (P, K, Z, 2) the bonus is the distance's in full,
            whatever the occupancies: looking right from a roundabout lane.
        bonus_outer, bonus_inner: int (P, K, Z, 2, C) lanes summed into
            `occupancyOuter` and `occupancyInner`.
        bonus_outer_here, bonus_inner_here: bool (P, K, Z, 2, C) those on the
            vehicle's own edge (weighted by (length - pos) / length).
        upstream_lane: int (L, U) lanes that lead into the lane.
        upstream_dist: float (L, U) from their start to the lane's start (m).
        upstream_minor: bool (L, U) a minor link lies between.
        lane_sibling: int (L,) the other internal lane leaving the same lane
            (-1: none); lane_diverge: float (L,) where they part, from the
            lane's start (m, `compile.internal_geometry`).
    """

    paths: LanePaths
    lane_speed: np.ndarray
    lane_roundabout: np.ndarray
    edge_lanes: np.ndarray
    laneq_length: np.ndarray
    laneq_offset: np.ndarray
    laneq_ends_in_links: np.ndarray
    laneq_next: np.ndarray
    bonus_junctions: np.ndarray
    bonus_seen: np.ndarray
    bonus_distance: np.ndarray
    bonus_unjammed: np.ndarray
    bonus_outer: np.ndarray
    bonus_inner: np.ndarray
    bonus_outer_here: np.ndarray
    bonus_inner_here: np.ndarray
    upstream_lane: np.ndarray
    upstream_dist: np.ndarray
    upstream_minor: np.ndarray
    lane_sibling: np.ndarray
    lane_diverge: np.ndarray


def ring_lanes(net_file: str | Path, driver: LookAheadDriver) -> RingLanes:
    """Build the tables for the roundabout in ``net_file`` (a `.net.xml` from
    `jaxround.sumo_files.netconvert`), with the look-ahead of ``driver``."""
    paths = lane_paths(net_file)
    net = sumolib.net.readNet(str(net_file), withInternal=True)
    index = {lid: k for k, lid in enumerate(paths.lane_ids)}
    lanes = [net.getLane(lid) for lid in paths.lane_ids]
    _, _, (sibling, diverge, _, _) = internal_lanes(net_file, net, paths)
    roundabout_edges = {e for r in net.getRoundabouts() for e in r.getEdges()}
    lane_roundabout = np.array(
        [_is_roundabout(net, ln, roundabout_edges) for ln in lanes]
    )
    n_paths, k_max = paths.path_lanes.shape
    z_max = max(len(ln.getEdge().getLanes()) for ln in lanes)
    c_max = 4 * paths.n_legs + 4

    routes = [route_edges(o, d, paths.n_legs) for o, d in paths.route_od]
    normal_rows = [route_rows(net, route, driver) for route in routes]
    edge_lanes = -np.ones((n_paths, k_max, z_max), np.int32)
    laneq_length = np.full((n_paths, k_max, z_max), np.nan)
    laneq_offset = np.zeros((n_paths, k_max, z_max), np.int32)
    laneq_ends = np.zeros((n_paths, k_max, z_max), bool)
    laneq_next = -np.ones((n_paths, k_max, z_max, c_max), np.int32)
    bonus_shape = (n_paths, k_max, z_max, 2)
    bonus_junctions = np.zeros(bonus_shape, np.int32)
    bonus_seen = np.zeros(bonus_shape)
    bonus_distance = np.zeros(bonus_shape)
    bonus_unjammed = np.zeros(bonus_shape, bool)
    bonus_outer = -np.ones((*bonus_shape, c_max), np.int32)
    bonus_inner = -np.ones((*bonus_shape, c_max), np.int32)
    bonus_outer_here = np.zeros((*bonus_shape, c_max), bool)
    bonus_inner_here = np.zeros((*bonus_shape, c_max), bool)

    for p in range(n_paths):
        route = routes[paths.path_route[p]]
        normal_k = -1  # route index of the last normal edge passed
        for k, lane_id in enumerate(paths.path_lane_ids(p)):
            lane = net.getLane(lane_id)
            edge = lane.getEdge()
            internal = edge.getFunction() == "internal"
            if internal:
                rows = internal_lane_rows(net, route, normal_k, edge.getID(), driver)
            else:
                normal_k += 1
                rows = normal_rows[paths.path_route[p]][normal_k]
            conts: list[list[sumolib.net.lane.Lane | None]] = []
            for z, row in enumerate(rows):
                edge_lanes[p, k, z] = index[edge.getLanes()[z].getID()]
                laneq_length[p, k, z] = row.length
                laneq_offset[p, k, z] = row.best_lane_offset
                cont = [net.getLane(x) for x in row.continuations]
                laneq_ends[p, k, z] = bool(cont[-1].getOutgoing())
                # SUMO's bestContinuations: a null lane first on an internal edge
                full = ([None] if internal else []) + cont
                conts.append(full)
                nxt = [index[x.getID()] for x in full[1:] if x is not None]
                laneq_next[p, k, z, : len(nxt)] = nxt
            for z in range(len(rows)):
                for side, direction in ((0, -1), (1, 1)):
                    z_neigh = z + direction
                    if not 0 <= z_neigh < len(rows):
                        continue
                    if side == 1 and len(conts[z_neigh]) > len(conts[z]):
                        continue  # 1.28: the left lane goes on further
                    offset = rows[z].best_lane_offset
                    if offset == 0 and rows[z_neigh].best_lane_offset == 0:
                        offset = direction
                    z_best = min(max(z + offset, 0), len(rows) - 1)
                    found = _bonus_walk(
                        net,
                        conts[z_best],
                        conts[max(z, z_neigh)],
                        lane,
                        roundabout_edges,
                    )
                    if found is None:
                        continue
                    junctions, seen, distance, outer, inner = found
                    at = (p, k, z, side)
                    bonus_junctions[at], bonus_seen[at] = junctions, seen
                    bonus_distance[at] = distance
                    bonus_unjammed[at] = side == 0 and lane_roundabout[index[lane_id]]
                    for table, here, walked in (
                        (bonus_outer, bonus_outer_here, outer),
                        (bonus_inner, bonus_inner_here, inner),
                    ):
                        for c, (walked_lane, on_own_edge) in enumerate(walked):
                            table[(*at, c)] = index[walked_lane.getID()]
                            here[(*at, c)] = on_own_edge

    upstream_lane, upstream_dist, upstream_minor = _upstream(net, lanes, index)
    return RingLanes(
        paths=paths,
        lane_speed=np.array([ln.getSpeed() for ln in lanes]),
        lane_roundabout=lane_roundabout,
        edge_lanes=edge_lanes,
        laneq_length=laneq_length,
        laneq_offset=laneq_offset,
        laneq_ends_in_links=laneq_ends,
        laneq_next=laneq_next,
        bonus_junctions=bonus_junctions,
        bonus_seen=bonus_seen,
        bonus_distance=bonus_distance,
        bonus_unjammed=bonus_unjammed,
        bonus_outer=bonus_outer,
        bonus_inner=bonus_inner,
        bonus_outer_here=bonus_outer_here,
        bonus_inner_here=bonus_inner_here,
        upstream_lane=upstream_lane,
        upstream_dist=upstream_dist,
        upstream_minor=upstream_minor,
        lane_sibling=sibling,
        lane_diverge=diverge,
    )


def _is_roundabout(
    net: sumolib.net.Net, lane: sumolib.net.lane.Lane, roundabout_edges: set[str]
) -> bool:
    """`MSEdge::isRoundabout`: a ring edge, or an internal edge whose
    predecessor or successor is one (internal chains: the lane before it)."""
    edge = lane.getEdge()
    if edge.getID() in roundabout_edges:
        return True
    if edge.getFunction() != "internal":
        return False
    if any(c.getTo().getID() in roundabout_edges for c in lane.getOutgoing()):
        return True
    before = _link_from(net, lane)
    return before is not None and _is_roundabout(net, before, roundabout_edges)


def _link_from(
    net: sumolib.net.Net, lane: sumolib.net.lane.Lane
) -> sumolib.net.lane.Lane | None:
    """The lane whose connection runs through internal lane ``lane``."""
    node = lane.getEdge().getFromNode()
    for edge in node.getIncoming():
        for before in edge.getLanes():
            if any(c.getViaLaneID() == lane.getID() for c in before.getOutgoing()):
                return before
    for edge in node.getIncoming():  # internal junctions: an internal lane before
        for before in edge.getLanes():
            for conn in before.getOutgoing():
                via = conn.getViaLaneID()
                if via and via != lane.getID():
                    inner = net.getLane(via)
                    if any(
                        c.getViaLaneID() == lane.getID() for c in inner.getOutgoing()
                    ):
                        return inner
    return None


def _bonus_walk(
    net: sumolib.net.Net,
    best: list[sumolib.net.lane.Lane | None],
    inner: list[sumolib.net.lane.Lane | None],
    ego_lane: sumolib.net.lane.Lane,
    roundabout_edges: set[str],
) -> tuple[int, float, float, list, list] | None:
    """The static part of `MSLCHelper::getRoundaboutDistBonus` for the
    continuations ``best`` and ``inner`` (None: the vehicle's own lane), or
    None where the bonus is 0 whatever the traffic."""

    def on_roundabout(lane: sumolib.net.lane.Lane) -> bool:
        return _is_roundabout(net, lane, roundabout_edges)

    junctions, entered, seen = 0, False, 0.0
    for i, lane in enumerate(best):
        lane = ego_lane if lane is None else lane
        if (not entered or on_roundabout(lane)) and i >= len(inner):
            return None  # the inner lane does not go on round
        last_seen = seen
        node = lane.getEdge().getToNode()
        if on_roundabout(lane):
            entered = True
            if len(node.getIncoming()) + len(node.getOutgoing()) > 2:
                junctions += 1
        elif entered:
            break
        seen += lane.getLength()
    if junctions < 2:
        return None  # the next exit is taken: no bonus
    outer_walk: list[tuple[sumolib.net.lane.Lane, bool]] = []
    inner_walk: list[tuple[sumolib.net.lane.Lane, bool]] = []
    distance, entered = 0.0, False
    prev_normal = prev_inner = None
    own_edge = ego_lane.getEdge()
    for i, lane in enumerate(best):
        if lane is None:
            continue  # the vehicle's own internal lane counts for nothing
        if on_roundabout(lane):
            entered = True
        elif entered:
            break
        via = _via(net, prev_normal, lane)
        if entered:
            distance += lane.getLength() + (via.getLength() if via else 0.0)
        prev_normal = lane
        outer_walk.append((lane, lane.getEdge() is own_edge))
        if via is not None:
            outer_walk.append((via, False))
        if i < len(inner) and inner[i] is not None:
            inner_lane = inner[i]
            inner_walk.append((inner_lane, lane.getEdge() is own_edge))
            inner_via = _via(net, prev_inner, inner_lane)
            if inner_via is not None:
                inner_walk.append((inner_via, False))
            prev_inner = inner_lane
    return junctions, last_seen, distance, outer_walk, inner_walk


def _via(
    net: sumolib.net.Net,
    before: sumolib.net.lane.Lane | None,
    lane: sumolib.net.lane.Lane,
) -> sumolib.net.lane.Lane | None:
    """The internal lane of the link from ``before`` to ``lane``, if any."""
    if before is None:
        return None
    for conn in before.getOutgoing():
        if conn.getToLane() is lane and conn.getViaLaneID():
            return net.getLane(conn.getViaLaneID())
    return None


def _upstream(
    net: sumolib.net.Net, lanes: list, index: dict[str, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each lane's upstream lanes (up to `UPSTREAM_HOPS` links), the distance
    from their start to its start, and whether a minor link lies between."""
    into: dict[int, list[tuple[int, bool]]] = {k: [] for k in range(len(lanes))}
    for k, ln in enumerate(lanes):
        for conn in ln.getOutgoing():
            nxt = conn.getViaLaneID() or conn.getToLane().getID()
            into[index[nxt]].append((k, conn.getState() in ("m", "=", "s", "w")))
    found: list[list[tuple[int, float, bool]]] = []
    for k in range(len(lanes)):
        rows: list[tuple[int, float, bool]] = []
        frontier = [(k, 0.0, False)]
        for _ in range(UPSTREAM_HOPS):
            nxt_frontier = []
            for lane, dist, minor in frontier:
                for before, is_minor in into[lane]:
                    row = (before, dist + lanes[before].getLength(), minor or is_minor)
                    rows.append(row)
                    nxt_frontier.append(row)
            frontier = nxt_frontier
        found.append(rows)
    width = max(1, max(len(rows) for rows in found))
    lane = -np.ones((len(lanes), width), np.int32)
    dist = np.full((len(lanes), width), np.inf)
    minor = np.zeros((len(lanes), width), bool)
    for k, rows in enumerate(found):
        for u, (before, d, is_minor) in enumerate(rows):
            lane[k, u], dist[k, u], minor[k, u] = before, d, is_minor
    return lane, dist, minor
