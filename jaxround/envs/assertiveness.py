"""The AVs' assertiveness: a policy action that retunes each AV's own vType.

In ``agent.action: assertiveness`` an AV's action is one real number x per
step; its assertiveness ``u = tanh(x)`` in (-1, 1) sets two numbers of its
vType for that step, around the vType's own values (tau0, impatience0)::

    tau        = max(tau0 * 2 ** -u, min(tau_floor, tau0))   (0.5 x .. 2 x)
    impatience = clip(impatience0 + max(u, 0), 0, 1)

tau_floor is the scenario's time-gap floor (`safety.min_av_tau_s`, 0.8 s).

u = 0 (x = 0) is the vType itself: a policy that outputs 0 drives exactly
like uncontrolled AVs, in JAX and in SUMO. SUMO's own models stay in charge
of safety and right of way: a shorter headway is still IDM car following,
an impatient AV still passes SUMO's gap acceptance (with its foes braking at
impatience times their decel, ``MSLink::blockedByFoe``). The SUMO controller
sets the same numbers after each step, for the next: ``vehicle.setTau``, which
gives the vehicle a type of its own, and ``vehicletype.setImpatience`` on that
type (``vehicle.setImpatience`` has no effect in SUMO 1.28;
`sumo_export.controller.set_tau_and_impatience`).

Why these two: the headroom study (docs/ppo.md) found that, at 100% AVs, a
shorter headway and impatience lower both the crossing time and the CO2 of
all vehicles, where speed commands under the IDM (eco, timed approaches)
found nothing to gain.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.core.params import CarFollowing

#: tau is scaled by 2 ** -u: at most halved or doubled.
TAU_RANGE = 2.0
#: Bounds of the raw action an exported policy's mean is clipped to
#: (tanh(3) = 0.995).
RAW_BOUND = 3.0


def assertiveness(raw: jax.Array) -> jax.Array:
    """``tanh(raw)``, float (...); NaN (no action) reads 0, the vType."""
    return jnp.tanh(jnp.nan_to_num(raw))


def assertive_tau(
    tau0: jax.Array, u: jax.Array, min_tau: float | jax.Array = 0.0
) -> jax.Array:
    """The headway of assertiveness u, float (...), never below the time-gap
    floor `min_tau` (`SafetyConfig.min_av_tau_s`; a vType already below it
    keeps its own tau)."""
    return jnp.maximum(tau0 * TAU_RANGE ** (-u), jnp.minimum(min_tau, tau0))


def assertive_impatience(impatience0: jax.Array, u: jax.Array) -> jax.Array:
    """The impatience of assertiveness u, float (...)."""
    return jnp.clip(impatience0 + jnp.maximum(u, 0.0), 0.0, 1.0)


def retuned_params(
    params: CarFollowing,
    raw: jax.Array,
    is_agent: jax.Array,
    min_tau: float | jax.Array = 0.0,
) -> CarFollowing:
    """Per-vehicle parameters with each AV's tau and impatience retuned.

    Args:
        params: the per-vehicle view (`EnvParams.for_vehicles`), tau and
            impatience float (M,).
        raw: float (M,) raw actions (NaN: none).
        is_agent: bool (M,) slots whose vehicle is an AV.
        min_tau: the AVs' time-gap floor, s (`assertive_tau`).
    """
    u = jnp.where(is_agent, assertiveness(raw), 0.0)
    return params.replace(
        tau=jnp.where(is_agent, assertive_tau(params.tau, u, min_tau), params.tau),
        impatience=jnp.where(
            is_agent, assertive_impatience(params.impatience, u), params.impatience
        ),
    )
