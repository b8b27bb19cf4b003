"""SUMO's strategic lane table for fixed routes, built once per network.

`MSVehicle::updateBestLanes` (SUMO's ``src/microsim/MSVehicle.cpp``) builds,
whenever a vehicle enters a normal edge of its route, one `LaneQ` per lane
of each route edge ahead: how far one can drive from the lane's start along
the route without changing (`length`), how many lanes to move to the edge's
best lane (`bestLaneOffset`, + left), whether the lane leads on along the
route (`allowsContinuation`) and the lanes followed (`bestContinuations`).
Without stops it depends on the network, the route and, through the
look-ahead window, a few vType numbers: it is computed here once, in the
same floating-point order as SUMO (which compares lengths for equality).

Not ported (the roundabouts jaxround builds have none): stops and
`arrivalLane`, lane permissions, `changeLeft`/`changeRight` restrictions,
disconnected routes, `MSDevice_ElecHybrid`'s overhead-wire preference.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import sumolib

from jaxround.scenario.config import DriverConfig, ScenarioConfig
from jaxround.scenario.edges import route_edges
from jaxround.sumo_files.netconvert import network_file

#: `updateBestLanes` adds edges while it has seen at most MOTORWAY_MIN_EDGES
#: or less than max(maxBrakeDist, MOTORWAY_LOOK_AHEAD_M) m, and at most
#: URBAN_MIN_EDGES or less than max(maxBrakeDist, URBAN_LOOK_AHEAD_M) m.
MOTORWAY_MIN_EDGES, MOTORWAY_LOOK_AHEAD_M = 4, 3000.0
URBAN_MIN_EDGES, URBAN_LOOK_AHEAD_M = 8, 200.0


@dataclass(frozen=True)
class LookAheadDriver:
    """The vType numbers of `updateBestLanes`' look-ahead, and the class.

    Defaults: SUMO's passenger car (maxSpeed 55.55 m/s, decel 4.5 m/s^2,
    tau 1 s, minGap 2.5 m) at SUMO's default step length of 1 s.
    """

    max_speed: float = 55.55  # m/s, `MSBaseVehicle::getMaxSpeed`
    decel: float = 4.5  # m/s^2
    tau: float = 1.0  # s
    min_gap: float = 2.5  # m
    step_length: float = 1.0  # s
    vehicle_class: str = "passenger"

    @classmethod
    def from_config(cls, driver: DriverConfig, step_length: float) -> LookAheadDriver:
        return cls(driver.max_speed, driver.decel, driver.tau, driver.min_gap,
                   step_length)  # fmt: skip

    def brake_gap(self, speed: float) -> float:
        """`MSCFModel::brakeGapEuler(speed, decel, tau)` (``MSCFModel.cpp``):
        the distance braking at `decel` step by step takes, plus `speed * tau`."""
        speed_reduction = self.decel * self.step_length
        steps = int(speed / speed_reduction)
        braking = steps * speed - speed_reduction * steps * (steps + 1) / 2
        return braking * self.step_length + speed * self.tau

    def max_brake_dist(self, start_lane_length: float) -> float:
        """`updateBestLanes`' ``maxBrakeDist``: the start lane's length plus
        a headway and a braking distance at full speed, plus the minimum gap."""
        v = self.max_speed
        return start_lane_length + self.tau * v + self.brake_gap(v) + self.min_gap


@dataclass(frozen=True)
class LaneRow:
    """One `MSVehicle::LaneQ`.

    Attributes:
        lane_id: the lane (a normal lane).
        length: m drivable from the lane's start along the route without
            changing lanes, as `updateBestLanes` sums it.
        best_lane_offset: lanes to move to the edge's best lane (+ left).
        allows_continuation: the lane leads on along the route.
        continuations: `bestContinuations`: this lane, then the lane
            followed on each later route edge (normal lanes).
    """

    lane_id: str
    length: float
    best_lane_offset: int
    allows_continuation: bool
    continuations: tuple[str, ...]


@dataclass
class _LaneQ:
    """A `LaneQ` while `updateBestLanes` works on it."""

    lane: sumolib.net.lane.Lane
    length: float
    allows_continuation: bool
    offset: int = 0
    current_length: float = field(init=False)
    continuations: list[sumolib.net.lane.Lane] = field(init=False)

    def __post_init__(self) -> None:
        self.current_length, self.continuations = self.length, [self.lane]

    def row(self) -> LaneRow:
        ids = tuple(lane.getID() for lane in self.continuations)
        return LaneRow(self.lane.getID(), self.length, self.offset,
                       self.allows_continuation, ids)  # fmt: skip


def _link(lane: sumolib.net.lane.Lane, to_lane: sumolib.net.lane.Lane) -> Any:
    """The connection from `lane` to `to_lane`, or None."""
    return next((c for c in lane.getOutgoing() if c.getToLane() is to_lane), None)


def _next_link_priority(continuations: list[sumolib.net.lane.Lane]) -> int:
    """`MSVehicle::nextLinkPriority`: 1 if the link from the first lane to
    the second has priority (an upper-case state), 0 if not, -1 without one."""
    link = _link(*continuations[:2]) if len(continuations) > 1 else None
    return -1 if link is None else int(link.getState().isupper())


def _route_edges(
    net: sumolib.net.Net, route: Sequence[str], vehicle_class: str
) -> list[sumolib.net.edge.Edge]:
    """The route's edges, refused where this port leaves SUMO's rules out."""
    edges = [net.getEdge(e) for e in route]
    for edge in edges:
        if len({lane.getLength() for lane in edge.getLanes()}) != 1:
            raise ValueError(f"edge {edge.getID()}: lanes of different lengths")
        if not all(lane.allows(vehicle_class) for lane in edge.getLanes()):
            raise ValueError(f"edge {edge.getID()}: a lane not for {vehicle_class}")
    for a, b in zip(edges, edges[1:], strict=False):
        if b not in a.getOutgoing():
            raise ValueError(f"{a.getID()} does not lead to {b.getID()}")
    return edges


def look_ahead_edges(
    edge_lengths: Sequence[float], start: int, max_brake_dist: float
) -> int:
    """How many route edges, from `start` on, `updateBestLanes` tables.

    It adds an edge, then goes on while the route does and the rules at
    `MOTORWAY_MIN_EDGES` hold.
    """
    motorway_m = max(max_brake_dist, MOTORWAY_LOOK_AHEAD_M)
    urban_m = max(max_brake_dist, URBAN_LOOK_AHEAD_M)
    seen, seen_length = 0, 0.0
    for length in edge_lengths[start:]:
        seen, seen_length = seen + 1, seen_length + length
        if not (seen <= MOTORWAY_MIN_EDGES or seen_length < motorway_m) or not (
            seen <= URBAN_MIN_EDGES or seen_length < urban_m
        ):
            break
    return seen


def _rank_last_edge(lanes: list[_LaneQ]) -> None:
    """The last edge of the window: shorter lanes point to the nearer end of
    the run of longest ones."""
    best = max(q.length for q in lanes)
    best_index = next(i for i, q in enumerate(lanes) if q.length == best)
    best_max_index = max(i for i, q in enumerate(lanes) if q.length == best)
    for i, q in enumerate(lanes):
        if q.length < best:
            q.offset = _nearer(best_index, best_max_index, i)


def _nearer(best_index: int, best_max_index: int, index: int) -> int:
    if abs(best_index - index) < abs(best_max_index - index):
        return best_index - index
    return best_max_index - index


def _take_from_next(lanes: list[_LaneQ], next_lanes: list[_LaneQ]) -> None:
    """One step of the backward pass: each lane of an edge takes the best
    next lane it leads to, then the edge's best lane is chosen and every
    other lane gets its offset (and, behind a lower-priority link than the
    best lane's, its own length only)."""
    edge = lanes[0].lane.getEdge()
    best_connected_length = max(
        (m.length for m in next_lanes
         if any(_link(q.lane, m.lane) is not None for q in lanes)),
        default=-1.0,
    )  # fmt: skip
    best_length = max(m.length for m in next_lanes)
    if best_connected_length <= 0:
        raise ValueError(f"edge {edge.getID()}: no lane leads on along the route")
    best_index = best_max_index = 0
    for i, q in enumerate(lanes):
        best_next = None
        if q.allows_continuation:
            for m in next_lanes:
                if _link(q.lane, m.lane) is not None and (
                    best_next is None
                    or best_next.length < m.length
                    or (best_next.length == m.length
                        and abs(best_next.offset) > abs(m.offset))
                ):  # fmt: skip
                    best_next = m
            if best_next is not None:
                if (best_next.length == best_connected_length
                        and abs(best_next.offset) < 2):  # fmt: skip
                    q.length += best_length
                else:
                    q.length += best_next.length
                q.offset = best_next.offset
        if best_next is not None and (
            best_next.allows_continuation or best_next.length > 0
        ):
            q.continuations += best_next.continuations
        else:
            q.allows_continuation = False
        b = lanes[best_index]
        same = b.length == q.length and abs(b.offset) == abs(q.offset)
        b_priority = _next_link_priority(b.continuations)
        q_priority = _next_link_priority(q.continuations)
        if (
            b.length < q.length
            or (b.length == q.length and abs(b.offset) > abs(q.offset))
            or (same and b_priority < q_priority)
        ):
            best_index = best_max_index = i
        elif same and b_priority == q_priority:
            best_max_index = i
    # `lanes[best_index]` is read anew for each lane, as SUMO does: its own
    # offset is reset to 0 on its turn.
    for i, q in enumerate(lanes):
        b = lanes[best_index]
        lower_priority = _next_link_priority(q.continuations) < _next_link_priority(
            b.continuations
        )
        if (
            q.length < b.length
            or (q.length == b.length and abs(q.offset) > abs(b.offset))
            or lower_priority
        ):
            q.offset = _nearer(best_index, best_max_index, i)
            if lower_priority:
                # SUMO: "try to move away from the lower-priority lane before it ends"
                q.length = q.current_length
        else:
            q.offset = 0


def edge_tables(
    net: sumolib.net.Net,
    route: Sequence[str],
    start: int = 0,
    driver: LookAheadDriver | None = None,
) -> list[list[LaneRow]]:
    """SUMO's `myBestLanes` as `updateBestLanes` builds it on entering
    ``route[start]``: one list of rows per route edge in its look-ahead
    window (the first is the current edge), one row per lane, right to left.

    Args:
        net: the network (`sumolib.net.readNet`).
        route: the route's normal edge ids.
        start: the route index of the edge entered.
        driver: the vType numbers of the look-ahead (SUMO's passenger car
            if None).
    """
    driver = driver or LookAheadDriver()
    edges = _route_edges(net, route, driver.vehicle_class)
    lengths = [e.getLane(0).getLength() for e in edges]  # `MSEdge::getLength`
    window = look_ahead_edges(lengths, start, driver.max_brake_dist(lengths[start]))
    tables: list[list[_LaneQ]] = []
    for k in range(start, start + window):
        after = edges[k + 1] if k + 1 < len(edges) else None
        tables.append([  # allowsContinuation: in `MSEdge::allowedLanes(after)`
            _LaneQ(lane, lengths[k], after is None
                   or any(c.getTo() is after for c in lane.getOutgoing()))
            for lane in edges[k].getLanes()
        ])  # fmt: skip
    _rank_last_edge(tables[-1])
    for k in range(len(tables) - 2, -1, -1):
        _take_from_next(tables[k], tables[k + 1])
    return [[q.row() for q in table] for table in tables]


def route_rows(
    net: sumolib.net.Net, route: Sequence[str], driver: LookAheadDriver | None = None
) -> list[list[LaneRow]]:
    """The current edge's rows on each edge of the route: entry k is what
    `libsumo.vehicle.getBestLanes` returns while the vehicle is on
    ``route[k]`` (the table is rebuilt on entering each normal edge)."""
    return [edge_tables(net, route, k, driver)[0] for k in range(len(route))]


def internal_lane_rows(
    net: sumolib.net.Net,
    route: Sequence[str],
    start: int,
    internal_edge_id: str,
    driver: LookAheadDriver | None = None,
) -> list[LaneRow]:
    """What `getBestLanes` returns on the internal edge between ``route[start]``
    and ``route[start + 1]`` (`updateBestLanes` on an internal lane).

    SUMO keeps the table built on ``route[start]`` and restricts its rows of
    the next edge to the lanes the internal edge's lanes lead to, one row per
    internal lane in its order, each offset clipped to stay on the internal
    edge's lanes; lengths stay (measured from the next lane's start). SUMO
    puts a null lane in front of each `bestContinuations`, which libsumo
    leaves out, as this does.
    """
    next_rows = {row.lane_id: row for row in edge_tables(net, route, start, driver)[1]}
    internal_lanes = net.getEdge(internal_edge_id).getLanes()
    rows = []
    for i, lane in enumerate(internal_lanes):
        # `getLinkCont()[0]->getLane()`: the normal lane the internal lane leads to
        row = next_rows[lane.getOutgoing()[0].getToLane().getID()]
        offset = min(max(row.best_lane_offset, -i), len(internal_lanes) - i - 1)
        rows.append(LaneRow(row.lane_id, row.length, offset, row.allows_continuation,
                            row.continuations))  # fmt: skip
    return rows


@dataclass(frozen=True)
class BestLanesArrays:
    """The current edge's rows (`route_rows`) of every route, padded.

    Shapes: R routes, E most edges in a route, Z most lanes on an edge. Lane
    z is ``f"{route_edge_ids[r][k]}_{z}"`` (0 rightmost).

    Attributes:
        route_edge_ids: R tuples of edge ids.
        n_lanes: (R, E) int32: lanes of route edge k, 0 past the route's end.
        length: (R, E, Z) float64, m: `LaneRow.length`; NaN where no lane.
        best_lane_offset: (R, E, Z) int32, 0 where no lane.
        allows_continuation: (R, E, Z) bool, False where no lane.
        continuation: (R, E, Z, E) int32: ``continuation[r, k, z, j]`` is the
            lane (index on route edge k + j) of lane z's `bestContinuations`
            (j = 0: lane z itself); -1 past its end.
    """

    route_edge_ids: tuple[tuple[str, ...], ...]
    n_lanes: np.ndarray
    length: np.ndarray
    best_lane_offset: np.ndarray
    allows_continuation: np.ndarray
    continuation: np.ndarray


def best_lanes_arrays(
    net: sumolib.net.Net,
    routes: Sequence[Sequence[str]],
    driver: LookAheadDriver | None = None,
) -> BestLanesArrays:
    """`route_rows` of each route, as `BestLanesArrays`."""
    tables = [route_rows(net, route, driver) for route in routes]
    n_routes, n_edges = len(routes), max(len(route) for route in routes)
    n_lanes_max = max(len(rows) for table in tables for rows in table)
    n_lanes = np.zeros((n_routes, n_edges), np.int32)
    length = np.full((n_routes, n_edges, n_lanes_max), np.nan)
    offset = np.zeros((n_routes, n_edges, n_lanes_max), np.int32)
    allows = np.zeros((n_routes, n_edges, n_lanes_max), bool)
    continuation = -np.ones((n_routes, n_edges, n_lanes_max, n_edges), np.int32)
    for r, table in enumerate(tables):
        for k, rows in enumerate(table):
            n_lanes[r, k] = len(rows)
            for z, row in enumerate(rows):
                length[r, k, z] = row.length
                offset[r, k, z] = row.best_lane_offset
                allows[r, k, z] = row.allows_continuation
                for j, lane_id in enumerate(row.continuations):
                    continuation[r, k, z, j] = net.getLane(lane_id).getIndex()
    ids = tuple(tuple(route) for route in routes)
    return BestLanesArrays(ids, n_lanes, length, offset, allows, continuation)


def scenario_routes(n_legs: int) -> list[list[str]]:
    """Every route of a roundabout of `n_legs` legs, origin-major, in the
    order of `jaxround.sumo_files.compile` and of the scenario's routes file."""
    return [route_edges(o, d, n_legs)
            for o in range(n_legs) for d in range(n_legs) if o != d]  # fmt: skip


def scenario_best_lanes(
    cfg: ScenarioConfig, net_file: str | Path | None = None
) -> BestLanesArrays:
    """`BestLanesArrays` of all routes of the scenario, with the look-ahead of
    its human drivers' vType (on its roundabouts every route is covered).

    Args:
        cfg: the scenario.
        net_file: its `.net.xml`; built (and cached) if None.
    """
    net_file = network_file(cfg) if net_file is None else net_file
    net = sumolib.net.readNet(str(net_file), withInternal=True)
    driver = LookAheadDriver.from_config(cfg.drivers.hv, cfg.simulation.dt_s)
    return best_lanes_arrays(net, scenario_routes(cfg.n_legs), driver)
