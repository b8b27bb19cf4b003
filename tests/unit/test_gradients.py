"""Gradients through the dynamics: finite, right (finite differences), and
the relaxed dynamics converge to the exact ones as the temperature goes to 0.

Compiling the backward pass takes most of this module's time (with the few
optimisations every test compiles with, `conftest.pytest_configure`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.analysis.survey import CALIBRATABLE, measured_rollout
from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs.rollout import make_episode_runner, uncontrolled_policy
from jaxround.envs.roundabout import RoundaboutEnv, make
from jaxround.scenario.schedule import make_schedule

#: Steps of the window the gradients are taken over (10 s).
WINDOW = 20
#: Consecutive states whose single next step is checked for the gap parameters.
GATE_STEPS = 40
#: The gap parameters act only through the entry's gap acceptance.
GAP_PARAMS = ("jm_timegap_minor", "impatience")


@pytest.fixture(scope="module")
def busy() -> tuple[RoundaboutEnv, EnvParams, EnvState, jax.Array]:
    """A busy state after 5 minutes of the default scenario, and the driver
    numbers as x0 (7,)."""
    env, params = make("milan", max_vehicles=32)
    sched = env.schedule_from_numpy(make_schedule(env.cfg, seed=0))
    state = make_episode_runner(env, n_steps=600)(params, sched, jax.random.PRNGKey(0))
    x0 = jnp.array([float(params.human_number(k)) for k in CALIBRATABLE], jnp.float32)
    return env, params, state, x0


def with_drivers(params: EnvParams, x: jax.Array, temperature: jax.Array) -> EnvParams:
    """`params` with the CALIBRATABLE numbers `x` (7,) and a temperature."""
    fields = {k: x[i] for i, k in enumerate(CALIBRATABLE)}
    return params.with_human(**fields).replace(relax_temperature=temperature)


@pytest.fixture(scope="module")
def window(busy):
    """The window's metric as a function of the driver numbers, with no more
    departures (insertion is not relaxed)."""
    env, params, state, x0 = busy
    later = jnp.where(state.inserted, state.schedule.depart_s, 1e9)
    state = state.replace(schedule=state.schedule.replace(depart_s=later))
    obs = env.observation(state, params)

    def metric(x: jax.Array, temperature: jax.Array) -> jax.Array:
        p = with_drivers(params, x, temperature)
        end, queues, in_network = measured_rollout(
            env, p, obs, state, WINDOW, remat=False
        )
        co2_g = (jnp.sum(end.stats.trip_co2_mg) + jnp.sum(end.co2_mg)) / 1000.0
        return jnp.sum(in_network) * env.dt + 10 * jnp.sum(queues) * env.dt + co2_g

    # one compiled program gives both (compiling takes longer than running)
    value_and_grad = jax.jit(jax.value_and_grad(metric))
    return (
        int(state.active.sum()),
        x0,
        lambda x, t: value_and_grad(x, t)[0],
        lambda x, t: value_and_grad(x, t)[1],
    )


def test_relaxed_metric_converges_to_the_exact_one(window) -> None:
    n_active, x0, metric, _ = window
    assert n_active >= 10
    exact = float(metric(x0, jnp.float32(0.0)))
    gaps = [abs(float(metric(x0, jnp.float32(t))) - exact) for t in (1.0, 0.1, 1e-3)]
    assert gaps[0] > 0.0  # the relaxation changes something at 1
    assert gaps[0] >= gaps[1] >= gaps[2]
    assert gaps[2] < 1e-3 * abs(exact)


def test_gradients_are_finite_and_match_finite_differences(window) -> None:
    _, x0, metric, grad = window
    temperature = jnp.float32(0.5)
    g = np.asarray(grad(x0, temperature))
    assert np.all(np.isfinite(g)), dict(zip(CALIBRATABLE, g, strict=True))
    checked = 0
    for i, name in enumerate(CALIBRATABLE):
        h = 1e-3 * float(x0[i])
        e = jnp.zeros_like(x0).at[i].set(h)
        fd = float(metric(x0 + e, temperature)) - float(metric(x0 - e, temperature))
        fd /= 2 * h
        if abs(fd) < 1e-2 and abs(g[i]) < 1e-2:
            continue  # this parameter does not act within the window
        assert abs(g[i] - fd) <= 0.05 * abs(fd), (name, g[i], fd)
        checked += 1
    assert checked >= 4  # accel, decel, tau, min_gap, delta act in 10 s


def test_gradients_stay_finite_at_zero_temperature(window) -> None:
    _, x0, _, grad = window
    g = np.asarray(grad(x0, jnp.float32(0.0)))
    assert np.all(np.isfinite(g))
    assert abs(g[CALIBRATABLE.index("accel")]) > 0  # speeds still carry gradients


def test_gap_parameters_match_finite_differences_where_the_gate_is_smooth(
    busy,
) -> None:
    """jm_timegap_minor and impatience act only where a vehicle weighs a gap,
    and the window above rarely holds one near its threshold. Here each of
    GATE_STEPS consecutive states is stepped once at temperature 1 s; where
    the step's outcome is smooth in the parameter (central differences with h
    and 2h agree within 1%) and the parameter acts (the difference spans at
    least 50 float32 steps of the outcome), the gradient must agree with them
    within 5%, and both parameters must act somewhere."""
    env, params, state, x0 = busy
    policy = uncontrolled_policy(env)
    key = jax.random.PRNGKey(2)

    def exact_step(s: EnvState, k: jax.Array) -> tuple[EnvState, EnvState]:
        obs = env.observation(s, params)
        _, nxt, *_ = env.step_env(k, s, policy(obs, s, k), params)
        return nxt, s

    keys = jax.random.split(jax.random.PRNGKey(1), GATE_STEPS)
    _, states = jax.jit(lambda s: jax.lax.scan(exact_step, s, keys))(state)

    def outcome(x: jax.Array, s: EnvState) -> jax.Array:
        p = with_drivers(params, x, jnp.float32(1.0))
        obs = env.observation(s, p)
        _, nxt, *_ = env.step_env(key, s, policy(obs, s, key), p)
        # the step's displacement, not the position: float32 positions of
        # 100 m round to 8e-6 m, as large as a 1% difference's effect
        return jnp.sum(nxt.speed) + jnp.sum((nxt.pos - s.pos) * nxt.active)

    # one program for the outcomes and their gradients (it compiles once)
    value_and_grad = jax.jit(jax.vmap(jax.value_and_grad(outcome), (None, 0)))
    grads = np.asarray(value_and_grad(x0, states)[1])
    assert np.all(np.isfinite(grads))

    def central(i: int, rel: float) -> tuple[np.ndarray, np.ndarray]:
        """The central difference, and whether it spans enough float32
        steps of the outcome (a few hundred m/s summed) to be read."""
        e = jnp.zeros_like(x0).at[i].set(rel * float(x0[i]))
        up, down = value_and_grad(x0 + e, states)[0], value_and_grad(x0 - e, states)[0]
        up, down = np.asarray(up), np.asarray(down)
        resolved = np.abs(up - down) > 50 * np.spacing(np.abs(up))
        return (up - down) / (2 * float(e[i])), resolved

    for name in GAP_PARAMS:
        i = CALIBRATABLE.index(name)
        (fd, resolved), (fd2, _) = central(i, 1e-2), central(i, 2e-2)
        smooth = np.abs(fd - fd2) <= 0.01 * np.abs(fd)
        acts = (np.abs(fd) > 1e-2) & resolved
        checked = np.nonzero(smooth & acts)[0]
        assert checked.size >= 1, (name, fd.tolist(), fd2.tolist())
        g = grads[checked, i]
        assert np.all(np.abs(g - fd[checked]) <= 0.05 * np.abs(fd[checked])), (
            name, checked.tolist(), g.tolist(), fd[checked].tolist(),
        )  # fmt: skip
