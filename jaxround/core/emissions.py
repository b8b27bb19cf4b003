"""SUMO 1.28's CO2 and fuel emissions of ``HBEFA4/PC_petrol_Euro-4`` in JAX.

Every function here is pure, element-wise over arrays of vehicles (array
arguments broadcast against each other), free of Python control flow on traced
values, and so usable under ``jax.jit`` and ``jax.vmap``. Results keep the
floating dtype of the inputs (float32 unless x64 is enabled).

The rate, in mg/s, for the speed ``v`` after a step (m/s), the acceleration
``a = (v_new - v_old) / dt`` of that step (m/s^2) and the road slope ``s``
(degrees, as ``vehicle.getSlope`` reports it) is::

    a' = a + 9.80665 * sin(s)
    E  = max(0, f0 + f1 v + f2 a' + f3 v^2 + f4 v^3 + f5 a' v + f6 a' v^2)
    E  = 0 if v > 0.5 and a < d(v, s)          (fuel cut-off while coasting)
    d(v, s) = min(0, c0 + c1 v - 9.81 * sin(s))                 v >= 10/3.6
    d(v, s) = v / (10/3.6) * d(10/3.6, s)                       v <  10/3.6

Measured against SUMO 1.28: ``emissionsMap`` over v 0..50 m/s, a -5..5 m/s^2
and slopes -6..6 deg (282,807 points per pollutant, all equal to the 6 printed
digits), and ``--emission-output`` of simulations on a flat and on a sloped
road (equal to the 8 printed decimals). Where this differs from the usual
summary of SUMO's HBEFA4 cut-off (``a' < c(v)``, the "notes" below):

* Slopes: the notes' cut-off ``a' < c(v)`` only holds on a flat road. SUMO
  compares the *raw* acceleration ``a`` with a threshold that contains the
  slope with g = 9.81 (PHEMlight's constant) and is capped at 0, while the
  polynomial uses ``a'`` with g = 9.80665. Downhill the cut starts at ``a < 0``.
* The threshold constants, measured to 1e-7 m/s^2, are c0 = -0.10794834 and
  c1 = -0.01297664 (notes: -0.107947 and -0.0129766; low-speed slope d/v =
  -0.051838, notes: -0.051837). They hold for SUMO's default vType mass and
  frontal area (our vTypes set neither).
* Trip totals: no partial weighting of the last step (below).

Trip totals (tripinfo ``CO2_abs`` / ``fuel_abs``, see :func:`trip_emissions_mg`):
SUMO adds ``rate * dt`` for every step *after* the insertion step, the arrival
step included with its full ``dt`` (the rate taken at ``arrivalSpeed``). The
insertion step itself is printed in ``--emission-output`` (rate at the depart
speed with a = 0) but is not part of the trip total. So for parity with SUMO
the arrival step has ``fraction = 1``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

#: Polynomial coefficients f0..f6 of SUMO 1.28's HBEFA4 table
#: (``HelpersHBEFA4.cpp``, class PC_petrol_Euro-4), CO2 in mg/s; the same
#: numbers as the reference notes, confirmed by SUMO's emission-output.
CO2_COEFFS = (1521.0, 15.59, 695.1, 0.0, 0.1199, 132.5, 3.434)
#: The same for fuel in mg/s (SUMO's default, non-volumetric fuel unit).
FUEL_COEFFS = (493.1, 5.054, 225.3, 0.0, 0.03887, 42.96, 1.113)

#: g in the slope term of the polynomial (standard gravity), m/s^2.
GRAVITY = 9.80665
#: g in the coasting threshold (PHEMlight's value, measured), m/s^2.
COAST_GRAVITY = 9.81
#: Coasting threshold ``c0 + c1 v`` on a flat road (measured, see module doc).
COAST_C0 = -0.10794834
COAST_C1 = -0.01297664
#: Below this speed (PHEMlight's ``SPEED_DCEL_MIN``, 10 km/h) the threshold is
#: scaled down linearly to 0 at v = 0.
COAST_SPEED_MIN = 10.0 / 3.6
#: SUMO's ``ZERO_SPEED_ACCURACY``: no fuel cut at or below this speed (m/s).
ZERO_SPEED_ACCURACY = 0.5

__all__ = [
    "CO2_COEFFS",
    "COAST_C0",
    "COAST_C1",
    "COAST_GRAVITY",
    "COAST_SPEED_MIN",
    "FUEL_COEFFS",
    "GRAVITY",
    "ZERO_SPEED_ACCURACY",
    "coasting_decel",
    "hbefa4_rates",
    "step_emissions_mg",
    "trip_emissions_mg",
]


def _float(x: ArrayLike) -> jax.Array:
    x = jnp.asarray(x)
    return x.astype(jnp.result_type(float, x))


def coasting_decel(v: ArrayLike, slope: ArrayLike = 0.0) -> jax.Array:
    """Acceleration below which SUMO cuts the fuel (``getCoastingDecel``).

    Args:
        v: (...) speed after the step (m/s).
        slope: (...) road slope in degrees (positive uphill).

    Returns:
        (...) the threshold, <= 0 (m/s^2); compare with the raw acceleration.
    """
    v = _float(v)
    grade = COAST_GRAVITY * jnp.sin(jnp.deg2rad(_float(slope)))
    at_min = jnp.minimum(0.0, COAST_C0 + COAST_C1 * COAST_SPEED_MIN - grade)
    above = jnp.minimum(0.0, COAST_C0 + COAST_C1 * v - grade)
    return jnp.where(v < COAST_SPEED_MIN, v / COAST_SPEED_MIN * at_min, above)


def _polynomial(f: tuple[float, ...], v: jax.Array, a: jax.Array) -> jax.Array:
    """HBEFA4's ``f0 + f1 v + f2 a + f3 v^2 + f4 v^3 + f5 a v + f6 a v^2``."""
    return (
        f[0] + v * (f[1] + v * (f[3] + f[4] * v)) + a * (f[2] + v * (f[5] + f[6] * v))
    )


def hbefa4_rates(
    v_new: ArrayLike, accel: ArrayLike, slope: ArrayLike = 0.0
) -> tuple[jax.Array, jax.Array]:
    """CO2 and fuel emission rates of SUMO's ``HBEFA4/PC_petrol_Euro-4``.

    Args:
        v_new: (...) speed at the end of the step (m/s).
        accel: (...) acceleration of the step, ``(v_new - v_old) / dt`` (m/s^2).
        slope: (...) road slope in degrees at the vehicle (SUMO's
            ``vehicle.getSlope``); 0 on a flat network.

    Returns:
        ``(co2, fuel)``, each (...) in mg/s: 0 while coasting (``v_new > 0.5``
        and ``accel < coasting_decel(v_new, slope)``), else the HBEFA4
        polynomial at ``accel + 9.80665 sin(slope)``, floored at 0.
    """
    v, a = jnp.broadcast_arrays(_float(v_new), _float(accel))
    slope = _float(slope)
    a_eff = a + GRAVITY * jnp.sin(jnp.deg2rad(slope))  # (...)
    coasting = (v > ZERO_SPEED_ACCURACY) & (a < coasting_decel(v, slope))  # (...)
    co2 = jnp.where(coasting, 0.0, jnp.maximum(0.0, _polynomial(CO2_COEFFS, v, a_eff)))
    fuel = jnp.where(
        coasting, 0.0, jnp.maximum(0.0, _polynomial(FUEL_COEFFS, v, a_eff))
    )
    return co2, fuel


def step_emissions_mg(
    v_old: ArrayLike,
    v_new: ArrayLike,
    dt: ArrayLike,
    fraction: ArrayLike = 1.0,
    slope: ArrayLike = 0.0,
) -> tuple[jax.Array, jax.Array]:
    """CO2 and fuel emitted over one step, as SUMO's emissions device adds it.

    Args:
        v_old: (...) speed at the start of the step (m/s); on the first step
            after insertion, the depart speed.
        v_new: (...) speed at the end of the step (m/s).
        dt: step length (s).
        fraction: (...) weight of the step in [0, 1]. SUMO 1.28 counts every
            step fully, the arrival step included (see :func:`trip_emissions_mg`),
            so parity with SUMO needs 1; a smaller value is a choice of our own.
        slope: (...) road slope in degrees at the end of the step.

    Returns:
        ``(co2, fuel)``, each (...) in mg: ``rate * dt * fraction``.
    """
    v_old, v_new = _float(v_old), _float(v_new)
    co2, fuel = hbefa4_rates(v_new, (v_new - v_old) / dt, slope)
    weight = dt * fraction
    return co2 * weight, fuel * weight


def trip_emissions_mg(
    v_depart: ArrayLike,
    v_steps: ArrayLike,
    dt: ArrayLike,
    valid: ArrayLike | None = None,
    slope: ArrayLike = 0.0,
) -> tuple[jax.Array, jax.Array]:
    """Trip totals as SUMO's tripinfo ``CO2_abs`` / ``fuel_abs`` count them.

    SUMO sums ``rate * dt`` over the steps that move the vehicle: the first is
    the step after the insertion step (its acceleration is measured from the
    depart speed), the last is the arrival step, weighted fully, with the
    speed tripinfo reports as ``arrivalSpeed``. The insertion step (rate at
    the depart speed, a = 0, printed by ``--emission-output``) is not counted.

    Args:
        v_depart: (...) depart speed (m/s).
        v_steps: (..., T) speed at the end of each step after insertion, the
            arrival step last (m/s); trailing padding is allowed, see ``valid``.
        dt: step length (s).
        valid: optional bool (..., T), True on the steps of the trip; must be a
            prefix along T. Default: all steps.
        slope: (..., T) or broadcastable road slope in degrees per step.

    Returns:
        ``(co2, fuel)``, each (...) in mg.
    """
    v_steps = _float(v_steps)
    v_depart = jnp.broadcast_to(_float(v_depart), v_steps.shape[:-1])
    v_prev = jnp.concatenate([v_depart[..., None], v_steps[..., :-1]], axis=-1)
    co2, fuel = step_emissions_mg(v_prev, v_steps, dt, 1.0, slope)  # (..., T)
    if valid is not None:
        co2 = jnp.where(valid, co2, 0.0)
        fuel = jnp.where(valid, fuel, 0.0)
    return co2.sum(axis=-1), fuel.sum(axis=-1)
