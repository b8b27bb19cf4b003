"""TraCI speed commands as SUMO 1.28 applies them to a vehicle.

A controller (`sumo_export.controller.PolicyController`) sends each AV
``vehicle.setSpeed(id, v_cmd)`` after a step; the command holds for the next
one. SUMO applies it twice in that step, both times through
``MSVehicle::Influencer::influenceSpeed`` (src/microsim/MSVehicle.cpp) under
the default speed mode 31:

1. ``MSVehicle::planMoveInternal`` starts planning from
   ``v = min(maxNextSpeed, laneMaxV)`` and lets the command replace it:
   ``max(min(v_cmd, v, maxNextSpeed), minNextSpeed)``. Every look-ahead speed
   of the step starts from there: the speeds and times a vehicle registers
   at the links ahead (``setApproachingForAllLinks``), its request, and the
   arrival its own entry is tested with (``MSLink::opened``).
2. ``MSVehicle::executeMove`` -> ``processTraCISpeedControl(vSafe, vNext)``
   replaces the car-following model's next speed with the command, clamped
   the same way: ``max(min(v_cmd, vSafe, maxNextSpeed), minNextSpeed)``. The
   lower clamp comes last, so a commanded vehicle never brakes harder than
   ``minNextSpeed`` allows, where its own model could brake at
   ``emergencyDecel``.

``minNextSpeed`` is ``MSCFModel_IDM::minNextSpeed``:
``max(v - decel' * dt, 0)`` with ``decel' = max(decel, min(emergencyDecel, 1.5))``.

Shapes: (...) any, usually (M,) vehicle slots. A NaN command means "no
command" (the vehicle drives its own model, as after ``setSpeed(id, -1)``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core.params import CarFollowing


def min_next_speed(speed: jax.Array, params: CarFollowing, dt: float) -> jax.Array:
    """``MSCFModel_IDM::minNextSpeed`` (Euler update), float (...)."""
    decel = jnp.maximum(params.decel, jnp.minimum(params.emergency_decel, 1.5))
    return jnp.maximum(speed - decel * dt, 0.0)


def max_next_speed(speed: jax.Array, params: CarFollowing, dt: float) -> jax.Array:
    """``MSCFModel::maxNextSpeed``: ``min(v + accel * dt, maxSpeed)``, float (...)."""
    return jnp.minimum(speed + params.accel * dt, params.max_speed)


def influence_speed(
    command: jax.Array,
    v_model: jax.Array,
    v_safe: jax.Array,
    v_max: jax.Array,
    v_min: jax.Array,
) -> jax.Array:
    """``Influencer::influenceSpeed`` with speed mode 31, float (...).

    Args:
        command: (...) the commanded speed, NaN where there is none.
        v_model: (...) the speed without a command (returned where NaN).
        v_safe: (...) the safe speed (bit 1 of the speed mode).
        v_max: (...) ``maxNextSpeed`` (bit 2).
        v_min: (...) ``minNextSpeed`` (bit 4; applied last, so it wins).
    """
    clamped = jnp.maximum(jnp.minimum(jnp.minimum(command, v_safe), v_max), v_min)
    return jnp.where(jnp.isnan(command), v_model, clamped)


def commanded_speed(
    speed: jax.Array, accel: jax.Array, params: CarFollowing, dt: float
) -> jax.Array:
    """The speed a controller commands for an acceleration, float (...).

    ``v + clip(a, -decel, accel) * dt``, at least ``max(v - decel * dt, 0)``:
    what `sumo_export.controller.commanded_speed` sends to SUMO. A NaN
    acceleration gives a NaN command (none).
    """
    a = jnp.clip(accel, -params.decel, params.accel)
    v = jnp.maximum(speed + a * dt, jnp.maximum(speed - params.decel * dt, 0.0))
    return jnp.where(jnp.isnan(accel), jnp.nan, v)
