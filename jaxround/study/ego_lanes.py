"""The ego's lanes on two-lane roads: the participant's turn signal and the
lane changes SUMO makes.

The participant asks for the lane to the left or the right (a key or a
gamepad button, ``{"type": "lane"}`` in `jaxround.study.protocol`). The
ask is a turn signal held for up to `SIGNAL_S` seconds: at every step of
it, while the ego is on a road (not inside a junction) that has the lane
asked for, SUMO is asked to change there for half a step
(`vehicle.changeLane`, as the AVs' lane action asks,
`sumo_export.controller.PolicyController.request_lanes`), and SUMO changes
when its safety checks allow it. The signal ends on the lane asked for,
on a road that has no such lane (asked inside a junction, the lane is
looked for on the next road), or after `SIGNAL_S`.

The ego's lane-change mode is `EGO_LANE_CHANGE_MODE` (SUMO's TraCI
``setLaneChangeMode`` bits, `MSVehicle::Influencer`): SUMO changes the
ego's lane only where its route needs another lane (LC2013's strategic
changes, to reach the exit), unless a signal asks otherwise; it makes no
cooperative, speed-gain or keep-right changes for the participant; and
an asked change waits for gaps that are safe for the vehicles on the
target lane (bits 8-9 = 2). The ego's speed stays the pedals' (speed mode
32, `jaxround.study.sim`): the participant slows down to find a gap.

Every change of the ego's lane is a ``lane_change`` event (``ride_events``)
whose detail says which way, to which lane, and whether it was asked for or
made for the route; a change in the step that takes the ego onto the next
road is told from the lanes its last lane leads to.
"""

from __future__ import annotations

from typing import Any

#: SUMO lane-change mode of the ego: strategic changes where no signal asks
#: otherwise (bits 0-1 = 1), none of its own otherwise, asked changes with
#: the target lane's safe gaps (bits 8-9 = 2).
EGO_LANE_CHANGE_MODE = 0b10_0000_0001
#: Longest a turn signal waits for its lane change, s.
SIGNAL_S = 4.0
#: The directions a participant may ask for, as lane index steps.
DIRECTIONS = {"left": 1, "right": -1}


class EgoLanes:
    """The ego's turn signal, its lane changes and where its route wants it.

    Args:
        libsumo: the running SUMO.
        ego_id: the ego's vehicle id.
        step_s: SUMO's step, s.
        events: the ride's event rows, appended to.

    Attributes:
        signal: +1 left, -1 right, 0 none.
        view: what the browser shows, ``[index, lanes, signal, route_side]``
            (the ego's lane index from the right, the road's lanes, the
            signal, and the side the ego must move to before the lane ends:
            -1 right, +1 left, 0 none, `route_side`), or None inside a
            junction or off the roads.
    """

    def __init__(
        self, libsumo: Any, ego_id: str, step_s: float, events: list[dict[str, Any]]
    ) -> None:
        self.libsumo = libsumo
        self.ego_id = ego_id
        self.step_s = step_s
        self.signal = 0
        self.signal_until_s = 0.0
        self.events = events
        self.view: list[int] | None = None
        self._last: str | None = None
        self._links: dict[str, set[str]] = {}

    def entered(self) -> None:
        """The ego is on the roads (each pass): its lane-change mode, no signal."""
        self.libsumo.vehicle.setLaneChangeMode(self.ego_id, EGO_LANE_CHANGE_MODE)
        self.signal = 0
        self._last = None

    def ask(self, direction: str, time_s: float) -> None:
        """The participant asks for the lane to the ``"left"`` or ``"right"``."""
        self.signal = DIRECTIONS[direction]
        self.signal_until_s = time_s + SIGNAL_S

    def request(self, time_s: float) -> None:
        """Before SUMO's step: ask SUMO for the signalled lane, or end the signal."""
        if self.signal == 0:
            return
        if time_s >= self.signal_until_s - 1e-9:
            self.signal = 0
            return
        veh = self.libsumo.vehicle
        road = veh.getRoadID(self.ego_id)
        if not road or road.startswith(":"):
            return  # inside a junction: on the next road
        target = veh.getLaneIndex(self.ego_id) + self.signal
        if not 0 <= target < self.libsumo.edge.getLaneNumber(road):
            self.signal = 0  # no lane there
            return
        veh.changeLane(self.ego_id, target, self.step_s / 2)

    def read(self, time_s: float) -> None:
        """After SUMO's step: the ego's lane, and a change if it made one."""
        veh = self.libsumo.vehicle
        lane = veh.getLaneID(self.ego_id)
        road = veh.getRoadID(self.ego_id)
        if self._last is not None and lane != self._last:
            side = self._change_side(self._last, lane)
            if side:
                self._record(time_s, side, lane)
        self._last = lane
        if not road or road.startswith(":"):
            self.view = None
            return
        index = veh.getLaneIndex(self.ego_id)
        self.view = [
            index,
            self.libsumo.edge.getLaneNumber(road),
            self.signal,
            route_side(veh.getBestLanes(self.ego_id), lane),
        ]

    def _change_side(self, before: str, after: str) -> int:
        """+1 left, -1 right if the ego changed lanes between `before` and
        `after`, 0 if it drove on: `after` follows `before` (through a
        junction's internal lane too), else the lane beside the one that
        follows on `after`'s road tells the side."""
        lane = self.libsumo.lane
        road = lane.getEdgeID(after)
        if lane.getEdgeID(before) == road:
            return 1 if _index(after) > _index(before) else -1
        followers = self._followers(before)
        if after in followers:
            return 0
        on_road = [f for f in followers if lane.getEdgeID(f) == road]
        if not on_road:
            return 0  # a jump the links do not explain (a teleport)
        return 1 if _index(after) > _index(on_road[0]) else -1

    def _followers(self, lane_id: str) -> set[str]:
        """Lanes a vehicle reaches from `lane_id` by driving on: its links'
        lanes and, past a junction's internal lane, theirs (SUMO's
        ``lane.getLinks``: approached lane, ..., internal lane, ...)."""
        if lane_id not in self._links:
            first = self._linked(lane_id)
            inside = [lane for lane in first if lane.startswith(":")]
            self._links[lane_id] = first.union(*map(self._linked, inside))
        return self._links[lane_id]

    def _record(self, time_s: float, side: int, lane: str) -> None:
        asked = side == self.signal
        self.events.append(
            {
                "time_s": round(time_s, 3),
                "kind": "lane_change",
                "other": None,
                "detail": f"{'left' if side > 0 else 'right'} to {lane}, "
                f"{'asked for' if asked else 'for the route'}",
            }
        )
        if asked:
            self.signal = 0

    def _linked(self, lane_id: str) -> set[str]:
        """The approached and internal lanes of `lane_id`'s links."""
        links = self.libsumo.lane.getLinks(lane_id)
        return {lane for link in links for lane in (link[0], link[4]) if lane}


def _index(lane_id: str) -> int:
    """The index of a lane from its id (SUMO's ``<edge>_<index>``)."""
    return int(lane_id.rsplit("_", 1)[1])


def route_side(best_lanes: Any, lane_id: str) -> int:
    """The side the ego must move to before the end of `lane_id` to stay on
    its route: -1 right, +1 left, 0 where the lane leads on to the route's
    next road. From SUMO's ``vehicle.getBestLanes``: per lane of the road,
    (lane id, length, occupation, offset to the best lane, allows
    continuation, next lanes)."""
    for lane, _, _, offset, continues, *_ in best_lanes:
        if lane == lane_id:
            return 0 if continues else max(-1, min(1, int(offset)))
    return 0
