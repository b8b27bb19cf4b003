"""The bounds SUMO 1.28 puts on a vehicle's next speed, in JAX.

* ``MSCFModel::finalizeSpeed`` with ``MSCFModel_IDM::minNextSpeed``: the
  acceleration / deceleration / emergency bounds (:func:`finalize_speed`).
* ``MSVehicle::executeMove``: speeds below ``0.1 * NUMERICAL_EPS * dt`` become
  exactly 0 (:func:`snap_speed`; :func:`next_speed` = finalize + snap).
* Action steps longer than the simulation step (:func:`hold_or_update`).

Element-wise over arrays of vehicles, like :mod:`jaxround.core.idm`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from jaxround.core.idm import NUMERICAL_EPS

__all__ = [
    "finalize_speed", "hold_or_update", "next_speed", "snap_speed", "speed_bounds",
]  # fmt: skip


def finalize_speed(
    v: ArrayLike,
    v_safe: ArrayLike,
    v_lane: ArrayLike,
    *,
    accel: ArrayLike,
    decel: ArrayLike,
    emergency_decel: ArrayLike,
    dt: ArrayLike,
    action_step: ArrayLike,
) -> jax.Array:
    """SUMO's ``MSCFModel::finalizeSpeed`` for the IDM (Euler update, no dawdle).

    ::

        vMax = min(v + accel*dt, v + (v_lane - v)*dt/action_step, v_safe)
        vMin = min(max(0, v - decel'*dt), max(v_safe, v - emergency_decel*dt, 0))
        v_next = max(vMin, vMax)

    with ``decel' = max(decel, min(emergency_decel, 1.5))``
    (``MSCFModel_IDM::minNextSpeed``; equal to ``decel`` for any decel >= 1.5).
    ``v_safe`` is the minimum over all constraints (leader, free road, stops,
    junctions). The vType ``maxSpeed`` cap of ``maxNextSpeed`` is implied by
    ``v_lane <= maxSpeed`` and left out. Measured in SUMO 1.28 (lane limit
    dropped below the current speed via TraCI): the lane term uses ``v_lane``
    itself; a variant with ``max(v_lane, v_safe)`` there is off by up to
    1.2 m/s. Speeds above the new limit are shed at most at ``decel'``.

    Args:
        v: (...) current speed (m/s).
        v_safe: (...) safe speed from the car-following constraints (m/s).
        v_lane: (...) ``getVehicleMaxSpeed``: lane limit * speedFactor, capped
            by the vType maxSpeed (m/s).
        accel: (...) vType accel.
        decel: (...) vType decel.
        emergency_decel: (...) vType emergencyDecel (default 9 m/s^2).
        dt: simulation step length (s).
        action_step: action step length (s), >= dt.

    Returns:
        (...) the speed at the end of the step.
    """
    v_min, v_max = speed_bounds(
        v, v_safe, v_lane, accel=accel, decel=decel, emergency_decel=emergency_decel,
        dt=dt, action_step=action_step,
    )  # fmt: skip
    return jnp.maximum(v_min, v_max)


def speed_bounds(
    v: ArrayLike,
    v_safe: ArrayLike,
    v_lane: ArrayLike,
    *,
    accel: ArrayLike,
    decel: ArrayLike,
    emergency_decel: ArrayLike,
    dt: ArrayLike,
    action_step: ArrayLike,
) -> tuple[jax.Array, jax.Array]:
    """`finalize_speed`'s ``(vMin, vMax)`` before ``vMax = max(vMin, vMax)``:
    the bounds ``MSCFModel::finalizeSpeed`` hands the lane-change model's
    ``patchSpeed`` (`jaxround.lanes.memory.patch_speed`). Arguments as
    `finalize_speed`'s; (...) each."""
    v = jnp.asarray(v, dtype=jnp.result_type(float, v))
    min_decel = jnp.maximum(decel, jnp.minimum(emergency_decel, 1.5))
    v_min_emergency = jnp.maximum(0.0, v - emergency_decel * dt)
    v_min = jnp.minimum(
        jnp.maximum(0.0, v - min_decel * dt), jnp.maximum(v_safe, v_min_emergency)
    )
    v_max = jnp.minimum(
        jnp.minimum(v + accel * dt, v + (v_lane - v) * dt / action_step), v_safe
    )
    return v_min, v_max


def snap_speed(v_next: ArrayLike, dt: ArrayLike) -> jax.Array:
    """The last touch of ``MSVehicle::executeMove`` on the next speed (Euler).

    SUMO sets speeds below ``NUMERICAL_EPS_SPEED = 0.1 * NUMERICAL_EPS * dt``
    (5e-5 m/s at dt 0.5) to exactly 0, so that a vehicle creeping towards a
    standing leader really stops, and floors the speed at 0.

    Args:
        v_next: (...) speed from :func:`finalize_speed` (or a held acceleration).
        dt: simulation step length (s).

    Returns:
        (...) the speed SUMO stores for the end of the step.
    """
    v_next = jnp.asarray(v_next, dtype=jnp.result_type(float, v_next))
    v_next = jnp.where(jnp.abs(v_next) < 0.1 * NUMERICAL_EPS * dt, 0.0, v_next)
    return jnp.maximum(v_next, 0.0)


def next_speed(
    v: ArrayLike,
    v_safe: ArrayLike,
    v_lane: ArrayLike,
    *,
    accel: ArrayLike,
    decel: ArrayLike,
    emergency_decel: ArrayLike,
    dt: ArrayLike,
    action_step: ArrayLike,
) -> jax.Array:
    """Speed at the end of an action step: :func:`snap_speed` of :func:`finalize_speed`.

    Args:
        v: (...) current speed (m/s).
        v_safe: (...) minimum of all safe speeds (m/s).
        v_lane: (...) ``getVehicleMaxSpeed`` on the current lane (m/s).
        accel: (...) vType accel.
        decel: (...) vType decel.
        emergency_decel: (...) vType emergencyDecel.
        dt: simulation step length (s).
        action_step: action step length (s).

    Returns:
        (...) the speed SUMO reports after the step.
    """
    v_fin = finalize_speed(
        v, v_safe, v_lane, accel=accel, decel=decel, emergency_decel=emergency_decel,
        dt=dt, action_step=action_step,
    )  # fmt: skip
    return snap_speed(v_fin, dt)


def hold_or_update(
    step_index: ArrayLike,
    action_every: int | ArrayLike,
    v: ArrayLike,
    v_new: ArrayLike,
    held_accel: ArrayLike,
    dt: ArrayLike,
) -> tuple[jax.Array, jax.Array]:
    """Action points: take the new speed, otherwise keep the last acceleration.

    With ``actionStepLength = action_every * dt`` a SUMO vehicle only plans at
    its action points; in between ``MSVehicle::executeMove`` continues with the
    acceleration of the previous step (``v + accel*dt``, no car following, no
    finalizeSpeed). The result goes through :func:`snap_speed`, and the
    acceleration to hold is the one realised, ``(v_next - v) / dt`` (SUMO's
    ``updateState``), so it becomes ``-v/dt`` when the speed hits 0. Which steps
    are action points depends on the departure time in SUMO; ``step_index``
    should count steps since the vehicle's insertion.

    Caveat: SUMO switches to the ballistic position update by itself when
    ``actionStepLength > step-length`` (unless ``--step-method.ballistic false``
    is given); these functions only cover the Euler update.

    Args:
        step_index: (...) integer step count since insertion.
        action_every: action step length in steps (>= 1).
        v: (...) current speed (m/s).
        v_new: (...) :func:`finalize_speed` result planned at this step (m/s).
        held_accel: (...) acceleration of the previous step (m/s^2).
        dt: simulation step length (s).

    Returns:
        (v_next, accel): (...) speed at the end of the step and the acceleration
        realised in it.
    """
    v = jnp.asarray(v, dtype=jnp.result_type(float, v))
    is_action = jnp.asarray(step_index) % action_every == 0
    v_next = snap_speed(jnp.where(is_action, v_new, v + held_accel * dt), dt)
    return v_next, (v_next - v) / dt
