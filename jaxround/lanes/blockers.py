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

Ego keeps the room only where the blocker fits in front of it: its
lengthWithGap and a minGap within ego's left space less POSITION_EPS and
ego's braking distance (measured on SUMO 1.28). At 38.5 s of the same hour
an AV with 11.09 m left, at 5.55 m/s (2.33 m to brake), keeps no room for
a 5 m human driver beside it that wants its lane: it slows to 4.0755 m/s,
as it does with the blocker's lane-change mode 0, where keeping the room
gives 3.40; with the blocker shortened by libsumo's ``setLength`` it keeps
the room up to a length of 3.6 m and not from 3.7 m on, where the sources
read (2021-2023), without the minGap, would keep it up to 6.16 m or 6.26 m.

Not ported: a blocker that does not fit is asked to keep ego's room
instead (``saveBlockerLength(length)`` on the blocker), which counts only
where the blocker's own wish is urgent; SUMO 1.28 did not keep the room
for ego in the case above, as the 2023 source would have. Element-wise
over (...) arrays.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core.junction import brake_gap as euler_brake_gap
from jaxround.lanes import follow
from jaxround.lanes.follow import Driver
from jaxround.lanes.views import Memory, Neighbour

#: The metres `_patchSpeed` keeps between the stop and the room, besides a
#: minGap. The 2021 and 2022 sources read 1 m (``MAGIC_offset``); SUMO 1.28
#: stops 0.1 m (POSITION_EPS) before: its speed in the case below, 3.68498
#: m/s, is libsumo's ``getStopSpeed`` at ``myLeftSpace - 7.5 - 2.5 - 0.1``
#: (16.45706 - 10.1 m; with 1 m it would be 2.97 m/s).
MAGIC_OFFSET = 0.1
#: SUMO's ``POSITION_EPS`` (m).
POSITION_EPS = 0.1


def save_blocker_length(
    blocker: Neighbour,
    *,
    counter: int,
    kept: jax.Array,
    ego: Driver,
    v: jax.Array,
    left_space: jax.Array,
    dt: float,
) -> jax.Array:
    """``saveBlockerLength(blocker, lcaCounter)``: the room (m) the vehicle
    keeps before its lane's end after looking at ``blocker``, at least
    ``kept`` (its ``myLeadingBlockerLength`` so far).

    A blocker counts if it wants ``counter`` (the LEFT or RIGHT bit of the
    direction opposite to the vehicle's wish) in its own state as the turns
    before left it, and fits in front: its lengthWithGap and ego's minGap
    within ``left_space - POSITION_EPS - brakeGap(v, decel, 0)`` (the
    module's note). ``ego``, ``v``: the vehicle's numbers and speed.
    """
    wants_counter = blocker.exists & ((jnp.asarray(blocker.state) & counter) != 0)
    brake = euler_brake_gap(v, ego.decel, 0.0, dt)
    potential = left_space - POSITION_EPS - brake - ego.min_gap
    fits = blocker.driver.length_with_gap <= potential
    return jnp.where(
        wants_counter & fits, jnp.maximum(blocker.driver.length_with_gap, kept), kept
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
