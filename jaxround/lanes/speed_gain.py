"""Step 9 of LC2013's look: the speed gain and keep right.

``MSLCM_LC2013::_wantsChange`` updates ``mySpeedGainProbability`` (and,
looking right, ``myKeepRightProbability``) and decides whether the vehicle
wants to change for speed or to keep right: one branch for a look to the
right (`gain_right`), another to the left (`gain_left`).
`jaxround.lanes.lc2013.wants_change` takes one, or both and keeps one where
the data decide the side of the look.

Everything is element-wise, as in `jaxround.lanes.lc2013`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxround.core.idm import NUMERICAL_EPS
from jaxround.lanes import follow
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.views import Ego, Neighbour

#: MSLCM_LC2013.cpp's constant.
KEEP_RIGHT_TIME = 5.0  # s
#: SUMO 1.28, not in the 2021 source read: a wish to change left for speed
#: turns urgent (and negotiates with the target lane as a strategic one
#: does) once mySpeedGainProbability passes this, whatever lcSpeedGain
#: (measured: 49.75 -> 50.38 in the step it turned, at 4 and 5 m/s;
#: `tests/sumo/test_lc2013_jax.py::test_urgent_speed_gain`).
SPEED_GAIN_URGENT_PROBABILITY = 50.0


class SpeedGain(NamedTuple):
    """Step 9 of `wants_change`: the speed-gain and keep-right
    probabilities after the look, and whether it wants to keep right, wants
    to gain speed, and urgently so (bool)."""

    sgp: jax.Array
    krp: jax.Array
    keep_right: jax.Array
    speed_gain: jax.Array
    urgent: jax.Array


def gain_right(
    gain: SpeedGain, *, ego: Ego, neigh_lead: Neighbour, this_vsafe: jax.Array,
    neigh_vsafe: jax.Array, relative_gain: jax.Array, neigh_dist: jax.Array,
    lc: LaneChangeParams, dt: float,
) -> SpeedGain:  # fmt: skip
    """Step 9 looking right: speed gain and keep right
    (``MSLCM_LC2013::_wantsChange``, ``if (right)``)."""
    v, driver = ego.speed, ego.driver
    sgp, krp = gain.sgp, gain.krp
    faster_here = this_vsafe - 5.0 / 3.6 > neigh_vsafe
    decayed = jnp.where(sgp < 0, sgp * 0.5**dt, sgp)
    gained = jnp.where((sgp < 0) | (relative_gain > 0), sgp - dt * relative_gain, sgp)
    sgp = jnp.where(faster_here, decayed, gained)
    road_speed_factor = ego.v_max / ego.speed_limit
    acceptance = 7.0 * road_speed_factor * jnp.maximum(1.0, v)
    full_speed_gap = jnp.maximum(
        0.0, neigh_dist - follow.brake_gap(driver, ego.v_max, dt)
    )
    driving_s = jnp.minimum(acceptance, full_speed_gap / ego.v_max)
    slow_neigh = neigh_lead.exists & (neigh_lead.speed < ego.v_max)
    gap_to_slow = jnp.maximum(
        0.0,
        jnp.minimum(
            full_speed_gap,
            neigh_lead.gap - follow.secure_gap(driver, ego.v_max, neigh_lead.speed),
        ),
    )
    driving_s = jnp.where(
        slow_neigh,
        jnp.minimum(
            driving_s,
            gap_to_slow / jnp.where(slow_neigh, ego.v_max - neigh_lead.speed, 1.0),
        ),
        driving_s,
    )
    delta_prob = lc.threshold_right * (driving_s / acceptance) / KEEP_RIGHT_TIME
    krp = jnp.where(faster_here, krp, krp - dt * delta_prob)
    keep_right = ~faster_here & (krp * lc.keep_right < -lc.threshold_right)
    speed_gain = (sgp < -lc.threshold_right) & (neigh_dist / jnp.maximum(0.1, v) > 20.0)
    return gain._replace(sgp=sgp, krp=krp, keep_right=keep_right, speed_gain=speed_gain)


def gain_left(
    gain: SpeedGain, *, ego: Ego, neigh_lead: Neighbour, this_vsafe: jax.Array,
    neigh_vsafe: jax.Array, relative_gain: jax.Array, neigh_dist: jax.Array,
    lc: LaneChangeParams, dt: float,
) -> SpeedGain:  # fmt: skip
    """Step 9 looking left: speed gain (``MSLCM_LC2013::_wantsChange``,
    ``else``)."""
    v, sgp = ego.speed, gain.sgp
    sgp = jnp.where(
        this_vsafe > neigh_vsafe,
        jnp.where(sgp > 0, sgp * 0.5**dt, sgp),
        jnp.where(
            this_vsafe == neigh_vsafe,
            jnp.where(sgp > 0, sgp * 0.8**dt, sgp),
            sgp + dt * relative_gain,
        ),
    )
    speed_gain = (
        (sgp > lc.threshold_left)
        & (relative_gain > NUMERICAL_EPS)
        & (neigh_dist / jnp.maximum(0.1, v) > 20.0)
    )
    speed_gain_urgent = sgp > SPEED_GAIN_URGENT_PROBABILITY
    return gain._replace(sgp=sgp, speed_gain=speed_gain, urgent=speed_gain_urgent)
