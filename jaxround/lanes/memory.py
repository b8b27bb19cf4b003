"""LC2013's memory across the step: reset before the changes, read by the
next step's speed planning.

* `prepare_step`: `MSLCM_LC2013::prepareStep`, called at the end of every
  vehicle's `executeMove`, before `MSEdgeControl::changeLanes`.
* `after_change`: `MSLCM_LC2013::changed`, for a vehicle that changed.
* `patch_speed`: `MSLCM_LC2013::_patchSpeed`, called by
  `MSCFModel::finalizeSpeed` in the next step's move.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.lanes import actions as lca
from jaxround.lanes.views import Memory


def prepare_step(memory: Memory) -> Memory:
    """Keep only a strategic wish's direction, drop the advices, and round
    both probabilities up to 1e-5 ("truncate to work around numerical
    instability between different builds"). Shapes (M,)."""
    strategic = (memory.state & lca.STRATEGIC) != 0
    return memory.replace(
        state=jnp.where(strategic, memory.state & lca.WANTS_LANECHANGE, 0).astype(
            jnp.int32
        ),
        speed_gain_probability=jnp.ceil(memory.speed_gain_probability * 1e5) * 1e-5,
        keep_right_probability=jnp.ceil(memory.keep_right_probability * 1e5) * 1e-5,
        advices=jnp.full_like(memory.advices, jnp.nan),
        left_space=jnp.zeros_like(memory.left_space),
        blocker_length=jnp.zeros_like(memory.blocker_length),
    )


def after_change(memory: Memory, changed: jax.Array) -> Memory:
    """`changed()`: state, probabilities, look-ahead speed and advices reset
    where ``changed`` (bool (M,))."""
    zero = jnp.zeros_like(memory.speed_gain_probability)
    return memory.replace(
        state=jnp.where(changed, 0, memory.state).astype(jnp.int32),
        speed_gain_probability=jnp.where(changed, zero, memory.speed_gain_probability),
        keep_right_probability=jnp.where(changed, zero, memory.keep_right_probability),
        look_ahead_speed=jnp.where(changed, zero, memory.look_ahead_speed),
        advices=jnp.where(changed[..., None], jnp.nan, memory.advices),
        # SUMO keeps these where the new lane is not yet the best; a change
        # that keeps room is an urgent one, onto the best lane
        left_space=jnp.where(changed, zero, memory.left_space),
        blocker_length=jnp.where(changed, zero, memory.blocker_length),
    )


def patch_speed(
    memory: Memory,
    v_min: jax.Array,
    wanted: jax.Array,
    v_max: jax.Array,
    cooperative_speed: jax.Array | float,
    blocker: tuple[jax.Array, jax.Array] | None = None,
) -> jax.Array:
    """The next speed after the lane-change advices, float (M,).

    The stop before the room kept for a blocker (braking beyond decel if it
    must) and the smallest advice within [v_min, v_max] (blended with
    ``wanted`` by lcCooperativeSpeed) win; without either, a blocked strategic wish or a
    blocking leader speeds up to ``(v_max + wanted) / 2`` and a cooperative
    wish blocked by its leader slows to ``(v_min + wanted) / 2``.

    Args:
        memory: the state and advices set in the previous step's changes.
        v_min, wanted, v_max: (M,) `finalizeSpeed`'s bounds and its speed.
        cooperative_speed: lcCooperativeSpeed (clipped to [0, 1]), scalar or (M,).
        blocker: (stop, v_min_emergency), (M,) each: the stop before the
            room kept for a blocker (NaN: none) and ``minNextSpeedEmergency``,
            which braking for it may go down to and which caps ``v_max``
            (`jaxround.lanes.blockers.blocker_stop_speed`; None: no room).
    """
    got_blocker = jnp.zeros(jnp.shape(wanted), bool)
    blocker_v = jnp.full(jnp.shape(wanted), jnp.inf, jnp.result_type(wanted))
    if blocker is not None:
        blocker_stop, v_min_emergency = blocker
        keeps = ~jnp.isnan(blocker_stop)
        safe = jnp.where(keeps, blocker_stop, jnp.inf)
        v_max = jnp.where(
            keeps, jnp.minimum(v_max, jnp.maximum(safe, v_min_emergency)), v_max
        )
        got_blocker = keeps & (safe < wanted)
        harder = got_blocker & (safe < v_min) & (safe >= v_min_emergency)
        v_min = jnp.where(harder, jnp.maximum(v_min_emergency, safe), v_min)
        blocker_v = jnp.where(got_blocker, jnp.maximum(v_min, safe), jnp.inf)
    weight = jnp.clip(jnp.asarray(cooperative_speed), 0.0, 1.0)
    weight = weight[..., None] if weight.ndim else weight
    advices = memory.advices  # (M, A)
    usable = (
        ~jnp.isnan(advices) & (advices >= v_min[:, None]) & (advices <= v_max[:, None])
    )
    blended = advices * weight + (1.0 - weight) * wanted[:, None]
    advised = jnp.minimum(
        jnp.minimum(wanted, blocker_v),
        jnp.min(jnp.where(usable, blended, jnp.inf), axis=1),
    )
    got_one = got_blocker | jnp.any(usable, axis=1)

    state = memory.state
    wants_blocked = ((state & lca.WANTS_LANECHANGE) != 0) & ((state & lca.BLOCKED) != 0)
    strategic = wants_blocked & ((state & lca.STRATEGIC) != 0)
    cooperative = wants_blocked & ~strategic & ((state & lca.COOPERATIVE) != 0)
    coop_by_leader = cooperative & ((state & lca.BLOCKED_BY_LEADER) != 0)
    coop_by_follower = (
        cooperative & ~coop_by_leader & ((state & lca.BLOCKED_BY_FOLLOWER) != 0)
    )
    blocking_leader = (state & lca.AMBLOCKINGLEADER) != 0
    up = (v_max + wanted) / 2.0
    down = jnp.where(wanted >= 0, (jnp.maximum(0.0, v_min) + wanted) / 2.0, wanted)
    patched = jnp.select(
        [strategic, coop_by_leader, coop_by_follower, blocking_leader],
        [up, down, up, up],
        wanted,
    )
    return jnp.where(got_one, advised, patched)
