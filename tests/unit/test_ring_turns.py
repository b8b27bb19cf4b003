"""The two-lane changer's turns (`jaxround.lanes.ring_turns`): the loop over
the vehicles gives what the scan over every slot gives, its gradient is the
scan's (`jaxround.lanes.ring_rounds` shares the same backward pass), and a vehicle
inserted into a slot starts with LC2013's memory cleared, as a new vehicle
in SUMO does."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.envs.rollout import uncontrolled_policy
from jaxround.envs.roundabout import make
from jaxround.lanes import ring_batches, ring_changer, ring_turns
from jaxround.lanes.views import Memory
from jaxround.scenario.schedule import make_schedule
from tests.conftest import TWO_LANE_SLOTS

#: Steps run (0.5 s each): the ring has filled and vehicles come and go.
STEPS = 480


def is_fresh(memory: Memory) -> jax.Array:
    """bool (M,): the slot's memory is a new vehicle's (`Memory.zeros`)."""
    return (
        (memory.state == 0)
        & (memory.speed_gain_probability == 0)
        & (memory.keep_right_probability == 0)
        & (memory.look_ahead_speed == 0)
        & jnp.all(jnp.isnan(memory.advices), axis=-1)
    )


@pytest.fixture(scope="module")
def episode():
    """Four minutes of two_lane.yaml's human drivers: each step's state
    after it (stacked), and how many vehicles entered a slot in it and did
    so with memory left in the slot."""
    env, params = make("two_lane", max_vehicles=TWO_LANE_SLOTS)
    policy = uncontrolled_policy(env)
    schedule = env.schedule_from_numpy(make_schedule(env.cfg, seed=0))
    obs, state = env.reset_to_schedule(schedule, params)

    def step(carry, key):
        obs, before = carry
        act_key, step_key = jax.random.split(key)
        action = policy(obs, before, act_key)
        obs, after, *_ = env.step(step_key, before, action, params)
        entered = after.active & ~before.active
        stale = entered & ~is_fresh(after.lanes.memory)
        return (obs, after), (after, jnp.sum(entered), jnp.sum(stale))

    keys = jax.random.split(jax.random.PRNGKey(0), STEPS)
    run = jax.jit(lambda carry, keys: jax.lax.scan(step, carry, keys)[1])
    return env, params, run((obs, state), keys)


def test_a_new_vehicle_starts_with_cleared_memory(episode) -> None:
    _, _, (states, entered, stale) = episode
    assert int(entered.sum()) > 100
    assert int(stale.sum()) == 0
    # and an empty slot keeps nothing between vehicles
    empty = ~states.active
    assert not bool(jnp.any(empty & ~is_fresh(states.lanes.memory)))


def assert_same_numbers(got, want) -> None:
    """Integers and booleans equal, floats to float32 rounding: XLA compiles
    the loop, the scan and each batch shape apart, and may round a sum or a
    fused multiply-add differently (1-2 ulp seen)."""
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if np.issubdtype(a.dtype, np.floating):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
        else:
            np.testing.assert_array_equal(a, b)


def test_the_vehicles_turns_are_every_slots_turns(episode) -> None:
    """On every eighth of the last 200 steps' states, the loop and the scan
    give the same changes and memory (floats to their rounding), and the
    CPU's changer has a finite gradient, the scan's."""
    env, params, (states, _, _) = episode
    changer = env.lane_changer
    lc = params.lane_change
    dt = changer.dt
    loop = jax.jit(ring_turns.turns_of_vehicles, static_argnums=4)
    scan = jax.jit(ring_turns.turns_of_every_slot, static_argnums=4)
    context = jax.jit(ring_changer.context, static_argnums=3)
    moved = 0
    for t in range(STEPS - 200, STEPS, 8):
        state = jax.tree.map(lambda x, t=t: x[t], states)
        veh, memory = changer.vehicles(state)
        assert 0 < int(veh.active.sum()) < veh.active.shape[0]
        got, want = (
            loop(changer.arrays, veh, memory, lc, dt),
            scan(changer.arrays, veh, memory, lc, dt),
        )
        (changes, after), (changes_all, after_all) = got, want
        # what an empty slot saw is no one's business, nor what a vehicle on
        # an edge without a changer (SUMO does not look there): the others'
        on = np.asarray(context(changer.arrays, veh, lc, dt).decides)
        assert on.sum() > 0
        for a, b in zip(
            jax.tree.leaves(changes.sight), jax.tree.leaves(changes_all.sight),
            strict=True,
        ):  # fmt: skip
            np.testing.assert_array_equal(np.asarray(a)[on], np.asarray(b)[on])
        mine = (changes._replace(sight=None), after)
        every = (changes_all._replace(sight=None), after_all)
        assert_same_numbers(mine, every)
        moved += int(jnp.sum(changes.direction != 0))
    assert moved > 0

    def summary(change, speed):
        changes, after = change(
            changer.arrays, veh._replace(speed=speed), memory, lc, dt
        )
        return jnp.sum(changes.pos) + jnp.sum(after.look_ahead_speed)

    # the CPU's changer; its backward pass is the scan's pullback at the
    # same inputs (`ring_turns.scan_gradient`, which the GPUs' `ring_rounds`
    # shares): taking the scan's own gradient as well compiled the same
    # backward twice, 50 s of CI for an equality by construction
    grad = jax.jit(jax.grad(lambda v: summary(ring_batches.change_lanes, v)))
    got = np.asarray(grad(veh.speed))
    assert np.all(np.isfinite(got))
    assert np.any(got[np.asarray(veh.active)] != 0)


@pytest.mark.parametrize("batch", [7])
def test_a_batch_two_to_a_lane_takes_each_roundabouts_turns(episode, batch) -> None:
    """Under `vmap`, `ring_batches` (two roundabouts to a lane of the loop,
    an odd batch leaving one alone: three pairs and one) gives each
    roundabout the changes and memory of its own loop (`turns_of_vehicles`),
    per-roundabout parameters and a second `vmap` included."""
    env, params, (states, _, _) = episode
    changer = env.lane_changer
    dt = changer.dt
    steps = np.linspace(STEPS - 200, STEPS - 1, batch).astype(int)
    batched = jax.tree.map(lambda x: x[steps], states)
    veh, memory = jax.vmap(changer.vehicles)(batched)
    lc = jax.tree.map(
        lambda x: jnp.broadcast_to(x, (batch,)), params.lane_change
    ).replace(cooperative=jnp.linspace(0.2, 1.0, batch))
    turns = ring_changer.context
    n_turns = jax.vmap(lambda v, p: turns(changer.arrays, v, p, dt).decides.sum())(
        veh, lc
    )
    assert len(set(np.asarray(n_turns).tolist())) > 2  # the pairs differ

    def one(change):
        return lambda v, m, p: change(changer.arrays, v, m, p, dt)

    want = jax.jit(jax.vmap(one(ring_turns.turns_of_vehicles)))(veh, memory, lc)
    got = jax.jit(jax.vmap(one(ring_batches.change_lanes)))(veh, memory, lc)
    twice = jax.jit(jax.vmap(jax.vmap(one(ring_batches.change_lanes))))(
        *jax.tree.map(lambda x: jnp.stack([x, x]), (veh, memory, lc))
    )
    assert int(jnp.sum(want[0].direction != 0)) > 0
    for result in (got, jax.tree.map(lambda x: x[1], twice)):
        assert_same_numbers(result, want)


def test_the_changer_drives_with_the_steps_car_following_numbers(episode) -> None:
    """Given the step's per-vehicle numbers (`EnvParams.for_vehicles`, any
    retuning included), the changer's drivers are those, as SUMO's LC2013
    reads a vehicle's own (a TraCI ``setTau`` included): with a headway of
    5 s its safety gaps refuse changes the vType's 1.35 s allows (10
    changes against 14 in these states; 3 s refused none of them once the
    edges took their turns in SUMO's order)."""
    env, params, (states, _, _) = episode
    changer = env.lane_changer
    lc = params.lane_change
    loop = jax.jit(ring_turns.turns_of_vehicles, static_argnums=4)
    slow = params.with_human(tau=jnp.float32(5.0))
    moved, moved_slow = 0, 0
    for t in range(STEPS - 200, STEPS, 8):
        state = jax.tree.map(lambda x, t=t: x[t], states)
        veh, memory = changer.vehicles(state, car=params.for_vehicles(state.is_av))
        # the vType's numbers, as the changer read them before it took the step's
        want, _ = changer.vehicles(state)
        assert_same_numbers(veh.driver, want.driver)
        veh_slow, _ = changer.vehicles(state, car=slow.for_vehicles(state.is_av))
        np.testing.assert_allclose(np.asarray(veh_slow.driver.tau), 5.0)
        moved += int(
            jnp.sum(loop(changer.arrays, veh, memory, lc, changer.dt)[0].direction != 0)
        )
        moved_slow += int(
            jnp.sum(
                loop(changer.arrays, veh_slow, memory, lc, changer.dt)[0].direction != 0
            )
        )
    assert moved_slow < moved
