"""Compile a SUMO roundabout network (`.net.xml`) into the core's arrays
(`jaxround.core.network.CompiledNetwork`, whose docstring says what they hold).

The JAX environment never holds a second, hand-written geometry: everything it
knows about the road comes from the same `.net.xml` that SUMO runs. Lane
shapes give the merge and divergence geometry; the ids of the edges are
`jaxround.scenario.edges`'.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from jaxround.core.network import CompiledNetwork, NetworkError
from jaxround.scenario.edges import in_edge, out_edge, ring_edge, route_edges


def compile_network(net_file: str | Path, n_legs: int | None = None) -> CompiledNetwork:
    """Read a `.net.xml` written by `jaxround.sumo_files.netconvert.build_network`.

    Args:
        net_file: the SUMO network.
        n_legs: expected number of legs; inferred from the ``in_*`` edges if None.

    Returns:
        The `CompiledNetwork`.

    Raises:
        NetworkError: the file is not a single-lane, single-ring roundabout with
            edges ``in_i``, ``out_i`` and ``ring_i``.
    """
    import sumolib

    path = Path(net_file)
    if not path.is_file():
        raise NetworkError(f"{path}: no such network file")
    net = sumolib.net.readNet(str(path), withInternal=True)
    edges = {e.getID(): e for e in net.getEdges(withInternal=True)}
    if n_legs is None:
        n_legs = sum(1 for eid in edges if eid.startswith("in_"))
    for i in range(n_legs):
        for eid in (in_edge(i), out_edge(i), ring_edge(i)):
            if eid not in edges:
                raise NetworkError(
                    f"{path}: edge {eid!r} missing; not a jaxround roundabout"
                )
            if edges[eid].getLaneNumber() != 1:
                raise NetworkError(
                    f"{path}: edge {eid!r} has several lanes; single lane only"
                )
    rounds = net.getRoundabouts()
    ring_ids = sorted(ring_edge(i) for i in range(n_legs))
    if len(rounds) != 1 or sorted(rounds[0].getEdges()) != ring_ids:
        raise NetworkError(
            f"{path}: expected exactly one roundabout made of {ring_ids}"
        )

    lane_ids: list[str] = []
    index: dict[str, int] = {}

    def lane_index(lane) -> int:
        lid = lane.getID()
        if lid not in index:
            index[lid] = len(lane_ids)
            lane_ids.append(lid)
        return index[lid]

    def via_lane(from_edge: str, to_edge: str):
        conns = edges[from_edge].getOutgoing().get(edges[to_edge], [])
        if len(conns) != 1 or not conns[0].getViaLaneID():
            raise NetworkError(
                f"{path}: no internal lane from {from_edge} to {to_edge}"
            )
        return net.getLane(conns[0].getViaLaneID()), conns[0]

    route_od, route_seq = [], []
    route_index = -np.ones((n_legs, n_legs), dtype=np.int32)
    for o in range(n_legs):
        for d in range(n_legs):
            if o == d:
                continue
            seq = []
            names = route_edges(o, d, n_legs)
            for a, b in zip(names, names[1:], strict=False):
                seq.append(lane_index(edges[a].getLane(0)))
                lane, _ = via_lane(a, b)
                seq.append(lane_index(lane))
            seq.append(lane_index(edges[names[-1]].getLane(0)))
            route_index[o, d] = len(route_od)
            route_od.append((o, d))
            route_seq.append(seq)

    entry_lane = np.array([index[f"{in_edge(i)}_0"] for i in range(n_legs)], np.int32)
    entry_internal, ring_through, visibility = [], [], []
    for i in range(n_legs):
        lane, conn = via_lane(in_edge(i), ring_edge(i))
        if conn.getState() != "m":
            raise NetworkError(
                f"{path}: the entry at leg {i} is not a minor (yield) link"
            )
        entry_internal.append(index[lane.getID()])
        prev = ring_edge((i - 1) % n_legs)
        through, _ = via_lane(prev, ring_edge(i))
        ring_through.append(index[through.getID()])
        visibility.append(connection_visibility(path, in_edge(i), ring_edge(i)))

    n_lanes = len(lane_ids)
    lanes = [net.getLane(lid) for lid in lane_ids]
    lane_length = np.array([ln.getLength() for ln in lanes], np.float64)
    lane_speed = np.array([ln.getSpeed() for ln in lanes], np.float64)
    lane_next = -np.ones(n_lanes, np.int32)
    for k, ln in enumerate(lanes):
        if ln.getEdge().getFunction() == "internal":
            outs = ln.getOutgoing()
            if len(outs) != 1:
                raise NetworkError(
                    f"{path}: internal lane {ln.getID()} does not lead on"
                )
            lane_next[k] = index.get(outs[0].getToLane().getID(), -1)
    shapes = tuple(np.asarray(ln.getShape(), np.float64) for ln in lanes)
    lane_sibling, lane_diverge, lane_partner, lane_converge = internal_geometry(
        lanes, shapes, lane_length, lane_next
    )

    n_routes = len(route_seq)
    k_max = max(len(s) for s in route_seq)
    route_lanes = -np.ones((n_routes, k_max), np.int32)
    route_lane_start = np.full((n_routes, k_max), np.nan)
    lane_offset = np.full((n_routes, n_lanes), np.nan)
    route_length = np.zeros(n_routes)
    yield_offset = np.zeros(n_routes)
    conflict_offset = np.full((n_routes, n_legs), np.nan)
    through_of = {lane: leg for leg, lane in enumerate(ring_through)}
    for r, seq in enumerate(route_seq):
        pos = 0.0
        for k, lane in enumerate(seq):
            route_lanes[r, k] = lane
            route_lane_start[r, k] = pos
            lane_offset[r, lane] = pos
            if k == 0:
                yield_offset[r] = lane_length[lane]
            if lane in through_of:
                conflict_offset[r, through_of[lane]] = pos
            pos += lane_length[lane]
        route_length[r] = pos

    return CompiledNetwork(
        n_legs=n_legs,
        lane_ids=tuple(lane_ids),
        lane_length=lane_length,
        lane_speed=lane_speed,
        lane_next=lane_next,
        lane_sibling=lane_sibling,
        lane_diverge=lane_diverge,
        lane_partner=lane_partner,
        lane_converge=lane_converge,
        lane_shapes=shapes,
        route_od=np.asarray(route_od, np.int32),
        route_index=route_index,
        route_lanes=route_lanes,
        route_lane_start=route_lane_start,
        route_length=route_length,
        lane_offset=lane_offset,
        entry_lane=entry_lane,
        entry_internal=np.asarray(entry_internal, np.int32),
        ring_through=np.asarray(ring_through, np.int32),
        yield_offset=yield_offset,
        conflict_offset=conflict_offset,
        entry_visibility=np.asarray(visibility),
    )


def internal_geometry(
    lanes: list,
    shapes: tuple[np.ndarray, ...],
    lane_length: np.ndarray,
    lane_next: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where internal lanes part and join. L lanes (sumolib's, in the order of
    the arrays).

    Returns:
        (sibling, diverge, partner, converge): int (L,) the other internal lane
        leaving the same lane (-1: none), float (L,) the lane position where
        they part (`_dist_to_divergence` from the start, as SUMO's
        same-source conflicts have it); int (L,) the other internal lane
        merging into the same lane (-1: none), float (L,) the length behind the merge
        (`_dist_to_divergence`).
    """  # fmt: skip
    n_lanes = len(lanes)
    lane_sibling = -np.ones(n_lanes, np.int32)
    lane_diverge = np.zeros(n_lanes)
    for k, ln in enumerate(lanes):
        if ln.getEdge().getFunction() != "internal":
            continue
        pred = [x.getID() for x in ln.getIncoming()]
        for j, other in enumerate(lanes):
            same_pred = [x.getID() for x in other.getIncoming()] == pred
            if j != k and other.getEdge().getFunction() == "internal" and same_pred:
                lane_sibling[k] = j
                lane_diverge[k] = _dist_to_divergence(
                    shapes[k], lane_length[k], shapes[j], lane_length[j],
                    same_source=True,
                )  # fmt: skip
    lane_partner = -np.ones(n_lanes, np.int32)
    lane_converge = np.zeros(n_lanes)
    for k in range(n_lanes):
        for j in range(n_lanes):
            if j != k and lane_next[k] >= 0 and lane_next[j] == lane_next[k]:
                lane_partner[k] = j
                lane_converge[k] = _dist_to_divergence(
                    shapes[k], lane_length[k], shapes[j], lane_length[j]
                )
    return lane_sibling, lane_diverge, lane_partner, lane_converge


def _dist_to_divergence(
    shape: np.ndarray,
    length: float,
    sib: np.ndarray,
    sib_length: float,
    min_dist: float = 2.5,
    same_source: bool = False,
) -> float:
    """SUMO's MSLink::computeDistToDivergence. For two lanes merging into one:
    the length of `shape`'s end that lies within `min_dist` of `sib`, taken as
    the max over both lanes and scaled to the lane's length. For two lanes
    leaving the same lane (`same_source`, shapes not reversed): the lane
    position where `shape` parts from `sib`, one geometric distance for both
    lanes, each scaled to its own lane's length
    (``interpolateGeometryPosToLanePos``)."""

    def glen(p):
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())

    def pdist(pt, poly):
        a, b = poly[:-1], poly[1:]
        v = b - a
        l2 = np.maximum((v * v).sum(1), 1e-300)
        t = np.clip(((pt - a) * v).sum(1) / l2, 0, 1)
        return float(np.min(np.linalg.norm(a + t[:, None] * v - pt, axis=1)))

    g_l, g_s = glen(shape), glen(sib)
    lr, sr = (shape, sib) if same_source else (shape[::-1], sib[::-1])
    lbc_s = lbc_l = 0.0
    if np.linalg.norm(lr[-1] - sr[-1]) > min_dist:
        dist = [pdist(p, sr) for p in lr] + [pdist(p, lr) for p in sr]
        n_l = len(lr)
        if dist[-1] > min_dist and dist[n_l - 1] > min_dist:
            for j in range(len(sr) - 2, -1, -1):
                i = j + n_l
                seg = float(np.linalg.norm(sr[j] - sr[j + 1]))
                if dist[i] > min_dist:
                    lbc_s += seg
                else:
                    lbc_s += seg - (min_dist - dist[i]) * seg / (dist[i + 1] - dist[i])
                    break
            for i in range(n_l - 2, -1, -1):
                seg = float(np.linalg.norm(lr[i] - lr[i + 1]))
                if dist[i] > min_dist:
                    lbc_l += seg
                else:
                    lbc_l += seg - (min_dist - dist[i]) * seg / (dist[i + 1] - dist[i])
                    break
    r = min(max(sib_length - lbc_s, length - lbc_l), g_s, g_l)
    return r * length / g_l


def connection_visibility(
    path: str | Path, from_edge: str, to_edge: str, from_lane: int | None = None
) -> float:
    """Foe visibility distance of a connection (SUMO's default is 4.5 m);
    of the one leaving lane `from_lane` where given."""
    for conn in ET.parse(path).getroot().iter("connection"):
        lane_ok = from_lane is None or conn.get("fromLane") == str(from_lane)
        if conn.get("from") == from_edge and conn.get("to") == to_edge and lane_ok:
            return float(conn.get("visibility", 4.5))
    raise NetworkError(f"{path}: no connection {from_edge} -> {to_edge}")
