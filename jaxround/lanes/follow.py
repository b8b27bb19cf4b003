"""The car-following quantities LC2013 asks of a vehicle's IDM (Euler update).

`MSLCM_LC2013` never integrates the IDM itself: it asks the car-following
model for a secure gap, a brake gap, the speed a leader or a stop allows.
These are SUMO's answers for the IDM (`MSCFModel_IDM` where it overrides
`MSCFModel`), element-wise over arrays of vehicles.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from jaxround.core import command, idm
from jaxround.core.junction import brake_gap as euler_brake_gap


class Driver(NamedTuple):
    """A vehicle's car-following numbers; scalars or arrays of one shape (...).

    Attributes:
        accel, decel, emergency_decel: m/s^2 [accel, decel, emergencyDecel].
        tau: time headway (s) [tau].
        min_gap, length: m [minGap, length].
        delta: IDM exponent [delta].
        max_speed: the vType's top speed (m/s) [maxSpeed].
    """

    accel: ArrayLike
    decel: ArrayLike
    emergency_decel: ArrayLike
    tau: ArrayLike
    min_gap: ArrayLike
    length: ArrayLike
    delta: ArrayLike
    max_speed: ArrayLike

    @property
    def idm(self) -> idm.IDMParams:
        return idm.IDMParams(self.accel, self.decel, self.tau, self.min_gap, self.delta)

    @property
    def length_with_gap(self) -> jax.Array:
        return jnp.asarray(self.length) + self.min_gap


def secure_gap(driver: Driver, v: ArrayLike, v_leader: ArrayLike) -> jax.Array:
    """`MSCFModel_IDM::getSecureGap`: the IDM's desired gap without minGap,
    ``max(0, v tau + v (v - v_leader) / (2 sqrt(a b)))``."""
    two_sqrt_ab = 2.0 * jnp.sqrt(jnp.asarray(driver.accel) * driver.decel)
    return jnp.maximum(0.0, v * driver.tau + v * (v - v_leader) / two_sqrt_ab)


def brake_gap(driver: Driver, v: ArrayLike, dt: float) -> jax.Array:
    """`MSCFModel::brakeGap(v)`: stepwise braking at decel, plus ``v tau``."""
    return euler_brake_gap(
        jnp.asarray(v, dtype=jnp.result_type(float, v)), driver.decel, driver.tau, dt
    )


def safe_stop_speed(driver: Driver, gap: ArrayLike, dt: float) -> jax.Array:
    """`MSCFModel::maximumSafeStopSpeed` on insertion (Euler): the fastest
    speed from which the vehicle stops within ``gap``, reacting after tau."""
    return idm.maximum_safe_stop_speed_euler(gap, driver.decel, driver.tau, dt)


def safe_follow_speed(
    driver: Driver,
    gap: ArrayLike,
    v_leader: ArrayLike,
    leader_decel: ArrayLike,
    dt: float,
) -> jax.Array:
    """`MSCFModel::maximumSafeFollowSpeed(..., onInsertion=true)`: stop
    behind a leader that brakes at ``max(decel, leader_decel)`` from now on
    (the generic safe speed, not the IDM's; LC2013 compares lanes with it)."""
    leader_brake = euler_brake_gap(
        jnp.asarray(v_leader, dtype=jnp.result_type(float, v_leader)),
        jnp.maximum(driver.decel, leader_decel),
        0.0,
        dt,
    )
    return safe_stop_speed(driver, jnp.asarray(gap) + leader_brake, dt)


def follow_speed(
    driver: Driver,
    v: ArrayLike,
    gap: ArrayLike,
    v_leader: ArrayLike,
    v_desired: ArrayLike,
    dt: float,
) -> jax.Array:
    """`MSCFModel_IDM::followSpeed`: the IDM's speed behind a leader
    ``gap`` ahead (SUMO's gap2pred: net of the follower's minGap)."""
    return idm.idm_follow_speed(
        v, v_leader, jnp.asarray(gap) + driver.min_gap, v_desired,
        vtype=driver.idm, dt=dt, n_substeps=idm.idm_substeps(dt),
    )  # fmt: skip


def stop_speed(
    driver: Driver, v: ArrayLike, gap: ArrayLike, v_desired: ArrayLike, dt: float
) -> jax.Array:
    """`MSCFModel_IDM::stopSpeed`: the IDM's speed to stop ``gap`` ahead."""
    return idm.idm_stop_speed(
        v, gap, v_desired, vtype=driver.idm, dt=dt, n_substeps=idm.idm_substeps(dt)
    )


def min_next_speed(driver: Driver, v: ArrayLike, dt: float) -> jax.Array:
    """`MSCFModel_IDM::minNextSpeed`: braking at most at
    ``max(decel, min(emergencyDecel, 1.5))`` in one step, not below 0
    (`jaxround.core.command.min_next_speed`, which reads the same two
    fields)."""
    return command.min_next_speed(jnp.asarray(v), driver, dt)


def min_next_speed_emergency(driver: Driver, v: ArrayLike, dt: float) -> jax.Array:
    """`MSCFModel::minNextSpeedEmergency`: braking at emergencyDecel for
    one step, not below 0."""
    return jnp.maximum(0.0, jnp.asarray(v) - driver.emergency_decel * dt)
