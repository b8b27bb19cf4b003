"""What one vehicle sees when it considers a lane change, and what it keeps.

LC2013 decides from a handful of numbers per vehicle: its own speed and
place, the leader on its lane, the leader and follower on the lane it looks
at, and SUMO's `MSVehicle::LaneQ` of both lanes. The geometry (a straight
road, a ring) gathers them; `jaxround.lanes.lc2013` only reads them. All
fields are scalars or arrays of one shape (...).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from jaxround.core.reductions import first_min
from jaxround.lanes.follow import Driver

#: How many speed advices a vehicle can hold for its next step.
N_ADVICES = 8


class Ego(NamedTuple):
    """The deciding vehicle.

    Attributes:
        speed: m/s after this step's move.
        accel: the acceleration of this step's move (m/s^2).
        pos: front position on its lane (m).
        driver: its car-following numbers.
        v_max: `getVehicleMaxSpeed` on its lane (m/s).
        neigh_v_max: the same on the lane it looks at (m/s).
        speed_limit: its lane's speed limit (m/s).
        lane_length: its lane's length (m).
    """

    speed: jax.Array
    accel: jax.Array
    pos: jax.Array
    driver: Driver
    v_max: jax.Array
    neigh_v_max: jax.Array
    speed_limit: jax.Array
    lane_length: jax.Array


class Neighbour(NamedTuple):
    """A leader or follower as `MSLaneChanger` hands it over
    (`std::pair<MSVehicle*, double>`).

    Attributes:
        exists: bool, whether there is one.
        gap: m, net of the follower's minGap (SUMO's ``.second``); < 0 overlaps.
        speed, accel: its speed (m/s) and last acceleration (m/s^2).
        driver: its car-following numbers.
        v_max: its `getVehicleMaxSpeed` on its own lane (m/s).
        state: its `myOwnState` as the turns before left it (int32 bits;
            `saveBlockerLength` reads its wish).
    """

    exists: jax.Array
    gap: jax.Array
    speed: jax.Array
    accel: jax.Array
    driver: Driver
    v_max: jax.Array
    state: jax.Array | int = 0


class LaneQ(NamedTuple):
    """SUMO's `MSVehicle::LaneQ` of one lane of the vehicle's edge.

    Attributes:
        length: metres the vehicle can drive along its route from the lane's
            start without changing lanes.
        best_lane_offset: lanes to the nearest lane that goes furthest (+ left).
        occupation: metres of vehicles (length + minGap) ahead on its
            continuation.
        ends_in_links: whether the last lane of its continuation has links on
            (SUMO: ``bestContinuations.back()->getLinkCont().size() != 0``).
    """

    length: jax.Array
    best_lane_offset: jax.Array
    occupation: jax.Array
    ends_in_links: jax.Array


@struct.dataclass
class Memory:
    """What LC2013 keeps of a vehicle between steps. Shapes (M,) unless said.

    Attributes:
        state: int32 `myOwnState`, `jaxround.lanes.actions` bits.
        speed_gain_probability: `mySpeedGainProbability` (> 0: left).
        keep_right_probability: `myKeepRightProbability` (<= 0).
        look_ahead_speed: `myLookAheadSpeed` (m/s).
        advices: (M, N_ADVICES) `myLCAccelerationAdvices` as next speeds
            (m/s, NaN: empty), for the next step's `patchSpeed`.
        left_space: `myLeftSpace`, the metres an urgent wish has left on
            its lane (0: none this step).
        blocker_length: `myLeadingBlockerLength`, the room (m) it keeps
            before that end for a vehicle that wants the other way
            (`jaxround.lanes.blockers`; 0: none).
    """

    state: jax.Array
    speed_gain_probability: jax.Array
    keep_right_probability: jax.Array
    look_ahead_speed: jax.Array
    advices: jax.Array
    left_space: jax.Array
    blocker_length: jax.Array

    @classmethod
    def zeros(cls, n_slots: int) -> Memory:
        zero = jnp.zeros(n_slots, jnp.result_type(float))
        return cls(
            state=jnp.zeros(n_slots, jnp.int32),
            speed_gain_probability=zero,
            keep_right_probability=zero,
            look_ahead_speed=zero,
            advices=jnp.full((n_slots, N_ADVICES), jnp.nan, jnp.result_type(float)),
            left_space=zero,
            blocker_length=zero,
        )


def push_advice(advices: jax.Array, speed: jax.Array) -> jax.Array:
    """`addLCSpeedAdvice`: ``speed`` into the first empty slot of (A,)
    ``advices`` (NaN ``speed``: nothing; a full row keeps its A smallest)."""
    n = advices.shape[0]
    empty = jnp.isnan(advices)
    # the first empty slot, else the first largest advice (as jnp.argmax, in
    # two one-operand reductions: `jaxround.core.reductions`)
    first_empty = jnp.min(jnp.where(empty, jnp.arange(n), n))
    full = first_empty == n
    _, largest = first_min(jnp.where(empty, jnp.inf, -advices))
    slot = jnp.where(full, largest, first_empty)
    keep = jnp.isnan(speed) | (full & (speed >= advices[slot]))
    return jnp.where(keep, advices, advices.at[slot].set(speed))
