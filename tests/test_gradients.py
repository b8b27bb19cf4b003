"""Gradients through the dynamics: finite, right (finite differences), and
the relaxed dynamics converge to the exact ones as the temperature goes to 0."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.env import make
from jaxround.rollout import make_episode_runner
from jaxround.schedule import make_schedule
from jaxround.survey import CALIBRATABLE, measured_rollout

#: Steps of the window the gradients are taken over (10 s).
WINDOW = 20


@pytest.fixture(scope="module")
def window():
    """A busy state after 5 minutes of the default scenario, no more
    departures, and the window's metric as a function of the driver numbers."""
    env, params = make("milan", max_vehicles=32)
    sched = env.schedule_from_numpy(make_schedule(env.cfg, seed=0))
    state = make_episode_runner(env, n_steps=600)(params, sched, jax.random.PRNGKey(0))
    later = jnp.where(state.inserted, state.schedule.depart_s, 1e9)
    state = state.replace(schedule=state.schedule.replace(depart_s=later))
    obs = env.observation(state, params)

    def metric(x: jax.Array, temperature: jax.Array) -> jax.Array:
        p = params.replace(
            relax_temperature=temperature,
            **{k: x[i] for i, k in enumerate(CALIBRATABLE)},
        )
        end, queues, in_network = measured_rollout(
            env, p, obs, state, WINDOW, remat=False
        )
        co2_g = (jnp.sum(end.trip_co2_mg) + jnp.sum(end.co2_mg)) / 1000.0
        return jnp.sum(in_network) * env.dt + 10 * jnp.sum(queues) * env.dt + co2_g

    x0 = jnp.array([float(getattr(params, k)) for k in CALIBRATABLE], jnp.float32)
    return int(state.active.sum()), x0, jax.jit(metric), jax.jit(jax.grad(metric))


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
