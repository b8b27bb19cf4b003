"""A batch of runs in chunks with a progress bar
(`jaxround.envs.rollout.runs_until_left`) ends in the states one
`run_until_left` per run gives: the same trips and integers to the bit, the
float sums to rounding."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.envs.rollout import run_until_left, runs_until_left, uncontrolled_policy
from jaxround.envs.roundabout import make
from jaxround.scenario.schedule import make_schedule


def test_chunks_give_the_states_of_one_loop(capsys) -> None:
    env, params = make("milan", max_vehicles=32, episode_s=150.0)
    schedules = [
        env.schedule_from_numpy(make_schedule(env.cfg, seed=s, penetration=0.5))
        for s in (0, 1, 2)
    ]
    batch = jax.tree.map(lambda *xs: np.stack(xs), *schedules)
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    flags = jnp.array([True, False, True])
    uncontrolled = uncontrolled_policy(env)

    def braking(obs, state, key):  # a policy the flag switches on
        del obs, key
        return jnp.where(state.is_av[:, None], jnp.array([[-1.0, jnp.nan]]), jnp.nan)

    def policy_of(flag):
        return lambda obs, state, key: jax.lax.cond(
            flag, braking, uncontrolled, obs, state, key
        )

    def one(schedule, key, flag):
        return run_until_left(env, params, schedule, key, policy_of(flag))

    want = jax.jit(jax.vmap(one))(batch, keys, flags)
    got = runs_until_left(
        env, params, batch, keys, policy_of, flags, desc="test", chunk_s=40.0
    )
    assert int(want.step.max()) > 40.0 / env.dt  # more than one chunk
    leaves = jax.tree_util.tree_leaves_with_path
    for (path, a), (_, b) in zip(leaves(got), leaves(want), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype.kind == "f":  # XLA may fuse the chunks' sums differently:
            # positions drift by float32 steps (1.3e-5 m at 13 m), and a time
            # to collision, a ratio, by 3e-5 of itself (2026-12-02)
            np.testing.assert_allclose(a, b, rtol=1e-4, err_msg=str(path))
        else:
            np.testing.assert_array_equal(a, b, err_msg=str(path))
    # the trips themselves are the same to the bit
    np.testing.assert_array_equal(np.asarray(got.arrival_s), np.asarray(want.arrival_s))
    assert "test" in capsys.readouterr().err  # the progress bar
