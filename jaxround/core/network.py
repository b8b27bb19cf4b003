"""A compiled roundabout network: the static arrays the JAX step reads.

Built from the `.net.xml` SUMO runs by `jaxround.sumo_files.compile`, so the
JAX environment never holds a second, hand-written geometry.

Each route (origin leg, exit leg) is a sequence of lanes, SUMO's internal
junction lanes included. A vehicle's state is its route and its position along
that route (front bumper, metres from the start of the route's first lane).
To find leaders across routes, every lane has an offset along every route
that drives it (nan where it does not); a vehicle on an internal lane that
merges into a route's next lane is projected onto that route through the merge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxround.core.crossing_tables import CrossingConflicts
from jaxround.scenario.edges import ring_edge


class NetworkError(ValueError):
    """The network is not a single-lane, single-ring roundabout jaxround can drive."""


@dataclass(frozen=True)
class CompiledNetwork:
    """Static arrays of a roundabout. R routes, L lanes, K max lanes per route.

    Attributes:
        n_legs: number of legs.
        lane_ids: the SUMO lane ids, length L.
        lane_length: float (L,) metres.
        lane_speed: float (L,) speed limit, m/s.
        lane_next: int (L,) the single successor of an internal lane, -1 else.
        lane_sibling: int (L,) the other internal lane leaving the same lane
            (exit vs through), -1 if none.
        lane_diverge: float (L,) lane position where an internal lane parts
            from its sibling (SUMO's same-source conflict point: one
            geometric distance from their common start, each lane's own
            length scale).
        lane_partner: int (L,) the other internal lane merging into the same
            lane (entry vs through), -1 if none.
        lane_converge: float (L,) length of an internal lane's end within 2.5 m
            of its merge partner (SUMO's length behind the crossing).
        lane_shapes: list of (n_i, 2) arrays, lane centre lines for drawing.
        route_od: int (R, 2) origin and exit leg of each route.
        route_index: int (n_legs, n_legs) route of (origin, exit), -1 on the diagonal.
        route_lanes: int (R, K) lane sequence, padded with -1.
        route_lane_start: float (R, K) position where each lane starts, nan padded.
        route_length: float (R,) total length.
        lane_offset: float (R, L) where lane l starts along route r, nan if not on r.
        entry_lane: int (n_legs,) the approach lane ``in_{i}_0``.
        entry_internal: int (n_legs,) internal lane from the approach onto the ring.
        ring_through: int (n_legs,) internal lane of the circulating (priority)
            link that the entry at leg i yields to.
        yield_offset: float (R,) where the route's yield line (end of its entry
            lane) lies along the route.
        conflict_offset: float (R, n_legs) where the route enters the ring
            through-link of leg i (start of ``ring_through[i]``), nan if it
            does not pass that link.
        entry_visibility: float (n_legs,) foe visibility distance of each entry (m).
        route_entry: int (R,) the entry (index into the entry arrays) each
            route starts at; None: its origin leg. A two-lane roundabout
            (`jaxround.lanes.ring_network`) has one entry per entry lane, G
            of them, and a route per lane path.
        entry_crossing: int (G,) the entry whose ring through lane each
            entry's link crosses and yields to as well (-1: none; None: no
            entry has one): a left entry lane's link crosses the outer ring
            lane going on.
        route_arrives: bool (R,) the route ends where vehicles leave; None:
            all do. A lane path that ends on the ring does not: a vehicle
            must change lanes before its end.
        crossings: the internal lanes that cross inside a junction, as SUMO
            measures the conflict (`jaxround.core.crossing_tables`); None:
            none cross.
    """

    n_legs: int
    lane_ids: tuple[str, ...]
    lane_length: np.ndarray
    lane_speed: np.ndarray
    lane_next: np.ndarray
    lane_sibling: np.ndarray
    lane_diverge: np.ndarray
    lane_partner: np.ndarray
    lane_converge: np.ndarray
    lane_shapes: tuple[np.ndarray, ...]
    route_od: np.ndarray
    route_index: np.ndarray
    route_lanes: np.ndarray
    route_lane_start: np.ndarray
    route_length: np.ndarray
    lane_offset: np.ndarray
    entry_lane: np.ndarray
    entry_internal: np.ndarray
    ring_through: np.ndarray
    yield_offset: np.ndarray
    conflict_offset: np.ndarray
    entry_visibility: np.ndarray
    route_entry: np.ndarray | None = None
    route_arrives: np.ndarray | None = None
    entry_crossing: np.ndarray | None = None
    crossings: CrossingConflicts | None = None

    @property
    def n_routes(self) -> int:
        return int(self.route_od.shape[0])

    @property
    def n_entries(self) -> int:
        """G: entries with a yield line (one per leg on one-lane entries)."""
        return int(self.entry_lane.shape[0])

    @property
    def entry_of_route(self) -> np.ndarray:
        """int (R,) the entry each route starts at."""
        if self.route_entry is None:
            return self.route_od[:, 0]
        return self.route_entry

    @property
    def entry_leg(self) -> np.ndarray:
        """int (G,) the leg of each entry: entry g < n_legs is leg g's (its
        outer lane on a two-lane entry); the others are the inner lanes of
        their routes' origin legs."""
        leg = np.arange(self.n_entries) % self.n_legs
        leg[self.entry_of_route] = self.route_od[:, 0]
        return leg

    @property
    def all_arrive(self) -> bool:
        """Every route ends where vehicles leave (a static fact)."""
        return self.route_arrives is None or bool(np.all(self.route_arrives))

    @property
    def n_lanes(self) -> int:
        return len(self.lane_ids)

    @property
    def ring_length(self) -> float:
        """Length of one lap of the ring (ring edges and through lanes)."""
        ids = {lid: k for k, lid in enumerate(self.lane_ids)}
        ring = [ids[f"{ring_edge(i)}_0"] for i in range(self.n_legs)]
        through = self.ring_through[: self.n_legs]  # the right lanes' entries
        return float(self.lane_length[ring].sum() + self.lane_length[through].sum())
