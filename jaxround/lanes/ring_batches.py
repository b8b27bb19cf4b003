"""A batch of roundabouts' lane-change turns, two roundabouts to a lane of
the batch.

`jaxround.lanes.ring_turns` takes one roundabout's turns one after another,
a `lax.while_loop` over the vehicles on edges with a changer. Under a plain
`jax.vmap` that loop runs, for every roundabout of the batch, as many turns
as the busiest one needs: in two_lane.yaml's traffic a batch of 256 runs
39 turns where a roundabout needs 17 on average, so that a CPU computes
more than twice the turns it keeps.

`turns_of_batch` is `ring_turns.turns_of_vehicles` with a batching rule of
its own (`jax.custom_batching.custom_vmap`): the roundabouts are ranked by
the turns they need, and the loop runs over half the batch, its j-th lane
taking every turn of the j-th busiest roundabout, then every turn of the
j-th least busy one. The loop runs as long as the longest pair (44.6
turns on average for the batch above, at half its width: 57% of the
turns computed before; the changer alone took 30-33 ms per call instead
of 39-40 there, docs/benchmarks.md). Each roundabout still takes its
turns one after another, as the same `ring_turns.take`, so its changes
and memory are those of `turns_of_vehicles`
(`tests/unit/test_ring_turns.py`; floats to their rounding, which XLA may
do in another order for another batch).

Shapes: B roundabouts, H = ceil(B / 2) lanes of the loop, M vehicle slots.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap

from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.ring_changer import (
    Context,
    RingArrays,
    RingChanges,
    RingVehicles,
    changes,
    context,
)
from jaxround.lanes.ring_turns import (
    first_carry,
    first_outcome,
    for_changes,
    scan_gradient,
    take,
    turns_of_vehicles,
)
from jaxround.lanes.views import Memory


def _axes(batched: Any) -> Any:
    return jax.tree.map(lambda b: 0 if b else None, batched)


def _rows(tree: Any, axes: Any, index: jax.Array) -> Any:
    """``tree``'s batched leaves at rows ``index``, the others as they are
    (``axes``: 0 or None, a tree prefix of ``tree``)."""
    return jax.tree.map(
        lambda a, x: x if a is None else jax.tree.map(lambda y: y[index], x),
        axes, tree, is_leaf=lambda a: a is None,
    )  # fmt: skip


def pairs(n_turns: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The loop's lanes for (B,) ``n_turns``: (first, second, paired), (H,)
    each: lane j takes the j-th busiest roundabout, then the j-th least busy
    (``paired`` False: none, the middle one of an odd batch; ``second`` is
    then ``first``)."""
    half = (n_turns.shape[0] + 1) // 2
    busiest = jnp.argsort(-n_turns, stable=True)
    first, second = busiest[:half], busiest[::-1][:half]
    paired = jnp.arange(half) < n_turns.shape[0] - half
    return first, jnp.where(paired, second, first), paired


def _batched_turns(
    dt: float,
    axis_size: int,
    in_batched: tuple,
    net: RingArrays,
    veh: RingVehicles,
    memory: Memory,
    lc: LaneChangeParams,
) -> tuple[tuple[RingChanges, Memory], Any]:
    """`custom_vmap` rule of `turns_of_batch`: B = ``axis_size`` roundabouts
    (``in_batched``: which leaves of each argument carry the batch axis)."""
    net_axes, veh_axes, memory_axes, lc_axes = (_axes(b) for b in in_batched)
    # the vehicles and their memory are the batch; broadcast any left unbatched
    veh, memory = (
        jax.tree.map(
            lambda x, a: x if a == 0 else jnp.broadcast_to(x, (axis_size, *x.shape)),
            tree,
            axes,
        )  # fmt: skip
        for tree, axes in ((veh, veh_axes), (memory, memory_axes))
    )
    axes = (net_axes, 0, lc_axes, 0)  # of (net, veh, lc, standing)

    def where_they_stand(net_b, veh_b, lc_b) -> tuple:  # noqa: ANN001
        return tuple(context(net_b, veh_b, lc_b, dt)[4:])

    standing = jax.vmap(where_they_stand, in_axes=axes[:3])(net, veh, lc)
    roundabouts = (net, veh, lc, standing)

    def start(net_b, veh_b, lc_b, standing_b, memory_b) -> tuple:  # noqa: ANN001
        ctx = Context(net_b, veh_b, lc_b, dt, *standing_b)
        carry = first_carry(ctx, memory_b)
        return carry, first_outcome(ctx, carry)

    def lane_turn(a, b, n_a, n_b, t, state_a, state_b) -> tuple:  # noqa: ANN001
        """Turn t of a loop lane: turn t of roundabout a, else turn t - n_a of
        b (past the end of both: a turn whose outcome is dropped)."""
        on_a = t < n_a
        pick = functools.partial(jax.tree.map, lambda x, y: jnp.where(on_a, x, y))
        net_r, veh_r, lc_r, standing_r = pick(a, b)
        carry, outcome = pick(state_a, state_b)
        ctx = Context(net_r, veh_r, lc_r, dt, *standing_r)
        local = jnp.where(on_a, t, t - n_a)
        i = ctx.order[local]
        carry, out = take(ctx, carry, i)
        outcome = jax.tree.map(
            lambda every, x: every.at[i].set(x), outcome, for_changes(out)
        )
        new = (carry, outcome)
        takes_b = ~on_a & (local < n_b)
        return (
            pick(new, state_a),
            jax.tree.map(lambda x, y: jnp.where(takes_b, x, y), new, state_b),
        )

    n_turns = jnp.sum(standing[-1], axis=1)  # decides: (B,)
    first, second, paired = pairs(n_turns)
    n_first, n_second = n_turns[first], jnp.where(paired, n_turns[second], 0)
    a, b = _rows(roundabouts, axes, first), _rows(roundabouts, axes, second)
    begin = jax.vmap(start, in_axes=(*axes, 0))
    state_a = begin(*a, jax.tree.map(lambda x: x[first], memory))
    state_b = begin(*b, jax.tree.map(lambda x: x[second], memory))
    turn = jax.vmap(lane_turn, in_axes=(axes, axes, 0, 0, None, 0, 0))

    def next_turn(loop: tuple) -> tuple:
        t, state_a, state_b = loop
        return (t + 1, *turn(a, b, n_first, n_second, t, state_a, state_b))

    longest = jnp.max(n_first + n_second)
    _, state_a, state_b = jax.lax.while_loop(
        lambda loop: loop[0] < longest, next_turn,
        (jnp.zeros((), jnp.int32), state_a, state_b),
    )  # fmt: skip
    # back to the batch's order: each roundabout from the lane that took it
    lanes = jnp.arange(first.shape[0])
    lane_of = jnp.zeros(axis_size, jnp.int32).at[second].set(lanes).at[first].set(lanes)
    is_first = jnp.zeros(axis_size, bool).at[first].set(True)
    (memory, outcome) = jax.tree.map(
        lambda x, y: jnp.where(
            is_first.reshape((-1,) + (1,) * (x.ndim - 1)), x[lane_of], y[lane_of]
        ),
        (state_a[0][-1], state_a[1]), (state_b[0][-1], state_b[1]),
    )  # fmt: skip

    def finish(net_b, veh_b, lc_b, standing_b, outcome_b) -> RingChanges:  # noqa: ANN001
        return changes(Context(net_b, veh_b, lc_b, dt, *standing_b), outcome_b)

    result = jax.vmap(finish, in_axes=(*axes, 0))(*roundabouts, outcome)
    out = (result, memory)
    return out, jax.tree.map(lambda _: True, out)


@functools.cache
def _for_step(dt: float) -> Any:
    @custom_vmap
    def turns(net, veh, memory, lc):  # noqa: ANN001, ANN202
        return turns_of_vehicles(net, veh, memory, lc, dt)

    turns.def_vmap(functools.partial(_batched_turns, dt))
    return turns


def turns_of_batch(
    net: RingArrays,
    veh: RingVehicles,
    memory: Memory,
    lc: LaneChangeParams,
    dt: float,
) -> tuple[RingChanges, Memory]:
    """`ring_turns.turns_of_vehicles`; under `jax.vmap`, two roundabouts to
    a lane of the batch (the module's docstring)."""
    return _for_step(float(dt))(net, veh, memory, lc)


#: Every vehicle's lane change for one step, one turn after another in
#: SUMO's order (`ring_turns`, its gradient too), batched as above:
#: ``change_lanes(net, veh, memory, lc, dt) -> (RingChanges, Memory)``;
#: `veh` after this step's move, `memory` after
#: `jaxround.lanes.memory.prepare_step`, `lc` scalars or (M,).
change_lanes = scan_gradient(turns_of_batch)
