"""The simplest vmapped car-following step: a ceiling for the environment's speed.

A ring road of M vehicle slots, of which a share is occupied; each step every
vehicle finds its leader by the same kind of masked pairwise search the
environment uses (nearest vehicle ahead, (M, M), reduced by
`jaxround.core.reductions.first_min`), takes one SUMO IDM update
(`jaxround.core.idm.idm_follow_speed`, with the environment's sub-steps) and moves
(Euler). No junction, no look-ahead over lanes, no insertion, no emissions.

`jaxround bench` times it beside the environment, on the same machine in the
same run: how fast XLA steps the bare minimum of a car-following model tells
how much of the gap to a target is the SUMO-faithful step's own work, and how
much is the machine. It is a yardstick, not a traffic model.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core import idm
from jaxround.core.reductions import first_min

#: (pos, speed, active) of the ring's slots, float (M,), float (M,), bool (M,).
RingState = tuple[jax.Array, jax.Array, jax.Array]
#: Ring length (m) and vehicle numbers of the yardstick (SUMO's passenger car,
#: Table 2's accel/decel/tau, IDM delta 4, 50 km/h).
RING_M = 100.0
LENGTH_M = 5.0
V0 = 13.89
VTYPE = idm.IDMParams(accel=1.76, decel=4.5, tau=1.35, min_gap=2.5, delta=4.0)


def bare_step(state: RingState, dt: float, n_substeps: int) -> RingState:
    """One step of the bare ring.

    Args:
        state: (pos, speed, active), float (M,), float (M,), bool (M,).

    Returns:
        The next (pos, speed, active).
    """
    pos, v, active = state
    ahead = (pos[None, :] - pos[:, None]) % RING_M  # (M, M)
    ahead = jnp.where(active[None, :] & (ahead > 0), ahead, jnp.inf)
    nearest, leader = first_min(ahead, axis=1)
    gap = nearest - LENGTH_M
    gap = jnp.where(jnp.isfinite(gap), gap, 1e3)
    v_next = idm.idm_follow_speed(
        v, v[leader], gap, V0, vtype=VTYPE, dt=dt, n_substeps=n_substeps
    )
    v_next = jnp.where(active, jnp.clip(v_next, 0.0, v + VTYPE.accel * dt), 0.0)
    return pos + v_next * dt, v_next, active


def measure_bare_ring(
    max_vehicles: int,
    batch: int,
    occupancy: float,
    steps: int,
    dt: float,
    n_substeps: int,
    *,
    min_timed_s: float = 1.0,
    max_repeats: int = 7,
) -> dict[str, Any]:
    """Time `steps` bare steps of `batch` rings of `max_vehicles` slots.

    Args:
        occupancy: share of occupied slots (the environment's mean vehicles
            over its slots, so both count about the same vehicle-steps).

    Returns:
        ``{"vehicle_steps_per_s", "us_per_step_per_roundabout",
        "flops_per_roundabout_step", "compile_s", "repeats", ...}``.
    """
    if not 0.0 < occupancy <= 1.0:
        raise ValueError(f"occupancy: {occupancy}, expected a share in (0, 1]")
    k_pos, k_on = jax.random.split(jax.random.PRNGKey(0))
    pos = jnp.sort(jax.random.uniform(k_pos, (batch, max_vehicles)) * RING_M, axis=1)
    active = jax.random.uniform(k_on, (batch, max_vehicles)) < occupancy
    speed = jnp.where(active, 5.0, 0.0)

    def window(
        pos: jax.Array, speed: jax.Array, active: jax.Array
    ) -> tuple[RingState, jax.Array]:
        def body(state: RingState, _: None) -> tuple[RingState, jax.Array]:
            state = bare_step(state, dt, n_substeps)
            return state, jnp.sum(state[2], dtype=jnp.int32)

        # the final state is returned too: XLA would drop unused steps
        return jax.lax.scan(body, (pos, speed, active), None, length=steps)

    t0 = time.perf_counter()
    run = jax.jit(jax.vmap(window)).lower(pos, speed, active).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(run(pos, speed, active))
    walls = []
    while True:
        t0 = time.perf_counter()
        _, counts = jax.block_until_ready(run(pos, speed, active))
        walls.append(time.perf_counter() - t0)
        if sum(walls) >= min_timed_s or len(walls) >= max_repeats:
            break
    wall = statistics.median(walls)
    vehicle_steps = int(np.sum(np.asarray(counts), dtype=np.int64))
    # one step, unbatched: XLA's cost analysis counts a loop's body only once
    one = jax.jit(lambda s: bare_step(s, dt, n_substeps))
    flops = compiled_flops(one.lower((pos[0], speed[0], active[0])).compile())
    return {
        "batch": batch,
        "max_vehicles": max_vehicles,
        "vehicle_steps_per_s": vehicle_steps / wall,
        "us_per_step_per_roundabout": 1e6 * wall / (batch * steps),
        "flops_per_roundabout_step": flops,
        "compile_s": compile_s,
        "repeats": len(walls),
        "wall_s": wall,
    }


def compiled_flops(compiled: Any) -> float | None:
    """XLA's count of floating-point operations of a compiled program (its cost
    analysis; comparisons and selects count), or None where the backend gives
    none."""
    try:
        cost = compiled.cost_analysis()
    except Exception:  # noqa: BLE001 - not every backend implements it
        return None
    if isinstance(cost, list | tuple):
        cost = cost[0] if cost else None
    if not cost or "flops" not in cost:
        return None
    return float(cost["flops"])
