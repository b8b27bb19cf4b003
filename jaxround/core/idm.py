"""SUMO 1.28's Intelligent Driver Model (``carFollowModel="IDM"``) in JAX.

Every function here is pure, element-wise over arrays of vehicles (all array
arguments broadcast against each other), free of Python control flow on traced
values, and so usable under ``jax.jit``, ``jax.vmap`` and ``jax.grad``. The
only static argument is the number of IDM sub-steps ``n_substeps`` (a Python
``int``, see :func:`idm_substeps`); a traced integer also works, through a
``lax.fori_loop`` (not reverse-differentiable then).

The formulas follow SUMO's source:

* ``MSCFModel_IDM::_v``: the IDM acceleration integrated over one simulation
  step in ``n = max(1, int(dt / 0.25 + 0.5))`` Euler sub-steps, with the leader
  speed held constant and the gap shrinking by the closing speed of each
  sub-step (:func:`idm_follow_speed`, :func:`idm_free_speed`,
  :func:`idm_stop_speed`).
* ``MSCFModel_IDM::followSpeed``: ``_v(gap2pred, v, vL, v0)``, where SUMO's
  ``gap2pred`` (the gap TraCI's ``vehicle.getLeader`` reports) is measured
  from the follower's front bumper *plus minGap* to the leader's back bumper;
  ``_v`` adds minGap back, so the IDM sees the bumper-to-bumper gap.
* ``MSCFModel_IDM::freeSpeed`` and ``stopSpeed``: ``_v`` without minGap.
* The bounds SUMO puts on the speed afterwards (``MSCFModel::finalizeSpeed``,
  ``MSVehicle::executeMove``) are in :mod:`jaxround.core.finalize`.

The vType's numbers travel as one `IDMParams` by keyword (``vtype=``);
`jaxround.core.params.CarFollowing.idm` gives them per vehicle. One action
step for a vehicle with leader / stops is::

    v_safe = min(idm_free_speed(...), idm_follow_speed(...), idm_stop_speed(...))
    v_next = finalize.next_speed(v, v_safe, v0, accel=..., decel=..., ...)
    x_next = x + v_next * dt

``v0`` (SUMO's ``desSpeed``) is ``MSLane::getVehicleMaxSpeed``: the lane speed
limit times the vehicle's speedFactor, capped by the vType's maxSpeed.

Only SUMO's default (semi-implicit Euler) position update is covered:
``x += v_next * dt``. SUMO switches to the ballistic update by itself when
``actionStepLength > step-length``; ``finalize.hold_or_update`` keeps the
Euler update in that case (see its caveat).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax
from jax.typing import ArrayLike

from jaxround.core.safe_math import finite_or, safe_power

#: SUMO's default ``stepping`` of the IDM (seconds per sub-step).
IDM_STEPPING = 0.25
#: SUMO's ``NUMERICAL_EPS`` (StdDefs.h).
NUMERICAL_EPS = 0.001
#: Gap SUMO's IDM free speed uses for "no leader" (m).
FREE_GAP = 1e6

__all__ = [
    "FREE_GAP",
    "IDMParams",
    "IDM_STEPPING",
    "NUMERICAL_EPS",
    "idm_free_speed",
    "idm_free_speed_ahead",
    "idm_follow_speed",
    "idm_stop_speed",
    "idm_substeps",
    "idm_v",
    "maximum_safe_stop_speed_euler",
]


class IDMParams(NamedTuple):
    """A vType's IDM numbers (SUMO's names in brackets); scalars, or arrays
    that broadcast against the speeds, e.g. (M,) or (M, 1) per vehicle.

    Attributes:
        accel: maximum acceleration ``a`` [accel] (m/s^2).
        decel: comfortable deceleration ``b`` [decel] (m/s^2).
        tau: time headway ``T`` [tau] (s).
        min_gap: jam distance ``s0`` [minGap] (m).
        delta: acceleration exponent [delta] (SUMO's default 4).
    """

    accel: ArrayLike
    decel: ArrayLike
    tau: ArrayLike
    min_gap: ArrayLike
    delta: ArrayLike


def idm_substeps(dt: float, stepping: float = IDM_STEPPING) -> int:
    """Number of IDM sub-steps per simulation step (SUMO's ``myIterations``).

    Args:
        dt: simulation step length in seconds (SUMO's ``TS``, not the action
            step length).
        stepping: the vType's IDM ``stepping`` parameter (default 0.25 s).

    Returns:
        ``max(1, int(dt / stepping + 0.5))``: 2 at dt 0.5, 4 at dt 1.0.
    """
    return max(1, int(dt / stepping + 0.5))


def idm_v(
    v: ArrayLike,
    v_leader: ArrayLike,
    gap: ArrayLike,
    v_des: ArrayLike,
    *,
    vtype: IDMParams,
    s0: ArrayLike,
    dt: ArrayLike,
    n_substeps: int | jax.Array,
) -> jax.Array:
    """SUMO's ``MSCFModel_IDM::_v``: the speed after one step of the IDM.

    The leader is assumed to keep ``v_leader`` during the step. ``gap`` is the
    gap the IDM sees (for a leader: bumper to bumper); ``s0`` is added to the
    desired gap (SUMO passes minGap for a leader, 0 for stops and free road).
    All array arguments broadcast to a common shape ``(...)``.

    Args:
        v: (...) current speed (m/s).
        v_leader: (...) leader speed, constant within the step (m/s).
        gap: (...) gap to the leader / obstacle as seen by the IDM (m).
        v_des: (...) desired speed ``v0`` (m/s); floored at 0.001.
        vtype: the IDM's numbers (its ``min_gap`` is not read: ``s0`` is).
        s0: (...) jam distance added to the desired gap (m).
        dt: simulation step length (s).
        n_substeps: number of sub-steps, see :func:`idm_substeps`.

    Returns:
        (...) the speed the IDM allows at the end of the step, >= 0.
    """
    v, v_leader, gap = (
        jnp.asarray(x, dtype=jnp.result_type(float, x)) for x in (v, v_leader, gap)
    )
    shape = jnp.broadcast_shapes(v.shape, v_leader.shape, gap.shape)
    accel, tau, delta = vtype.accel, vtype.tau, vtype.delta
    two_sqrt_ab = 2.0 * jnp.sqrt(accel * vtype.decel)
    v_des = jnp.maximum(NUMERICAL_EPS, v_des)
    h = dt / n_substeps

    def body(_: int | jax.Array, carry: tuple[jax.Array, jax.Array]):
        speed, g = carry
        s = jnp.maximum(0.0, speed * tau + speed * (speed - v_leader) / two_sqrt_ab)
        s = s + s0
        g = jnp.maximum(NUMERICAL_EPS, g)
        # no leader (infinite gap): no interaction term, and a finite gradient
        g_fin = finite_or(g, 1.0)
        interaction = jnp.where(jnp.isfinite(g), (s * s) / (g_fin * g_fin), 0.0)
        acc = accel * (1.0 - safe_power(speed / v_des, delta) - interaction)
        speed = jnp.maximum(0.0, speed + acc * h)
        g = g - jnp.maximum(0.0, (speed - v_leader) * h)
        return speed, g

    gap = jnp.broadcast_to(gap, shape)
    if isinstance(n_substeps, int):
        # unrolled, the first sub-step keeps v's own shape: asked for every
        # lane ahead (v (M, 1), gaps (M, K)), its free-road power is taken
        # once per vehicle, not once per lane (the same numbers)
        carry = (v, gap)
        for i in range(n_substeps):
            carry = body(i, carry)
    else:
        carry = lax.fori_loop(0, n_substeps, body, (jnp.broadcast_to(v, shape), gap))
    speed = jnp.maximum(0.0, carry[0])
    return jnp.broadcast_to(speed, jnp.broadcast_shapes(speed.shape, shape))


def idm_follow_speed(
    v: ArrayLike,
    v_leader: ArrayLike,
    gap: ArrayLike,
    v0: ArrayLike,
    *,
    vtype: IDMParams,
    dt: ArrayLike,
    n_substeps: int | jax.Array,
) -> jax.Array:
    """SUMO's ``MSCFModel_IDM::followSpeed``: the speed a leader allows.

    ``gap`` is the net bumper-to-bumper gap (leader's back minus follower's
    front), i.e. TraCI's ``vehicle.getLeader`` distance **plus** ``min_gap``
    (SUMO's getLeader / ``gap2pred`` has minGap already subtracted, and
    ``_v`` adds it back). The desired gap is
    ``min_gap + max(0, v*tau + v*(v - v_leader) / (2*sqrt(accel*decel)))``.

    Args:
        v: (...) follower speed (m/s).
        v_leader: (...) leader speed at the start of the step (m/s).
        gap: (...) bumper-to-bumper gap (m).
        v0: (...) desired speed: ``min(lane limit * speedFactor, maxSpeed)``.
        vtype: the IDM's numbers; its ``min_gap`` is the IDM's ``s0``.
        dt: simulation step length (s).
        n_substeps: see :func:`idm_substeps`.

    Returns:
        (...) safe speed for the end of the step (before :func:`finalize_speed`).
    """
    return idm_v(
        v, v_leader, gap, v0, vtype=vtype, s0=vtype.min_gap, dt=dt,
        n_substeps=n_substeps,
    )  # fmt: skip


def idm_free_speed_ahead(
    v: ArrayLike,
    seen: ArrayLike,
    v_limit: ArrayLike,
    v0: ArrayLike,
    *,
    vtype: IDMParams,
    dt: ArrayLike,
    n_substeps: int | jax.Array,
) -> jax.Array:
    """SUMO's ``MSCFModel_IDM::freeSpeed``: respect a speed limit ``seen`` ahead.

    SUMO calls this once per lane in the look-ahead (``v_limit`` = that lane's
    ``getVehicleMaxSpeed``, ``seen`` = distance to its start) and, on the
    route's last edge, with the distance to the arrival point. While
    ``v <= v_limit`` it is plain free-road acceleration (gap 1e6, no minGap);
    above it, the limit's start is treated as a standing obstacle at
    ``max(seen, secure gap)``, and within the secure gap the result is capped
    at ``v_limit``. ``v0`` is the *current* lane's desired speed.

    Args:
        v: (...) current speed (m/s).
        seen: (...) distance to where ``v_limit`` starts (m).
        v_limit: (...) the speed limit ahead (vehicle-specific, m/s).
        v0: (...) desired speed on the current lane (m/s).
        vtype: the IDM's numbers (no minGap: ``s0`` is 0).
        dt: simulation step length (s).
        n_substeps: see :func:`idm_substeps`.

    Returns:
        (...) the speed the limit allows.
    """
    v = jnp.asarray(v, dtype=jnp.result_type(float, v))
    two_sqrt_ab = 2.0 * jnp.sqrt(vtype.accel * vtype.decel)
    sec_gap = jnp.maximum(0.0, v_limit * vtype.tau + v_limit * v_limit / two_sqrt_ab)
    # below the limit free road behind a "leader" at the limit's speed,
    # above it the standing obstacle: one `idm_v` on the chosen inputs (it
    # works element by element, so this is the choice of the two results)
    below = v <= v_limit
    v_safe = idm_v(
        v, jnp.where(below, v_limit, 0.0),
        jnp.where(below, FREE_GAP, jnp.maximum(seen, sec_gap)), v0,
        vtype=vtype, s0=0.0, dt=dt, n_substeps=n_substeps,
    )  # fmt: skip
    v_safe = jnp.where(seen < sec_gap, jnp.minimum(v_safe, v_limit), v_safe)
    # a negative limit (ballistic red-light case) is returned as it is
    return jnp.where(v_limit < 0.0, v_limit, v_safe)


def idm_free_speed(
    v: ArrayLike,
    v0: ArrayLike,
    *,
    vtype: IDMParams,
    dt: ArrayLike,
    n_substeps: int | jax.Array,
    seen: ArrayLike = FREE_GAP,
) -> jax.Array:
    """Free-road IDM speed: SUMO's ``freeSpeed`` for the current lane's limit.

    For ``v <= v0`` this is ``_v(gap=1e6, vL=v0, desSpeed=v0)`` without minGap
    (as in SUMO, ``vtype.min_gap`` is not used). For ``v > v0`` (the limit
    dropped) SUMO brakes towards a standing obstacle at ``max(seen, secure
    gap)``; ``seen`` is the distance SUMO passes (to the lane end / arrival
    point), by default far away.

    Args:
        v: (...) current speed (m/s).
        v0: (...) desired speed ``min(lane limit * speedFactor, maxSpeed)``.
        vtype: the IDM's numbers.
        dt: simulation step length (s).
        n_substeps: see :func:`idm_substeps`.
        seen: (...) distance SUMO passes as ``seen`` (m).

    Returns:
        (...) free-road speed for the end of the step.
    """
    return idm_free_speed_ahead(
        v, seen, v0, v0, vtype=vtype, dt=dt, n_substeps=n_substeps
    )


def maximum_safe_stop_speed_euler(
    gap: ArrayLike, decel: ArrayLike, headway: ArrayLike, dt: ArrayLike
) -> jax.Array:
    """SUMO's ``MSCFModel::maximumSafeStopSpeedEuler`` (Krauss stop speed).

    Args:
        gap: (...) distance to the stop point (m).
        decel: (...) deceleration ``b`` (m/s^2).
        headway: (...) reaction time (s); the IDM passes its action step length.
        dt: simulation step length (s).

    Returns:
        (...) the largest speed from which the vehicle can stop within ``gap``.
    """
    g = jnp.asarray(gap, dtype=jnp.result_type(float, gap)) - NUMERICAL_EPS
    b = decel * dt
    t = headway
    s = dt
    g_pos = finite_or(jnp.maximum(g, 0.0), FREE_GAP)  # no stop point: far away
    root = jnp.sqrt(s * s + 4.0 * (s * (2.0 * g_pos / b - t) + t * t))
    n = jnp.floor(0.5 - (t - 0.5 * root) / s)
    h = 0.5 * n * (n - 1.0) * b * s + n * b * t
    r = (g_pos - h) / (n * s + t)
    return jnp.where(g < 0.0, 0.0, n * b + r)


def idm_stop_speed(
    v: ArrayLike,
    distance: ArrayLike,
    v0: ArrayLike,
    *,
    vtype: IDMParams,
    dt: ArrayLike,
    n_substeps: int | jax.Array,
    action_step: ArrayLike | None = None,
) -> jax.Array:
    """SUMO's IDM speed for stopping at a point ``distance`` ahead.

    ``MSCFModel_IDM::stopSpeed``: ``_v(distance, v, vL=0, v0)`` without minGap;
    0 when ``distance < 0.01``. When the vehicle stands (``v < 0.001``) and the
    IDM gives (almost) 0 although ``distance > 0``, SUMO falls back to the
    Krauss stop speed (:func:`maximum_safe_stop_speed_euler` with the action
    step length as headway) so that the stop point can still be reached.

    On top of that the result is capped at ``distance / dt`` (the stop point is
    never overshot within the step). This cap is not in the IDM source; it was
    measured in SUMO 1.28 for both vehicle stops (``vehicle.setStop``) and red
    traffic lights: without it, a vehicle a few cm short of the stop point
    re-accelerates in the second IDM sub-step (the desired gap is 0 at v = 0)
    and the last approach step differs by up to ~0.3 m/s.

    Where the stop point lies is the caller's business; measured in SUMO 1.28:
    a vehicle stop at ``endPos`` is approached as a point at
    ``endPos + NUMERICAL_EPS``, a red traffic light (plain netconvert
    junction) as a point 1.0 m before the lane end.

    Args:
        v: (...) current speed (m/s).
        distance: (...) distance from the front bumper to the stop point (m).
        v0: (...) desired speed (m/s).
        vtype: the IDM's numbers (no minGap: ``s0`` is 0).
        dt: simulation step length (s).
        n_substeps: see :func:`idm_substeps`.
        action_step: action step length (s), default ``dt``.

    Returns:
        (...) the speed the stop allows.
    """
    action_step = dt if action_step is None else action_step
    v = jnp.asarray(v, dtype=jnp.result_type(float, v))
    result = idm_v(
        v, 0.0, distance, v0, vtype=vtype, s0=0.0, dt=dt, n_substeps=n_substeps
    )
    creep = maximum_safe_stop_speed_euler(distance, vtype.decel, action_step, dt)
    stuck = (distance > 0.0) & (v < NUMERICAL_EPS) & (result < NUMERICAL_EPS)
    result = jnp.where(stuck, creep, result)
    result = jnp.minimum(result, jnp.maximum(distance, 0.0) / dt)
    return jnp.where(distance < 0.01, 0.0, result)
