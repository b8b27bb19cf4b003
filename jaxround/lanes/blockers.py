"""Room kept before a lane's end for a vehicle that must change the other
way: LC2013's answer to a counter-lane-change deadlock.

A vehicle whose lane ends for its route (an urgent strategic wish) may be
blocked by a vehicle beside it that wants to come the other way: each waits
for the other. In `_wantsChange`'s urgent branch SUMO has the vehicle keep
room before its lane's end for such a blocker (``myLeadingBlockerLength``,
with ``myLeftSpace`` the metres it has left), and its next `_patchSpeed`
brakes, harder than its decel if it must, to stop before that room, so
that the blocker can get past and both can change.

* `save_blocker_length`: ``MSLCHelper::saveBlockerLength`` (SUMO's 2023
  source; LC2013's own method in 2021), for the target lane's leader and
  for the first vehicle registered blocked on the own lane.
* `blocker_stop_speed`: the speed of `_patchSpeed`'s step #2, the stop
  before the kept room.

Measured on two_lane.yaml at 50% AVs (2026-12-02): at 30.5 s an AV on the
inner ring lane that must leave at the next exit, blocked by a vehicle on
the outer lane that wants the inner one, brakes from 7.06 to 3.69 m/s in
SUMO 1.28 (6.8 m/s^2, beyond its decel of 4.3), and both change in that
step; with the blocker's lane-change mode 0 (no wish to change), SUMO drives
it on at 5.89 m/s, as the step did without the room.

Not ported: when the blocker does not fit in front of ego, SUMO asks the
blocker to keep ego's room instead, and ego keeps it anyway only if the
blocker cannot (2023: ``canSaveBlockerLength`` on the blocker's own left
space) and ego's lane has no relief connection; here ego keeps it in that
case. Element-wise over (...) arrays.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.lanes import follow
from jaxround.lanes.follow import Driver
from jaxround.lanes.views import Memory, Neighbour

#: The metres `_patchSpeed` keeps between the stop and the room, besides a
#: minGap. The 2021 and 2022 sources read 1 m (``MAGIC_offset``); SUMO 1.28
#: stops 0.1 m (POSITION_EPS) before: its speed in the case below, 3.68498
#: m/s, is libsumo's ``getStopSpeed`` at ``myLeftSpace - 7.5 - 2.5 - 0.1``
#: (16.45706 - 10.1 m; with 1 m it would be 2.97 m/s).
MAGIC_OFFSET = 0.1


def save_blocker_length(
    blocker: Neighbour, *, counter: int, kept: jax.Array
) -> jax.Array:
    """``saveBlockerLength(blocker, lcaCounter)``: the room (m) the vehicle
    keeps before its lane's end after looking at ``blocker``, at least
    ``kept`` (its ``myLeadingBlockerLength`` so far).

    A blocker counts if it wants ``counter`` (the LEFT or RIGHT bit of the
    direction opposite to the vehicle's wish) in its own state as the turns
    before left it. Whether it fits in front (``lengthWithGap <= leftSpace -
    brakeGap(v, decel, 0)``) or not, the vehicle keeps its room (see the
    module's note).
    """
    wants_counter = blocker.exists & ((jnp.asarray(blocker.state) & counter) != 0)
    return jnp.where(
        wants_counter, jnp.maximum(blocker.driver.length_with_gap, kept), kept
    )


def blocker_stop_speed(
    memory: Memory, driver: Driver, v: jax.Array, v_desired: jax.Array, dt: float
) -> tuple[jax.Array, jax.Array]:
    """`_patchSpeed` step #2: the speed (M,) to stop ``MAGIC_OFFSET`` and a
    minGap before the room kept for a blocker (``stopSpeed(v, space)``), NaN
    where no room is kept or the space is used up; and the floor braking for
    it may go down to, ``minNextSpeedEmergency`` (M,).

    Args:
        memory: the last changes' ``left_space`` and ``blocker_length``.
        driver: each vehicle's car-following numbers; v: its speed (M,).
        v_desired: its `getVehicleMaxSpeed` on its lane (M,), the IDM's.
    """
    space = memory.left_space - memory.blocker_length - MAGIC_OFFSET - driver.min_gap
    keeps = (memory.blocker_length != 0) & (space > 0)
    safe = follow.stop_speed(driver, v, jnp.where(keeps, space, 1.0), v_desired, dt)
    stop = jnp.where(keeps, safe, jnp.nan)
    return stop, follow.min_next_speed_emergency(driver, v, dt)
