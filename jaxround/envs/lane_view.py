"""The AVs' lane action and what an AV sees of the lanes beside it.

The lane action (``action[:, 1]``, the paper's Eq. 2 change-lane decision
generalised): above 0.5 asks for the lane to the left, below -0.5 for the
lane to the right, anything between holds the AV's lane, and NaN asks
nothing (LC2013 decides, as for an uncontrolled AV). A trained network
sends NaN, left or right (three lane choices, on two-lane roads), or NaN
and left (the paper's binary decision, on one-lane roads;
`agents.common.networks.lane_column`). It is sent as SUMO's controller sends
it (`sumo_export.controller`): ``vehicle.changeLane(id, index + d, dt / 2)``
with d in {-1, 0, +1} and the index of the lane the AV is on when it is
commanded, for the next lane-change phase only
(`jaxround.lanes.traci.REQUEST_STEPS`), only where that edge has the lane
asked for (a hold: where the edge has two lanes), under SUMO's default
lane-change mode 1621, and only off junctions: not from an AV on an
internal (junction) lane, nor from one whose move could carry it onto one
(its position on its lane plus ``(v + accel * dt) * dt``, the farthest it
can go in the step, at least the lane's length). SUMO changes lanes on the
ring's through internal edges too (``MSEdge::allowsLaneChanging``), and
there its safety checks do not see a vehicle on the other internal lane
that leaves the same ring lane (the exit's): requests sent there ran AVs
into such vehicles beside them (docs/two_lane.md). The request is urgent
and cancels an LC2013 wish it conflicts with (a hold cancels every
change, an AV's own strategic change to reach its exit too), but keeps
LC2013's safety checks (`jaxround.lanes.traci`). SUMO weighs it in the next
step's lane-change phase, after the move
(``MSVehicle::Influencer::influenceChangeDecision`` in ``MSLaneChanger``),
and so does `jaxround.envs.lane_changes.LaneChanger`.

The ``"lanes"`` observer is the ``"rich"`` one and `LANE_COLUMNS`: the
index of the AV's lane on its edge; how far its own lane path goes on (a
path on the inner ring lane ends where the vehicle must leave it for its
exit) and those to the right and to the left from beside it (0 where no
change is possible there); and the gaps to the next vehicle ahead on its
own lane path and on those to the right and left (the back of any vehicle
whose front is on a lane of that path, lane for lane); all over
`DISTANCE_SCALE` and at most 1. On one-lane roads the AV's lane is 0,
nothing is beside it (no room either) and its own gap is the rich
observer's leader gap.

Shapes: M vehicle slots.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core.geometry import NetArrays
from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs import observe
from jaxround.envs.observe import DISTANCE_SCALE
from jaxround.lanes.paths import LEFT, RIGHT
from jaxround.lanes.ring_changer import locate
from jaxround.lanes.ring_neighbours import RingArrays

#: Columns the ``"lanes"`` observer adds after the rich observer's 17.
LANE_COLUMNS = (
    "lane_index", "room_own", "room_right", "room_left",
    "gap_own", "gap_right", "gap_left",
)  # fmt: skip
#: Column of each lane number in the ``"lanes"`` observation.
LANE_INDEX, ROOM_OWN, ROOM_RIGHT, ROOM_LEFT, GAP_OWN, GAP_RIGHT, GAP_LEFT = range(
    17, 24
)
#: The lane column's values: ask for the lane to the left, hold, to the right.
LEFT_LANE, HOLD_LANE, RIGHT_LANE = 1.0, 0.0, -1.0
#: The rich observer's leader gap column (`jaxround.envs.scripted.LEADER_GAP`).
_RICH_LEADER_GAP = 11


def lane_direction(lane_action: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(asked bool (M,), direction int (M,) +1 left, 0 hold, -1 right) of the
    action's lane column; NaN asks nothing."""
    left = jnp.where(lane_action > 0.5, 1, 0)
    direction = jnp.where(lane_action < -0.5, -1, left).astype(jnp.int32)
    return ~jnp.isnan(lane_action), direction


def lane_request(
    net: RingArrays,
    state: EnvState,
    lane_action: jax.Array,
    agent: jax.Array,
    reach: jax.Array,
) -> jax.Array:
    """int (M,) the lane index each AV asks for this step (-1: none).

    Args:
        net: the lane changer's arrays.
        state: the state at the start of the step (before the move).
        lane_action: float (M,) the action's lane column.
        agent: bool (M,) the slots that hold an AV.
        reach: float (M,) the farthest each vehicle can move in the step (m):
            a request is sent only where that keeps it off a junction.
    """
    _, lane, on_lane = locate(net, state.route, state.pos)
    asked, direction = lane_direction(lane_action)
    right, left = net.lane_side[lane, RIGHT] >= 0, net.lane_side[lane, LEFT] >= 0
    exists = jnp.where(
        direction > 0, left, jnp.where(direction < 0, right, left | right)
    )
    off_junction = ~net.lane_internal[lane] & (on_lane + reach < net.lane_length[lane])
    asked = agent & asked & exists & off_junction
    return jnp.where(asked, net.lane_index[lane] + direction, -1).astype(jnp.int32)


def lane_numbers(
    net: RingArrays, path_length: jax.Array, state: EnvState, params: EnvParams
) -> jax.Array:
    """float (M, 7) the `LANE_COLUMNS` of every slot (0 for empty slots);
    ``path_length`` float (P,) each lane path's length (the step's
    ``NetArrays.route_length``: its routes are the lane paths)."""
    k, lane, on_lane = locate(net, state.route, state.pos)
    path, active = state.route, state.active
    # every vehicle's front along any path, nan where that path lacks its lane
    front = net.lane_offset[:, lane] + on_lane[None, :]  # (P, M)
    front = jnp.where(active[None, :], front, jnp.nan)
    back = front - params.vehicle.length
    m = path.shape[0]
    columns = []
    for side in (None, RIGHT, LEFT):
        q = path if side is None else net.change_path[path, k, side]
        has = (q >= 0) & active
        q = jnp.maximum(q, 0)
        here = net.path_lanes[q, k]
        own_front = net.lane_offset[q, here] + on_lane  # (M,)
        ahead = front[q] > own_front[:, None]  # (M, M), nan compares false
        ahead = ahead & ~jnp.eye(m, dtype=bool)
        gap = jnp.min(jnp.where(ahead, back[q] - own_front[:, None], jnp.inf), axis=1)
        gap = jnp.where(has, jnp.minimum(gap / DISTANCE_SCALE, 1.0), 0.0)
        room = path_length[q] - own_front
        room = jnp.where(has, jnp.clip(room / DISTANCE_SCALE, 0.0, 1.0), 0.0)
        columns.append((gap, room))
    (gap_own, room_own), (gap_right, room_right), (gap_left, room_left) = columns
    index = jnp.where(active, net.lane_index[lane], 0).astype(gap_own.dtype)
    return jnp.stack(
        [index, room_own, room_right, room_left, gap_own, gap_right, gap_left],
        axis=-1,
    )


def lanes_observation(
    rich: jax.Array,
    net: RingArrays | None,
    path_length: jax.Array,
    state: EnvState,
    params: EnvParams,
) -> jax.Array:
    """The ``"lanes"`` observer's rows, float (M, 24): ``rich`` (M, 17) and
    the `LANE_COLUMNS` (`lane_numbers`); ``net`` None on one-lane roads (no
    room counted there: a one-lane road has no lane to change to)."""
    if net is None:
        zero = jnp.zeros_like(rich[:, :1])
        own_gap = rich[:, _RICH_LEADER_GAP : _RICH_LEADER_GAP + 1]
        lanes = jnp.concatenate([zero, zero, zero, zero, own_gap, zero, zero], axis=1)
    else:
        lanes = lane_numbers(net, path_length, state, params).astype(rich.dtype)
    return jnp.concatenate([rich, lanes], axis=1)


def observation_by_name(
    observer: str,
    net: NetArrays,
    lanes: RingArrays | None,
    state: EnvState,
    params: EnvParams,
    route_destination: jax.Array,
) -> jax.Array:
    """The rows of the observer named ``observer``, float (M, D)
    (`jaxround.envs.observe.OBSERVATION_SIZES`); ``lanes`` the lane
    changer's arrays (None on one-lane roads)."""
    if observer == "paper":
        return observe.paper_observation(net, state, params)[0]
    rich = observe.rich_observation(net, state, params, route_destination)
    if observer == "rich":
        return rich
    return lanes_observation(rich, lanes, net.route_length, state, params)
