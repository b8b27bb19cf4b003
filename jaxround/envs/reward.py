"""The AVs' rewards, per vehicle slot and step: the paper's Eq. 3
(``agent.reward: paper``) and one for what the evaluation measures
(``agent.reward: system``, `system_reward`).

Eq. 3 (`av_reward`):

Desired-velocity term: the deviation of the AV's speed from its desired speed
(the limit of its lane), subtracted from the peak allowed deviation (the
desired speed itself) and bounded below by 0. Pollution term, the same
against P, the CO2 rate of a single vehicle at constant desired speed. The
two are weighted, summed and normalised to [0, 1]:

    r_v = max(0, v_des - |v - v_des|) / v_des
    r_p = max(0, P - |p - P|) / P
    r   = (w_v r_v + w_p r_p) / (w_v + w_p) - time_penalty

The paper's terms are all non-negative, which pays a vehicle for staying in
the network longer; `time_penalty` (1 by default, 0 for Eq. 3 exactly) turns
the sum into the cost ``1 - r`` of each step spent in the roundabout, so
crossing sooner pays. What Eq. 3 optimises: driving at the desired speed and
emitting at the rate of a car cruising at it. Its pollution term pays for
*matching* that rate, not for emitting less: coasting with the fuel cut
(0 mg/s) scores 0 there, idling (~1.5 g/s) about 0.8.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core import emissions
from jaxround.core.params import EnvParams


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
    w_v, w_p = params.reward.speed_weight, params.reward.pollution_weight
    r = (w_v * r_v + w_p * r_p) / (w_v + w_p)
    return r - params.reward.time_penalty


def system_reward(
    n_in_system: jax.Array,
    co2_step_mg: jax.Array,
    active: jax.Array,
    agent: jax.Array,
    params: EnvParams,
    dt: float,
    share: float = 1.0,
    conflicts_step: jax.Array | None = None,
) -> jax.Array:
    """A reward for what the evaluation measures, per slot, float (M,).

    Two costs per step, each a blend of the whole roundabout's (weight
    `share`) and the AV's own (weight ``1 - share``):

    - time: the crossing time of Eq. 4 summed over all vehicles grows by dt
      for every vehicle in the network or due and waiting to be inserted;
      shared equally among the AVs acting in this step, so that at
      ``share = 1`` their rewards add up to minus the system's cost. The
      AV's own: dt for being in the network.
    - CO2: all vehicles' CO2 of the step, shared the same way; the AV's own.
    - near-conflicts (`reward.conflict_weight` each, 0 by default): the
      conflicts that began in the step, counted once per vehicle of the pair
      as SUMO's SSM device writes them, shared the same way; the AV's own.

    ::

        r_i = -w_t dt (share n_in_system / n_agents + (1 - share))
              -w_c (share co2_all_g / n_agents + (1 - share) co2_i_g)
              -w_k (share conflicts_all / n_agents + (1 - share) conflicts_i)

    The shared part pays an AV for what it does to the others (the human
    drivers beside it, the AVs behind), the own part gives each AV a clear
    signal of its own decisions.

    Args:
        n_in_system: () vehicles in the network or waiting to be inserted at
            the start of the step.
        co2_step_mg: (M,) CO2 each slot emitted in the step, mg.
        active: bool (M,) slots that held a vehicle in the step.
        agent: bool (M,) slots that held an AV in the step.
        params: its `reward.time_weight` (per vehicle-second) and
            `reward.co2_weight` (per g).
        dt: step length, s.
        share: weight of the roundabout's cost, in [0, 1].
        conflicts_step: int (M,) conflicts each slot's vehicle entered in
            the step; None: no conflict cost.

    Returns:
        float (M,) the reward of each AV slot, 0 elsewhere.
    """
    n_agents = jnp.maximum(jnp.sum(agent), 1)
    co2_g = jnp.where(active, co2_step_mg, 0.0) / 1000.0
    time_cost = (
        params.reward.time_weight
        * dt
        * (share * n_in_system / n_agents + (1.0 - share))
    )
    co2_cost = params.reward.co2_weight * (
        share * jnp.sum(co2_g) / n_agents + (1.0 - share) * co2_g
    )
    cost = time_cost + co2_cost
    if conflicts_step is not None:
        conflicts = jnp.where(active, conflicts_step, 0).astype(jnp.float32)
        cost = cost + params.reward.conflict_weight * (
            share * jnp.sum(conflicts) / n_agents + (1.0 - share) * conflicts
        )
    return jnp.where(agent, -cost, 0.0)
