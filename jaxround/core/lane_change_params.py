"""A vType's lane-change numbers (LC2013), traced so a `vmap` can sweep them.

SUMO's names in brackets; the defaults are those of the constructor
`MSLCM_LC2013::MSLCM_LC2013` (SUMO 1.28).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class LaneChangeParams:
    """LC2013's parameters for one vType. Scalars (or arrays that broadcast
    against the vehicles).

    Attributes:
        strategic: eagerness to change for the route [lcStrategic]; < 0 never.
        cooperative: willingness to change or slow down to let others change
            [lcCooperative]; it also serves as lcCooperativeSpeed and
            lcCooperativeRoundabout, which SUMO defaults to it.
        speed_gain: eagerness to change for speed [lcSpeedGain]; 0 never.
        keep_right: eagerness to keep right [lcKeepRight].
        assertive: gaps accepted as secure gap / assertive [lcAssertive].
        lookahead_left: factor on the strategic look-ahead for changes to
            the left [lcLookaheadLeft].
        speed_gain_right: ratio of the left to the right speed-gain
            threshold [lcSpeedGainRight].
    """

    strategic: jax.Array | float = 1.0
    cooperative: jax.Array | float = 1.0
    speed_gain: jax.Array | float = 1.0
    keep_right: jax.Array | float = 1.0
    assertive: jax.Array | float = 1.0
    lookahead_left: jax.Array | float = 2.0
    speed_gain_right: jax.Array | float = 0.1

    @property
    def threshold_left(self) -> jax.Array:
        """`myChangeProbThresholdLeft`: 0.2 / lcSpeedGain (never for 0)."""
        gain = jnp.asarray(self.speed_gain, jnp.result_type(float))
        return jnp.where(gain > 0, 0.2 / jnp.where(gain > 0, gain, 1.0), jnp.inf)

    @property
    def threshold_right(self) -> jax.Array:
        """`myChangeProbThresholdRight`: (0.2 / lcSpeedGainRight) / lcSpeedGain."""
        return self.threshold_left / jnp.asarray(
            self.speed_gain_right, jnp.result_type(float)
        )

    @property
    def safety_factor(self) -> jax.Array:
        """`getSafetyFactor`: 1 / lcAssertive, on the secure gaps of a change."""
        return 1.0 / jnp.asarray(self.assertive, jnp.result_type(float))
