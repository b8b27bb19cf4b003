"""The AVs' reward: Eq. 3 of the paper, per vehicle slot and step.

Desired-velocity term: the deviation of the AV's speed from its desired speed
(the limit of its lane), subtracted from the peak allowed deviation (the
desired speed itself) and bounded below by 0. Pollution term, the same
against P, the CO2 rate of a single vehicle at constant desired speed. The
two are weighted, summed and normalised to [0, 1]:

    r_v = max(0, v_des - |v - v_des|) / v_des
    r_p = max(0, P - |p - P|) / P
    r   = (w_v r_v + w_p r_p) / (w_v + w_p) - time_penalty

The paper's terms are all non-negative, which pays a vehicle for staying in
the network longer; `time_penalty` (1 by default) turns the sum into the cost
``1 - r`` of each step spent in the roundabout, so crossing sooner pays.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround import emissions
from jaxround.state import EnvParams


def reference_pollution(v_desired: jax.Array) -> jax.Array:
    """P: CO2 rate (mg/s) of a vehicle at constant speed `v_desired`, (...)."""
    co2, _ = emissions.hbefa4_rates(v_desired, jnp.zeros_like(v_desired))
    return co2


def av_reward(
    speed: jax.Array,
    v_desired: jax.Array,
    co2_rate: jax.Array,
    params: EnvParams,
) -> jax.Array:
    """Eq. 3 for every slot, float (M,).

    Args:
        speed: (M,) speed at the end of the step, m/s.
        v_desired: (M,) desired speed (lane limit times speed factor), m/s.
        co2_rate: (M,) CO2 emitted over the step divided by dt, mg/s.
        params: reward weights and time penalty.
    """
    v_des = jnp.maximum(v_desired, 1e-3)
    r_v = jnp.maximum(0.0, v_des - jnp.abs(speed - v_des)) / v_des
    p_ref = jnp.maximum(reference_pollution(v_des), 1e-3)
    r_p = jnp.maximum(0.0, p_ref - jnp.abs(co2_rate - p_ref)) / p_ref
    w_v, w_p = params.reward_speed_weight, params.reward_pollution_weight
    r = (w_v * r_v + w_p * r_p) / (w_v + w_p)
    return r - params.reward_time_penalty
