"""What an AV's action means when it is an acceleration (``agent.action:
accel``): the speed command sent for it (the other meaning, ``assertiveness``,
is in `jaxround.envs.assertiveness`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core import command as traci
from jaxround.core.params import CarFollowing
from jaxround.core.state import EnvState


def command_from_action(
    state: EnvState, action: jax.Array, params: CarFollowing, dt: float
) -> jax.Array:
    """Each slot's speed command for this step, float (M,), NaN for none.

    An AV's ``action[:, 0]`` is an acceleration (m/s^2), sent as the speed
    command `jaxround.core.command.commanded_speed` (what the SUMO controller sends
    with ``setSpeed``); a NaN acceleration sends none, so the AV drives its
    vType as without a controller. Human drivers and empty slots get none.

    Args:
        state: the state at the start of the step.
        action: float (M, 2) the policy's action.
        params: the per-vehicle parameters (`EnvParams.for_vehicles`).
        dt: step length (s).
    """
    command = traci.commanded_speed(state.speed, action[:, 0], params, dt)
    return jnp.where(state.active & state.is_av, command, jnp.nan)
