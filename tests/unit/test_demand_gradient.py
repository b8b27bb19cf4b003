"""The demand's score-function gradient (`jaxround.analysis.demand_gradient`): exact in
expectation against an analytic case, and consistent with finite differences
of the batch mean through whole rollouts."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.analysis import demand_gradient as dg
from jaxround.core.params import EnvParams
from jaxround.envs.roundabout import RoundaboutEnv, make
from tests.conftest import fully_optimised, small_config


@pytest.fixture(scope="module")
def small() -> tuple[RoundaboutEnv, EnvParams]:
    return make(small_config(n_vehicles=40, duration_s=120.0), max_vehicles=16)


def test_score_gradient_matches_an_analytic_expectation(small) -> None:
    # E[share of the vehicles from leg 0] = s_0 / sum(s), whose gradient is
    # known; it does not depend on the destinations, so od gets almost none
    env, params = small
    keys = jax.random.split(jax.random.PRNGKey(0), 20_000)

    def estimate(p: EnvParams) -> jax.Array:
        frozen = jax.lax.stop_gradient(p)
        drawn = jax.vmap(env.draw_schedule, in_axes=(0, None))(keys, frozen)
        values = jax.vmap(lambda s: jnp.mean(s.origin == 0))(drawn)
        log_probs = jax.vmap(lambda s: dg.schedule_log_prob(env, s, p))(drawn)
        return dg.surrogate(values, log_probs)

    value, grad = jax.jit(jax.value_and_grad(estimate))(params)
    s = np.asarray(params.demand.origin_share, np.float64)
    total = s.sum()
    assert float(value) == pytest.approx(s[0] / total, abs=0.005)
    analytic = (np.eye(len(s))[0] * total - s[0]) / total**2
    np.testing.assert_allclose(
        np.asarray(grad.demand.origin_share), analytic, atol=0.03
    )
    od = np.asarray(params.demand.od)
    g_od = np.asarray(grad.demand.od)
    assert np.all(g_od[od == 0] == 0)  # never drawn: no gradient, not a biased one
    np.testing.assert_allclose(g_od, 0.0, atol=0.03)


def test_score_gradient_agrees_with_finite_differences_of_rollouts(small) -> None:
    env, params = small
    f = dg.expected_metric(
        env, dg.mean_crossing_time, jax.random.PRNGKey(1), 128, n_steps=240
    )
    # one program for both: the backward pass is only through the log-probs;
    # five batches of 128 episodes run, so it is compiled fully
    value_and_grad = jax.jit(jax.value_and_grad(f))
    with fully_optimised():
        value, grad = value_and_grad(params)
    assert float(value) > 0
    od = np.asarray(params.demand.od)
    assert np.all(np.asarray(grad.demand.od)[od == 0] == 0)
    # from leg 0, the next exit and the farthest: more of one shortens the
    # mean crossing, more of the other lengthens it
    h = 0.05
    for j in (1, 3):

        def od_at(step: float, j: int = j) -> EnvParams:
            od = params.demand.od.at[0, j].add(step)
            return params.replace(demand=params.demand.replace(od=od))

        up, down = od_at(h), od_at(-h)
        fd = float(value_and_grad(up)[0] - value_and_grad(down)[0]) / (2 * h)
        g = float(grad.demand.od[0, j])
        assert abs(fd) > 0.5, fd
        assert 0.5 < g / fd < 2.0, (j, g, fd)


def test_bad_batches_are_refused(small) -> None:
    env, _ = small
    with pytest.raises(ValueError, match="n_episodes"):
        dg.expected_metric(env, dg.mean_queue, jax.random.PRNGKey(0), 1)
    with pytest.raises(ValueError, match="2 episodes"):
        dg.leave_one_out_baseline(jnp.ones(1))
