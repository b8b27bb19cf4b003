"""A roundabout with two-lane roads as the step's arrays: lane paths as routes.

The step (`jaxround.core.dynamics`) keeps a vehicle as (route, position
along it) and finds leaders through the lanes routes share
(`CompiledNetwork.lane_offset`). With parallel lanes each lane path of
`jaxround.lanes.paths` becomes one such route, so a vehicle follows the
vehicles on its own lanes, whatever their path, and not those beside it;
a lane change moves it to another path (`LanePaths.change_path`).

Each entry lane is an entry of its own, with its yield line and its foe:
the ring's through lane that merges with it into the same ring lane (the
right entry lane's link merges with the outer ring lane going on, the
left one's with the inner ring lane). Entries are numbered right lanes
first, leg by leg (entry g < n_legs is leg g's right lane), then the left
lanes. A vehicle departs on the route's path SUMO's ``departLane="best"``
takes when nothing is in the way: the rightmost lane whose path reaches
the exit.

A left entry lane's link also crosses the outer ring lane's through link
and yields to it (`LanePaths.link_foes`): ``entry_crossing`` names the
entry whose through lane that is, and the entry test
(`jaxround.core.junction.entry_blocked_weight`) asks that link's
registrations too.

A one-lane roundabout compiles to the arrays of
`jaxround.sumo_files.compile.compile_network`, path for route and lane for
lane (the lanes numbered in another order); `make` still uses that one
there.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import sumolib

from jaxround.core.crossing_tables import crossing_conflicts
from jaxround.core.network import CompiledNetwork, NetworkError
from jaxround.lanes.paths import LanePaths, lane_paths
from jaxround.scenario.edges import in_edge, ring_edge
from jaxround.sumo_files.compile import connection_visibility, internal_geometry


def compile_lane_network(
    net_file: str | Path, n_legs: int | None = None
) -> tuple[CompiledNetwork, LanePaths]:
    """The step's arrays of a roundabout with one- or two-lane roads.

    Args:
        net_file: a `.net.xml` from `jaxround.sumo_files.netconvert`.
        n_legs: expected legs; inferred from the ``in_*`` edges if None.

    Returns:
        (network, paths): the `CompiledNetwork` whose routes are the lane
        paths (route r is path r of `paths`), and the `LanePaths`.

    Raises:
        NetworkError: as `lane_paths`; an entry lane that does not join the
            ring through one minor link, or a route no lane path completes.
    """
    paths = lane_paths(net_file, n_legs)
    net = sumolib.net.readNet(str(net_file), withInternal=True)
    index = {lid: k for k, lid in enumerate(paths.lane_ids)}
    lane_length = paths.lane_length
    lane_next, shapes, (sibling, diverge, partner, converge) = internal_lanes(
        net_file, net, paths
    )

    entries = _entries(net_file, net, paths, index, partner)
    entry_lane = np.array([e[0] for e in entries], np.int32)
    first_lane = paths.path_lanes[:, 0]
    route_entry = np.array(
        [int(np.nonzero(entry_lane == lane)[0][0]) for lane in first_lane], np.int32
    )
    ring_through = np.array([e[2] for e in entries], np.int32)
    crossing = _crossings(paths, entries)
    n_paths, n_entries = paths.n_paths, len(entries)
    conflict_offset = np.full((n_paths, n_entries), np.nan)
    for p in range(n_paths):
        for g, through in enumerate(ring_through):
            conflict_offset[p, g] = paths.lane_offset[p, through]

    return CompiledNetwork(
        n_legs=paths.n_legs,
        lane_ids=paths.lane_ids,
        lane_length=lane_length,
        lane_speed=np.array(
            [net.getLane(lid).getSpeed() for lid in paths.lane_ids], np.float64
        ),
        lane_next=lane_next,
        lane_sibling=sibling,
        lane_diverge=diverge,
        lane_partner=partner,
        lane_converge=converge,
        lane_shapes=shapes,
        route_od=paths.route_od[paths.path_route],
        route_index=_depart_paths(net_file, paths),
        route_lanes=paths.path_lanes,
        route_lane_start=paths.path_lane_start,
        route_length=paths.path_length,
        lane_offset=paths.lane_offset,
        entry_lane=entry_lane,
        entry_internal=np.array([e[1] for e in entries], np.int32),
        ring_through=ring_through,
        yield_offset=lane_length[first_lane],
        conflict_offset=conflict_offset,
        entry_visibility=np.array([e[3] for e in entries]),
        route_entry=route_entry,
        route_arrives=paths.path_complete.copy(),
        entry_crossing=crossing,
        crossings=crossing_conflicts(
            [
                (e[1], entries[c][2])
                for e, c in zip(entries, crossing, strict=True)
                if c >= 0
            ],
            shapes,
            lane_length,
            np.array([net.getLane(lid).getWidth() for lid in paths.lane_ids]),
        ),
    ), paths


def internal_lanes(
    net_file: str | Path, net: sumolib.net.Net, paths: LanePaths
) -> tuple[np.ndarray, tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """The internal lanes of ``paths``' lanes (L, in their order): int (L,)
    the lane each leads onto (-1: a normal lane), the lanes' shapes, and
    `compile.internal_geometry` (sibling, diverge, partner, converge).

    Raises:
        NetworkError: an internal lane with more than one outgoing lane.
    """
    lanes = [net.getLane(lid) for lid in paths.lane_ids]
    index = {lid: k for k, lid in enumerate(paths.lane_ids)}
    lane_next = -np.ones(len(lanes), np.int32)
    for k, ln in enumerate(lanes):
        if paths.lane_internal[k]:
            outs = ln.getOutgoing()
            if len(outs) != 1:
                raise NetworkError(f"{net_file}: internal lane {ln.getID()} forks")
            lane_next[k] = index[outs[0].getToLane().getID()]
    shapes = tuple(np.asarray(ln.getShape(), np.float64) for ln in lanes)
    geometry = internal_geometry(lanes, shapes, paths.lane_length, lane_next)
    return lane_next, shapes, geometry


def _entries(
    net_file: str | Path,
    net: sumolib.net.Net,
    paths: LanePaths,
    index: dict[str, int],
    partner: np.ndarray,
) -> list[tuple[int, int, int, float]]:
    """(entry lane, its internal lane, the through lane it merges with, the
    link's foe visibility) of each entry lane: right lanes leg by leg, then
    left lanes."""
    found: list[tuple[int, tuple[int, int, int, float]]] = []
    for leg in range(paths.n_legs):
        ring = ring_edge(leg)
        for ln in net.getEdge(in_edge(leg)).getLanes():
            conns = [c for c in ln.getOutgoing() if c.getTo().getID() == ring]
            if len(conns) != 1 or not conns[0].getViaLaneID():
                raise NetworkError(
                    f"{net_file}: lane {ln.getID()} joins the ring through "
                    f"{len(conns)} links, expected one"
                )
            conn = conns[0]
            if conn.getState() != "m":
                raise NetworkError(
                    f"{net_file}: the entry from {ln.getID()} is not a minor "
                    "(yield) link"
                )
            internal = index[conn.getViaLaneID()]
            if partner[internal] < 0:
                raise NetworkError(
                    f"{net_file}: the entry from {ln.getID()} merges with no ring lane"
                )
            visibility = connection_visibility(
                net_file, in_edge(leg), ring, ln.getIndex()
            )
            entry = (index[ln.getID()], internal, int(partner[internal]), visibility)
            found.append((ln.getIndex() * paths.n_legs + leg, entry))
    return [entry for _, entry in sorted(found)]


def _crossings(
    paths: LanePaths, entries: list[tuple[int, int, int, float]]
) -> np.ndarray:
    """int (G,): the entry whose through lane each entry's link yields to
    besides the one it merges with (-1: none)."""
    through_of = {e[2]: g for g, e in enumerate(entries)}
    crossing = -np.ones(len(entries), np.int32)
    for g, (_, internal, merge, _) in enumerate(entries):
        foes = [f for f in paths.link_foes[internal] if f >= 0 and f != merge]
        unknown = [paths.lane_ids[f] for f in foes if f not in through_of]
        if unknown or len(foes) > 1:
            raise NetworkError(
                f"the entry link to {paths.lane_ids[internal]} yields to "
                f"{[paths.lane_ids[f] for f in foes]} besides its merge; the "
                "step knows one crossing ring lane per entry"
            )
        if foes:
            crossing[g] = through_of[foes[0]]
    return crossing


def _depart_paths(net_file: str | Path, paths: LanePaths) -> np.ndarray:
    """int (n_legs, n_legs): the path a vehicle of (origin, exit) departs on,
    its route's rightmost first lane whose path reaches the exit (-1 on the
    diagonal)."""
    table = -np.ones_like(paths.route_index)
    for o in range(paths.n_legs):
        for d in range(paths.n_legs):
            r = paths.route_index[o, d]
            if r < 0:
                continue
            complete = [
                p for p in paths.depart_path[r] if p >= 0 and paths.path_complete[p]
            ]
            if not complete:
                raise NetworkError(
                    f"{net_file}: no lane of leg {o}'s entry leads to exit {d} "
                    "without a lane change"
                )
            table[o, d] = complete[0]
    return table
