"""A step's lane-change turns, one after another, and their gradient.

`MSLaneChanger` gives the vehicles their turns one after another, each
seeing what the turns before it left (`jaxround.lanes.ring_changer`: the
order, one turn). Forward, `change_lanes` takes only the turns of the
vehicles on edges with a changer: a `lax.while_loop` over them, so that a
step costs what those vehicles need, not what its slots hold (they come
first in the order, and the turn of an empty slot or of a vehicle on an
edge without a changer would change nothing: `ring_changer.turn`).

Reverse mode cannot differentiate a `while_loop`, so the gradient is the
one of the same turns taken by a `lax.scan` over every slot
(`turns_of_every_slot`), whose values are the same, recomputed in the
backward pass (`scan_gradient`): the gradient is exact, as through the
rest of the step, and costs the scan only where one is taken.
`jaxround.lanes.ring_batches` (the step's `change_lanes`, batched two
roundabouts to a lane) and `jaxround.lanes.ring_rounds` (the turns in
rounds, for GPUs) get it the same way.

Shapes: M vehicle slots, L lanes, as in `jaxround.lanes.ring_changer`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from jaxround.lanes.decide import Kept, deliver, keep
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.ring_changer import (
    Context,
    Outcome,
    RingArrays,
    RingChanges,
    RingVehicles,
    View,
    changes,
    context,
    turn,
)
from jaxround.lanes.views import Memory

#: What the turns before a vehicle's leave it: the lanes (M,), who had a
#: turn (M,), the last and first vehicle registered blocked per lane (L,)
#: each, and the memory.
Carry = tuple[jax.Array, jax.Array, jax.Array, jax.Array, Memory]


def take(ctx: Context, carry: Carry, i: jax.Array) -> tuple[Carry, Outcome]:
    """Vehicle ``i``'s turn: what it leaves the turns after it, its outcome."""
    lane, done, last_blocked, first_blocked, mem = carry
    own = ctx.lane[i]
    view = View(lane, done, last_blocked[own], first_blocked[own],
                mem.state[i], mem.advices[i], mem.state)  # fmt: skip
    # the barrier measured faster on the CPU (docs/benchmarks.md, 2026-11-28:
    # 23 against 25-26 ms per call at batch 256); XLA expands it before fusion
    out = jax.lax.optimization_barrier(turn(ctx, i, view, mem))
    # its row: what the turn keeps, or `changed()`'s reset where it changed
    # (`jaxround.lanes.memory.after_change` of its row alone)
    moved = out.direction != 0
    kept = jax.tree.map(
        lambda x, reset: jnp.where(moved, reset, x), out.kept, reset_row(out.kept)
    )
    mem = keep(deliver(mem, out.told), i, kept)
    mem = mem.replace(state=mem.state.at[i].set(jnp.where(moved, 0, out.state)))
    for side in (0, 1):
        target, blocked = out.target[side], out.blocked[side]
        last_blocked = jnp.where(blocked, last_blocked.at[target].set(i),
                                 last_blocked)  # fmt: skip
        first_blocked = jnp.where(
            blocked & (first_blocked[target] < 0),
            first_blocked.at[target].set(i), first_blocked,
        )  # fmt: skip
    lane = lane.at[i].set(out.to_lane)
    return (lane, done.at[i].set(True), last_blocked, first_blocked, mem), out


def reset_row(kept: Kept) -> Kept:
    """A row of `Kept` as `changed()` leaves it (`after_change`): zeros,
    no advices."""
    return Kept(*(jnp.zeros_like(x) for x in kept))._replace(
        advices=jnp.full_like(kept.advices, jnp.nan)
    )


def first_carry(ctx: Context, memory: Memory) -> Carry:
    """Before the first turn: nobody has moved, had a turn or registered."""
    none = -jnp.ones(ctx.net.lane_length.shape[0], jnp.int32)
    return ctx.lane, jnp.zeros(ctx.lane.shape[0], bool), none, none, memory


def for_changes(out: Outcome) -> Outcome:
    """What `ring_changer.changes` reads of a turn's outcome (the rest left
    out of the loop's carry: under `vmap` a `while_loop` selects every
    number of its carry in every iteration)."""
    return out._replace(state=None, kept=None, told=None, blocked=None, target=None)


def first_outcome(ctx: Context, carry: Carry) -> Outcome:
    """Every slot's `for_changes` outcome before any turn (M, ...): no
    change, what the slots without a turn keep."""
    shapes = jax.eval_shape(lambda: for_changes(take(ctx, carry, ctx.order[0])[1]))
    m = ctx.veh.pos.shape[0]
    outcome = jax.tree.map(lambda x: jnp.zeros((m, *x.shape), x.dtype), shapes)
    return outcome._replace(to_lane=ctx.lane, to_path=ctx.veh.path)


def turns_of_vehicles(
    net: RingArrays,
    veh: RingVehicles,
    memory: Memory,
    lc: LaneChangeParams,
    dt: float,
) -> tuple[RingChanges, Memory]:
    """The turns of the vehicles on edges with a changer, a `while_loop` over
    them; every other slot's outcome is "no change" (as its turn would
    give)."""
    ctx = context(net, veh, lc, dt)
    init = first_carry(ctx, memory)
    outcome = first_outcome(ctx, init)
    n_turns = jnp.sum(ctx.decides)

    def more(loop: tuple[jax.Array, Carry, Outcome]) -> jax.Array:
        return loop[0] < n_turns

    def next_turn(loop: tuple[jax.Array, Carry, Outcome]) -> tuple:
        n, carry, outcome = loop
        i = ctx.order[n]
        carry, out = take(ctx, carry, i)
        outcome = jax.tree.map(
            lambda every, x: every.at[i].set(x), outcome, for_changes(out)
        )
        return n + 1, carry, outcome

    _, (*_, memory), outcome = jax.lax.while_loop(
        more, next_turn, (jnp.zeros((), jnp.int32), init, outcome)
    )
    return changes(ctx, outcome), memory


def turns_of_every_slot(
    net: RingArrays,
    veh: RingVehicles,
    memory: Memory,
    lc: LaneChangeParams,
    dt: float,
) -> tuple[RingChanges, Memory]:
    """Every slot's turn, a `lax.scan` (differentiable; the same values as
    `turns_of_vehicles`)."""
    ctx = context(net, veh, lc, dt)
    (*_, memory), outs = jax.lax.scan(
        lambda carry, i: take(ctx, carry, i), first_carry(ctx, memory), ctx.order
    )
    outcome = jax.tree.map(lambda x: jnp.zeros_like(x).at[ctx.order].set(x), outs)
    return changes(ctx, outcome), memory


def scan_gradient(forward: Callable[..., tuple]) -> Callable[..., tuple]:
    """`forward(net, veh, memory, lc, dt) -> (changes, memory, *more)`
    with the gradient of `turns_of_every_slot` (more: outputs without one)."""

    @functools.partial(jax.custom_vjp, nondiff_argnums=(4,))
    def changed(net, veh, memory, lc, dt):  # noqa: ANN001, ANN202
        return forward(net, veh, memory, lc, dt)

    def keep_inputs(net, veh, memory, lc, dt):  # noqa: ANN001, ANN202
        return forward(net, veh, memory, lc, dt), (net, veh, memory, lc)

    def backward(dt: float, inputs: tuple, cotangent: tuple) -> tuple:
        _, pullback = jax.vjp(lambda *a: turns_of_every_slot(*a, dt), *inputs)
        return pullback(tuple(cotangent[:2]))

    changed.defvjp(keep_inputs, backward)

    def call(
        net: RingArrays, veh: RingVehicles, memory: Memory,
        lc: LaneChangeParams, dt: float,
    ) -> Any:  # fmt: skip
        return changed(net, veh, memory, lc, dt)

    return call
