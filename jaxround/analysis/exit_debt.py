"""What a vehicle still owes when it leaves the network slowly.

Crossing time and CO2 per vehicle stop at the end of the exit leg. A vehicle
that leaves below the speed limit has still to accelerate to it: it will
emit more, and take longer over the road ahead, than one that leaves at the
limit (docs/ppo.md, the headroom study's caveat). A criterion on CO2 per
vehicle alone pays a controller for leaving slowly.

`exit_debt` charges it: over the next `AHEAD_M` metres, the CO2 and the time
of an IDM free-road acceleration from the exit speed to the limit (SUMO's
HBEFA model, `jaxround.core.emissions`), minus those of driving them at the
limit. Tabulated once per limit and acceleration, then interpolated.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxround.core.emissions import step_emissions_mg

#: Metres of road after the network over which the debt is counted.
AHEAD_M = 150.0
#: The IDM of the free-road acceleration: a, delta (the AV vType's a).
ACCEL, DELTA = 2.6, 4.0
#: Step of the tabulation, s, and its speed grid, m/s.
DT_S, GRID_MPS = 0.1, 0.1


def debt_table(limit_mps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(speeds, co2_g, time_s), float (V,): the debt of leaving at each speed
    in [0, limit]."""
    speeds = np.arange(0.0, limit_mps + GRID_MPS / 2, GRID_MPS)
    v = jnp.asarray(speeds, jnp.float32)
    dist = jnp.zeros_like(v)
    co2 = jnp.zeros_like(v)
    t = jnp.zeros_like(v)
    for _ in range(int(60.0 / DT_S)):  # 60 s reach 150 m from standstill
        going = dist < AHEAD_M
        v_new = jnp.minimum(
            v + ACCEL * (1 - (v / limit_mps) ** DELTA) * DT_S, limit_mps
        )
        step_m = (v + v_new) / 2 * DT_S
        frac = jnp.clip((AHEAD_M - dist) / jnp.maximum(step_m, 1e-6), 0.0, 1.0)
        mg, _ = step_emissions_mg(v, v_new, DT_S)
        co2 = co2 + jnp.where(going, mg * frac, 0.0)
        t = t + jnp.where(going, DT_S * frac, 0.0)
        dist = dist + jnp.where(going, step_m, 0.0)
        v = jnp.where(going, v_new, v)
    cruise_mg, _ = step_emissions_mg(limit_mps, limit_mps, 1.0)  # per second
    at_limit_s = AHEAD_M / limit_mps
    co2_g = (np.asarray(co2) - float(cruise_mg) * at_limit_s) / 1000.0
    return speeds, np.maximum(co2_g, 0.0), np.maximum(np.asarray(t) - at_limit_s, 0.0)


def exit_debt(
    exit_speed: jnp.ndarray, table: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(co2_g, time_s) owed by vehicles leaving at `exit_speed` (...), by
    interpolation in `debt_table`; 0 at or above the limit."""
    speeds, co2_g, time_s = (jnp.asarray(x, jnp.float32) for x in table)
    return jnp.interp(exit_speed, speeds, co2_g), jnp.interp(exit_speed, speeds, time_s)
