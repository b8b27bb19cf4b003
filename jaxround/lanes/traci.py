"""A lane request sent by TraCI (`vehicle.changeLane`), as SUMO 1.28 weighs
it against LC2013's own wishes under the default lane-change mode 1621.

`MSVehicle::Influencer::influenceChangeDecision`: while a request for lane
index i is active, it asks to go RIGHT, LEFT or HOLD by the lane the
vehicle is on (nothing where i is not a lane of its edge). Mode 1621
(`setLaneChangeMode`: strategic, cooperative, speed gain and keep right
`LC_NOCONFLICT`, TraCI priority ``(1621 >> 8) & 3`` = 2, `LCP_URGENT`:
"change if not blocked, adapt own speed and speed of blockers") cancels a
model wish that conflicts with the request (its direction or STAY, and its
urgency), adds the request (`LCA_TRACI` and the direction, `LCA_URGENT`
too unless it is HOLD: SUMO's lane-change output reads ``traci|urgent``)
and keeps the blocked bits: the change happens only where SUMO's safety
checks allow it, and a blocked one negotiates as an urgent strategic
change does (LC2013's urgent branch, with the request's remaining time).
Where SUMO asks (three places per look) is docs/lc2013-map.md section 13;
`jaxround.lanes.lc2013.wants_change` and `jaxround.lanes.decide.turn_of`
ask there.

Everything is element-wise over arrays of one shape (...).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.lanes import actions as lca

#: `MSVehicle::ChangeRequest`, as the changers carry it.
NONE, RIGHT, LEFT, HOLD = 0, -1, 1, 2
#: No lane requested (a vehicle's ``lane_request``).
NO_LANE = -1
#: How long a request is sent for, in steps: ``changeLane(id, i, 0.5 dt)``
#: after step t is weighed in step t + 1's lane-change phase (remaining
#: 0.5 dt, LC2013's time to negotiate an urgent change) and gone by the
#: next. (A request for a whole dt would still hold, with 0 s remaining,
#: in the phase after: ``influenceChangeDecision`` drops a request only
#: once the time is past its end.)
REQUEST_STEPS = 0.5


def change_request(
    lane_request: jax.Array, lane_index: jax.Array, n_lanes: jax.Array
) -> jax.Array:
    """The request of a vehicle asking for lane index ``lane_request``
    (`NO_LANE`: none) on lane ``lane_index`` of an edge of ``n_lanes``."""
    asked = (lane_request >= 0) & (lane_request < n_lanes)
    left = jnp.where(lane_index < lane_request, LEFT, HOLD)
    way = jnp.where(lane_index > lane_request, RIGHT, left)
    return jnp.where(asked, way, NONE).astype(jnp.int32)


def influence(state: jax.Array, request: jax.Array) -> jax.Array:
    """`influenceChangeDecision` under mode 1621: ``state`` (int bits) with
    the request applied (`NONE` leaves it as it is).

    A wish whose only reason is an earlier request (`LCA_TRACI`) falls to
    `LC_NEVER` and is cancelled before the request is added again. (SUMO
    does that for a reasonless wish without a request too, where the
    vehicle has an influencer; LC2013 gives none.)"""
    state = jnp.asarray(state, jnp.int32)
    active = request != NONE
    wants = (state & (lca.WANTS_LANECHANGE | lca.STAY)) != 0
    reasons = lca.STRATEGIC | lca.COOPERATIVE | lca.SPEEDGAIN | lca.KEEPRIGHT
    no_reason = (state & reasons) == 0
    conflict = no_reason | (
        (((state & lca.LEFT) != 0) & (request != LEFT))
        | (((state & lca.RIGHT) != 0) & (request != RIGHT))
        | (((state & lca.STAY) != 0) & (request != HOLD))
    )
    cancelled = jnp.where(
        active & wants & conflict,
        state & ~(lca.WANTS_LANECHANGE | lca.STAY | lca.URGENT),
        state,
    )
    way = jnp.where(
        request == LEFT, lca.LEFT, jnp.where(request == RIGHT, lca.RIGHT, lca.STAY)
    )
    urgent = jnp.where(request == HOLD, 0, lca.URGENT)  # not LCP_OPPORTUNISTIC
    asked = cancelled | lca.TRACI | way | urgent
    return jnp.where(active, asked, state).astype(jnp.int32)


def cancels(state: jax.Array, request: jax.Array) -> jax.Array:
    """`MSAbstractLaneChangeModel::cancelRequest`: whether the request
    changes a wish (then LC2013 drops it and goes on to its next reason)."""
    return influence(state, request) != state
