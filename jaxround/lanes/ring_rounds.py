"""Every vehicle's lane-change turn at once, in rounds until nothing moves:
the changes, memory and sight of `jaxround.lanes.ring_batches.change_lanes`
without its M turns one after another.

A turn depends only on the turns before it in SUMO's order
(`MSLaneChanger::laneChange`, front to back): the lanes they left, the
vehicles they registered blocked, the messages they sent
(`informLeader`/`informFollower`). A round gives every vehicle its turn as
the previous round's outcomes say the turns before it went (a Jacobi
sweep over the sequential order). The first turn is right after one
round, the n-th after n rounds at the latest, and a round that changes
none of what the turns hand on to later turns has reached the one outcome
that agrees with every turn before it, which is the sequential one. Each
round is (M, M) work done at once; in two_lane.yaml's traffic one to three
rounds settle a step, 1.9 on average (`jaxround.apps.ring_lane_replay`
counts them). Run batched, a batch takes the rounds of its slowest step.

Which to use: on a GPU the rounds, on a CPU the turns one by one (the
rounds repeat the work; measured by `jaxround.apps.bench.changer`,
docs/lc2013-map.md section 12).

Shapes: M vehicle slots, A advices per vehicle.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxround.lanes import actions as lca
from jaxround.lanes.decide import Kept, Told
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.ring_changer import (
    Outcome,
    RingArrays,
    RingChanges,
    RingVehicles,
    View,
    changes,
    context,
    turn,
)
from jaxround.lanes.ring_turns import scan_gradient
from jaxround.lanes.views import N_ADVICES, Memory


def smallest(advices: jax.Array, more: jax.Array) -> jax.Array:
    """The A smallest of (A,) ``advices`` and (N,) ``more`` (NaN: empty; an
    advice may be inf), what `push_advice` keeps of them pushed one by one
    (in another order). By counting, not sorting: N is small."""
    both = jnp.concatenate([advices, more])
    key = jnp.where(
        jnp.isnan(both), jnp.inf, jnp.minimum(both, jnp.finfo(both.dtype).max)
    )
    index = jnp.arange(both.shape[0])
    ahead = (key[None, :] < key[:, None]) | (
        (key[None, :] == key[:, None]) & (index[None, :] < index[:, None])
    )
    place = jnp.sum(ahead, axis=1)  # distinct places 0 .. A + N - 1
    at = place[None, :] == jnp.arange(advices.shape[0])[:, None]  # (A, A + N)
    return jnp.where(jnp.any(at, axis=1), both[jnp.argmax(at, axis=1)], jnp.nan)


def _kept_wishes(out: Outcome) -> jax.Array:
    """int (M,) each turn's own state as later turns read it (a vehicle
    that changed keeps none: `changed()`)."""
    return jnp.where(out.direction != 0, 0, out.state)


def _handed_on(out: Outcome, rank: jax.Array) -> tuple[jax.Array, ...]:
    """What a round's turns hand on to the turns after them: the lanes they
    leave, their registrations as blocked, the wishes they keep (read by
    `saveBlockerLength`), and the messages whose receiver has its turn later
    (the others change nothing this step)."""
    told = out.told
    later = rank[told.slot] > rank[:, None]  # (M, 4)
    real = later & (~jnp.isnan(told.speed) | (told.bits != 0))
    wished = _kept_wishes(out) & lca.WANTS_LANECHANGE
    return (
        out.to_lane,
        wished,
        out.blocked,
        jnp.where(out.blocked, out.target, -1),
        jnp.where(real, told.slot, -1),
        jnp.where(real, jnp.where(jnp.isnan(told.speed), -jnp.inf, told.speed), 0.0),
        jnp.where(real, told.bits, 0),
    )


def _same(old: tuple[jax.Array, ...], new: tuple[jax.Array, ...]) -> jax.Array:
    return jnp.all(jnp.stack([jnp.all(a == b) for a, b in zip(old, new, strict=True)]))


def turns_in_rounds(
    net: RingArrays,
    veh: RingVehicles,
    memory: Memory,
    lc: LaneChangeParams,
    dt: float,
) -> tuple[RingChanges, Memory, jax.Array]:
    """`jaxround.lanes.ring_batches.change_lanes`, in rounds (`change_lanes`:
    with the gradient of the turns one by one, `ring_turns.scan_gradient`).

    Returns:
        (changes, memory, rounds): as the sequential changer's (advices in
        another order within a row), and the rounds it took (int).
    """
    ctx = context(net, veh, lc, dt)
    m = veh.pos.shape[0]
    slots = jnp.arange(m)
    rank = jnp.zeros(m, jnp.int32).at[ctx.order].set(jnp.arange(m, dtype=jnp.int32))
    before = rank[None, :] < rank[:, None]  # (M, M): j's turn before i's

    def views(out: Outcome) -> View:
        """Every vehicle's view at its turn, from the outcomes of the turns
        before it; (M, ...) each."""
        registered = before & jnp.any(
            out.blocked[None] & (out.target[None] == ctx.lane[:, None, None]), axis=2
        )  # (M, M): j registered blocked on i's lane before i's turn
        anyone = jnp.any(registered, axis=1)
        last = jnp.argmax(jnp.where(registered, rank[None], -1), axis=1)
        first = jnp.argmin(jnp.where(registered, rank[None], m), axis=1)
        bits, advices = inbox(out.told, rank[:, None] < rank[out.told.slot], m)
        return View(
            lane=jnp.where(before, out.to_lane[None], ctx.lane[None]),
            done=before,
            last_blocked=jnp.where(anyone, last, -1),
            first_blocked=jnp.where(anyone, first, -1),
            state=memory.state | bits,
            advices=jax.vmap(smallest)(memory.advices, advices),
            states=jnp.where(before, _kept_wishes(out)[None], memory.state[None]),
        )

    def one_round(out: Outcome) -> Outcome:
        return jax.vmap(lambda i, view: turn(ctx, i, view, memory))(slots, views(out))

    # before the first round nobody has moved, registered or told anything
    def alone(i: jax.Array) -> Outcome:
        none = jnp.asarray(-1)
        view = View(ctx.lane, jnp.zeros(m, bool), none, none, memory.state[i],
                    memory.advices[i], memory.state)  # fmt: skip
        return turn(ctx, i, view, memory)

    zeros = jax.tree.map(
        lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(jax.vmap(alone), slots)
    )
    blank = zeros._replace(
        state=memory.state,
        kept=Kept(
            memory.speed_gain_probability, memory.keep_right_probability,
            memory.look_ahead_speed, memory.advices, memory.left_space,
            memory.blocker_length,
        ),
        to_lane=ctx.lane,
        to_path=veh.path,
        told=zeros.told._replace(
            slot=jnp.full_like(zeros.told.slot, -1),
            speed=jnp.full_like(zeros.told.speed, jnp.nan),
        ),
    )  # fmt: skip

    def unsettled(carry):
        rounds, _, moving = carry
        return moving & (rounds <= m)

    def sweep(carry):
        rounds, out, _ = carry
        new = one_round(out)
        return rounds + 1, new, ~_same(_handed_on(out, rank), _handed_on(new, rank))

    start = (jnp.asarray(0), blank, jnp.asarray(True))
    rounds, out, _ = jax.lax.while_loop(unsettled, sweep, start)

    # each vehicle's memory after every turn: what its turn kept (nothing if
    # it changed: `changed()`), then what the turns after it told it
    moved = out.direction != 0
    bits, advices = inbox(out.told, rank[:, None] > rank[out.told.slot], m)
    kept = jax.tree.map(
        lambda x: jnp.where(moved.reshape(-1, *([1] * (x.ndim - 1))), 0, x), out.kept
    )
    memory = Memory(
        state=(jnp.where(moved, 0, out.state) | bits).astype(jnp.int32),
        speed_gain_probability=kept.speed_gain_probability,
        keep_right_probability=kept.keep_right_probability,
        look_ahead_speed=kept.look_ahead_speed,
        left_space=kept.left_space,
        blocker_length=kept.blocker_length,
        advices=jax.vmap(smallest)(
            jnp.where(moved[:, None], jnp.nan, out.kept.advices), advices
        ),
    )
    return changes(ctx, out), memory, rounds


def inbox(told: Told, counted: jax.Array, m: int) -> tuple[jax.Array, jax.Array]:
    """What each of the M vehicles receives of the messages ``told`` ((M, 4)
    each, row: the sender) where ``counted`` (M, 4): the OR of their state
    bits (M,) and their A smallest advices (M, A), NaN-padded."""
    n_advices = N_ADVICES
    slots = jnp.arange(m)
    to = jnp.where(counted, told.slot, m)  # m: nobody
    bits = jnp.bitwise_or.reduce(
        jnp.where(to[None] == slots[:, None, None], told.bits[None], 0), axis=(1, 2)
    )
    speed = told.speed.ravel()
    to_advise = jnp.where(jnp.isnan(speed), m, to.ravel())
    order = jnp.lexsort((jnp.where(jnp.isnan(speed), jnp.inf, speed), to_advise))
    sorted_to, sorted_speed = to_advise[order], speed[order]
    start = jnp.searchsorted(sorted_to, slots, method="compare_all")
    index = jnp.minimum(start[:, None] + jnp.arange(n_advices), speed.shape[0] - 1)
    mine = sorted_to[index] == slots[:, None]
    return bits, jnp.where(mine, sorted_speed[index], jnp.nan)


#: `turns_in_rounds` with the gradient of the turns one by one:
#: ``change_lanes(net, veh, memory, lc, dt) -> (RingChanges, Memory, rounds)``.
change_lanes = scan_gradient(turns_in_rounds)
