"""Following SUMO's vehicles along the lane paths (`jaxround.lanes.paths`).

SUMO reports a vehicle's lane; the JAX step keeps it on a lane path (its
route there) and a position along it. `PathTracker` turns each vehicle's
lane after every SUMO step into its path: a new vehicle takes the path of
its route from the lane it was inserted on, and a vehicle found on
another lane of the edge its path is on changed lanes, to the path
`LanePaths.change_path` names. The SUMO recorder
(`jaxround.apps.ring_lane_record`) and the SUMO observer of AV
controllers (`sumo_export.traffic`) read SUMO this way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jaxround.lanes.paths import LEFT, RIGHT, LanePaths


@dataclass
class PathTracker:
    """Follows SUMO's vehicles along the lane paths (see the module doc).

    Attributes:
        paths: the roundabout's lane paths.
        state: each vehicle's path, by SUMO id (`forget` the ones gone).
    """

    paths: LanePaths
    state: dict[str, int] = field(default_factory=dict)  # id -> path

    def __post_init__(self) -> None:
        self.index = {lid: k for k, lid in enumerate(self.paths.lane_ids)}
        self.edge = [lid.rsplit("_", 1)[0] for lid in self.paths.lane_ids]

    def step(self, vid: str, lane_id: str, route: int) -> tuple[int, int, int]:
        """(path before the step's change, path after, change -1/0/+1).

        Raises:
            ValueError: the vehicle is on an edge its path does not take, or
                changed to a lane its paths do not allow.
        """
        lane = self.index[lane_id]
        if vid not in self.state:
            path = int(self.paths.depart_path[route, self.paths.lane_index[lane]])
            self.state[vid] = path
            return path, path, 0
        path = self.state[vid]
        on_path = next((
            int(x) for x in self.paths.path_lanes[path]
            if x >= 0 and self.edge[x] == self.edge[lane]
        ), None)  # fmt: skip
        if on_path is None:
            raise ValueError(f"{vid}: on {lane_id}, off its lane path")
        if on_path == lane:
            return path, path, 0
        side = LEFT if self.paths.lane_left[on_path] == lane else RIGHT
        k = int(np.nonzero(self.paths.path_lanes[path] == on_path)[0][0])
        new = int(self.paths.change_path[path, k, side])
        if new < 0 or self.paths.path_lanes[new, k] != lane:
            raise ValueError(f"{vid}: a change to {lane_id} the paths do not allow")
        self.state[vid] = new
        return path, new, 1 if side == LEFT else -1

    def forget(self, keep: set[str]) -> None:
        """Drop every vehicle but those in ``keep`` (the ones still driving)."""
        for vid in [v for v in self.state if v not in keep]:
            del self.state[vid]
