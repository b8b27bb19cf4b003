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


def insertion_stop_speed(
    v: jax.Array,
    v0: jax.Array,
    seen: jax.Array,
    params: CarFollowing,
    dt: float,
    n_substeps: int,
    iterations: int = 12,
) -> jax.Array:
    """Insertion speed before the yield line `seen` metres ahead (SUMO, measured).

    While the line lies within the vehicle's braking distance plus minGap
    (SUMO's insertion look-ahead), the speed is lowered to the IDM stop speed
    for the line, the lane's speed `v0` staying the desired speed.

    Args:
        v: (G,) the speed to start from; v0: (G,) the desired speed;
        seen: (G,) distance from the front to the yield line.

    Returns:
        (G,) speed.
    """
    p = params

    def iterate(carry: tuple[jax.Array, jax.Array, jax.Array]):
        i, speed, _ = carry
        reach = brake_gap(speed, p.decel, p.tau, dt) + p.min_gap
        too_fast = reach > seen - STOP_OFFSET
        s2 = idm.idm_v(
            speed, 0.0, seen, v0, vtype=p.idm, s0=0.0, dt=dt, n_substeps=n_substeps
        )
        lowered = jnp.where(too_fast, jnp.minimum(s2, speed), speed)
        return i + 1, lowered, jnp.any(lowered != speed)

    # until no speed changes (a fixed point: later iterations change nothing)
    def more(carry: tuple[jax.Array, jax.Array, jax.Array]) -> jax.Array:
        i, _, changed = carry
        return (i < iterations) & changed

    return lax.while_loop(more, iterate, (0, v, jnp.bool_(True)))[1]
