"""Insertion speeds: how fast SUMO lets a vehicle enter (departSpeed="max").

Shapes: G legs (one candidate vehicle per leg and step).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from jaxround.core import idm
from jaxround.core.junction import brake_gap
from jaxround.core.params import CarFollowing

#: A blocked vehicle stops this far before its stop line (m).
STOP_OFFSET = 0.1
#: SUMO's DIST_TO_STOPLINE_EXPECT_PRIORITY (MSVehicle.cpp): where a vehicle
#: plans to stop before a major link (the jmStoplineGap default, m).
MAJOR_STOP_OFFSET = 1.0


def link_stop_distance(
    seen: jax.Array, speed: jax.Array, decel: jax.Array, dt: float, major: jax.Array
) -> jax.Array:
    """Where a vehicle plans to stop before a link ``seen`` m ahead, float
    (M,): ``MSVehicle::planMoveInternal``'s ``seen - laneStopOffset``, 1 m
    before a major link (``min(1, seen - brakeGap)`` where it can brake
    before it), ``POSITION_EPS`` before a minor one, and at least 0. All (M,)
    but ``dt``; ``major`` bool."""
    brake_dist = brake_gap(speed, decel, 0.0, dt)
    offset = jnp.where(
        seen >= brake_dist,
        jnp.minimum(MAJOR_STOP_OFFSET, seen - brake_dist),
        MAJOR_STOP_OFFSET,
    )
    offset = jnp.where(major, offset, 0.0)
    return jnp.maximum(seen - jnp.maximum(offset, STOP_OFFSET), 0.0)


def insertion_speed(
    v: jax.Array,
    v0: jax.Array,
    v_leader: jax.Array,
    gap: jax.Array,
    params: CarFollowing,
    dt: float,
    n_substeps: int,
    iterations: int = 12,
) -> jax.Array:
    """SUMO's MSCFModel_IDM::insertionFollowSpeed, its recursion as a loop.

    Args:
        v: (G,) the speed to start from.
        v0: (G,) desired speed (lane limit * speed factor).
        v_leader: (G,) speed of the vehicle ahead.
        gap: (G,) gap to it after minGap (SUMO's gap2pred), >= 0.

    Returns:
        (G,) the speed the vehicle is inserted with.
    """
    p = params
    two_sqrt_ab = 2.0 * jnp.sqrt(p.accel * p.decel)

    def follow(speed: jax.Array) -> jax.Array:
        return idm.idm_follow_speed(
            speed, v_leader, gap + p.min_gap, v0, vtype=p.idm, dt=dt,
            n_substeps=n_substeps,
        )  # fmt: skip

    def iterate(carry: tuple[jax.Array, jax.Array, jax.Array]):
        i, speed, done = carry
        s_star = jnp.maximum(
            0.0, speed * p.tau + speed * (speed - v_leader) / two_sqrt_ab
        )
        ok = gap >= s_star
        s2 = follow(speed)
        s3 = follow(s2)
        settle = s2 - s3 < dt
        return i + 1, jnp.where(done | ok, speed, s2), done | ok | settle

    # a loop that stops once every speed is settled, not an unrolled one: the
    # step compiles much faster, and later iterations would change nothing
    # (insertion carries no gradient, see `RoundaboutEnv._insert`)
    def more(carry: tuple[jax.Array, jax.Array, jax.Array]) -> jax.Array:
        i, _, done = carry
        return (i < iterations) & ~jnp.all(done)

    done = jnp.zeros_like(v, dtype=bool)
    return lax.while_loop(more, iterate, (0, v, done))[1]


#: SUMO's MSCFModel_IDM insertion recursion stops once two more IDM updates
#: would lower the speed by less than this (m/s).
SETTLED_DROP = 1.0


def insertion_stop_speed(
    v: jax.Array,
    v0: jax.Array,
    seen: jax.Array,
    params: CarFollowing,
    dt: float,
    n_substeps: int,
    iterations: int = 12,
) -> jax.Array:
    """Insertion speed before the yield line `seen` metres ahead.

    SUMO's ``MSLane::isInsertionSuccess`` (MSLane.cpp) asks for a stop at the
    minor entry link only while the line lies within the vehicle's braking
    distance plus minGap (``dist = brakeGap(speed) + minGap``; measured with
    the line 0.1 m closer), the speed then coming from
    ``MSCFModel::insertionStopSpeed`` for the IDM. Measured on SUMO 1.28
    (`tests/sumo/test_insertion_sumo.py`, speed factors 0.8-1.4), that speed
    is the recursion of ``MSCFModel_IDM::insertionFollowSpeed`` with the IDM
    stop speed in place of the follow speed: while the IDM's desired gap
    ``v*tau + v^2 / (2 sqrt(a b))`` exceeds `seen`, ``s2`` = the stop speed
    from the speed and ``s3`` = the one from ``s2``; ``s2`` once
    ``s2 - s3 < 1`` m/s, else again from ``s2``. The lane's speed `v0` stays
    the desired speed. (One lowering alone, the rule before, left drivers
    with speed factors of about 1.1 up to 1 m/s faster than SUMO's.)

    Args:
        v: (G,) the speed to start from; v0: (G,) the desired speed;
        seen: (G,) distance from the front to the yield line.

    Returns:
        (G,) speed.
    """
    p = params
    two_sqrt_ab = 2.0 * jnp.sqrt(p.accel * p.decel)
    reach = brake_gap(v, p.decel, p.tau, dt) + p.min_gap
    must_stop = reach > seen - STOP_OFFSET

    def stop(speed: jax.Array) -> jax.Array:
        return idm.idm_v(
            speed, 0.0, seen, v0, vtype=p.idm, s0=0.0, dt=dt, n_substeps=n_substeps
        )

    def iterate(carry: tuple[jax.Array, jax.Array, jax.Array]):
        i, speed, done = carry
        desired_gap = jnp.maximum(0.0, speed * p.tau + speed * speed / two_sqrt_ab)
        room = seen >= desired_gap
        s2 = stop(speed)
        s3 = stop(s2)
        settled = s2 - s3 < SETTLED_DROP
        lowered = jnp.where(done | room, speed, s2)
        return i + 1, lowered, done | room | settled

    # a loop that stops once every speed is settled (later iterations would
    # change nothing; insertion carries no gradient)
    def more(carry: tuple[jax.Array, jax.Array, jax.Array]) -> jax.Array:
        i, _, done = carry
        return (i < iterations) & ~jnp.all(done)

    return lax.while_loop(more, iterate, (0, v, ~must_stop))[1]
