"""The speed a lane will allow a vehicle, as LC2013 anticipates it when it
compares its own lane with the one beside it (`MSLCM_LC2013::_wantsChange`,
the speed-gain branches). Element-wise over (...) arrays.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.lanes import follow
from jaxround.lanes.views import Ego, Neighbour


def accelerating(vehicle: Neighbour) -> jax.Array:
    """Whether SUMO sees the vehicle accelerate (``getAcceleration() > 0``).

    A vehicle that approaches its desired speed on a free road accelerates
    by ever smaller amounts, forever in SUMO's doubles; in float32 its speed
    stops a few units in the last place short of the desired speed and its
    acceleration reads 0. Such a vehicle (within 32 of those units) counts
    as accelerating, as in SUMO; in float64 the margin is negligible."""
    short = vehicle.v_max - vehicle.speed
    margin = 32 * jnp.finfo(jnp.result_type(vehicle.speed)).eps * vehicle.v_max
    stalled = (vehicle.accel == 0) & (short > 0) & (short < margin)
    return vehicle.exists & ((vehicle.accel > 0) | stalled)


def anticipate_follow_speed(
    ego: Ego, leader: Neighbour, dist: jax.Array, v_max: jax.Array,
    accelerating: jax.Array, dt: float,
) -> jax.Array:  # fmt: skip
    """`anticipateFollowSpeed`: the speed a lane will allow, capped at
    ``v_max``: with an accelerating leader in play the IDM's speed one second
    on, else the generic safe speed behind the leader (or to stop within
    ``dist``, the lane's LaneQ length)."""
    driver, v = ego.driver, ego.speed
    v_1s = v + driver.accel - driver.accel * dt
    accelerating_free = follow.follow_speed(driver, v_1s, dist, 0.0, ego.v_max, dt)
    accelerating_led = follow.follow_speed(
        driver, v_1s, leader.gap, leader.speed, ego.v_max, dt
    )
    steady_free = follow.safe_stop_speed(driver, dist, dt)
    steady_led = follow.safe_follow_speed(
        driver, leader.gap, leader.speed, leader.driver.decel, dt
    )
    led = jnp.where(accelerating, accelerating_led, steady_led)
    free = jnp.where(accelerating, accelerating_free, steady_free)
    return jnp.minimum(v_max, jnp.where(leader.exists, led, free))
