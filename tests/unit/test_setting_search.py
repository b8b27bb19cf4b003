"""The search over AV settings: CMA-ES on toy objectives, and the batched
evaluation against a plain uncontrolled run."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxround.analysis.cmaes import minimise
from jaxround.analysis.setting_search import (
    SPACE,
    SearchProblem,
    from_unit,
    search_scenario,
    setting_of,
    to_unit,
    vtype_setting,
)
from jaxround.apps.search import pareto_front
from jaxround.envs.rollout import run_until_left, vehicle_records
from tests.conftest import small_config


def test_cmaes_finds_the_minimum_of_a_quadratic() -> None:
    optimum = np.array([0.3, -1.2, 2.0, 0.7], np.float32)

    def fitness(x: np.ndarray) -> np.ndarray:
        return ((x - optimum) ** 2).sum(1)

    trace = minimise(fitness, np.zeros(4), 0.5, 12, 60, progress=False)
    np.testing.assert_allclose(trace.best, optimum, atol=1e-3)
    assert trace.best_fitness == pytest.approx(trace.fitness.min())
    assert trace.points.shape == (1 + 60 * 12, 4)


def test_cmaes_finds_a_known_setting_at_the_bounds_of_the_box() -> None:
    # a toy objective of the settings whose minimum lies on two bounds: the
    # search in the unit cube must reach them exactly (tau 0.5, cruise none)
    target = setting_of(
        dict(tau=0.5, impatience=0.4, accel=3.5, jm_timegap_minor=1.0, cruise_mps=14.0)
    )
    scale = np.array([hi - lo for lo, hi in SPACE.values()], np.float32)

    def fitness(unit: np.ndarray) -> np.ndarray:
        s = np.asarray(from_unit(unit))
        return (((s - target) / scale) ** 2).sum(1)

    trace = minimise(fitness, np.full(5, 0.5), 0.3, 12, 60, progress=False)
    best = np.asarray(from_unit(trace.best))
    assert np.all(np.abs(best - target) <= 1e-2 * scale), best
    np.testing.assert_allclose(to_unit(target), np.clip(to_unit(target), 0, 1))


def test_minimise_refuses_a_bad_budget() -> None:
    with pytest.raises(ValueError, match="population"):
        minimise(lambda x: x.sum(1), np.zeros(2), population=1)


def test_pareto_front_keeps_the_undominated_points() -> None:
    time_s = np.array([1.0, 2.0, 3.0, 2.5, 1.5])
    co2_g = np.array([5.0, 3.0, 1.0, 4.0, 6.0])
    assert pareto_front(time_s, co2_g).tolist() == [0, 1, 2]


def test_vtype_setting_scores_as_an_uncontrolled_run(tmp_path) -> None:
    """The batched evaluation of the vType's own numbers, without a cruise
    command, is the uncontrolled episode: same crossing times and CO2."""
    cfg = search_scenario(small_config(n_vehicles=30, duration_s=120.0), 120.0)
    problem = SearchProblem(cfg, 0.5, [200, 201], max_vehicles=16)
    scores = problem.score_settings(vtype_setting(cfg)[None])
    env, params = problem.env, problem.params
    states = jax.jit(
        jax.vmap(lambda s: run_until_left(env, params, s, jax.random.PRNGKey(0)))
    )(problem.schedules)
    # fixed blocks of 2 settings x 2 schedules: 3 settings and, after
    # with_seeds, 3 schedules are padded to 2 x 2 blocks of one program
    blocked = SearchProblem(cfg, 0.5, [200, 201], max_vehicles=16, rows=2)
    other = vtype_setting(cfg).copy()
    other[0] = 0.5  # tau
    three = np.stack([vtype_setting(cfg), other, vtype_setting(cfg)])
    in_blocks = blocked.with_seeds([201, 200, 201]).score_settings(three)
    for j in range(2):
        rec = vehicle_records(env, jax.tree.map(lambda x, j=j: x[j], states))
        assert rec.arrived.all() and scores["missing"][0, j] == 0
        assert scores["overflow"][0, j] == 0
        np.testing.assert_allclose(
            scores["time_s"][0, j], rec.crossing_time_s.mean(), rtol=1e-5
        )
        np.testing.assert_allclose(scores["co2_g"][0, j], rec.co2_g.mean(), rtol=1e-5)
    expected = scores["time_s"] + 0.5 * scores["co2_g"]
    np.testing.assert_allclose(scores["objective"], expected, rtol=1e-6)
    for key, values in in_blocks.items():
        assert values.shape == (3, 3), key
        for row in (0, 2):  # the vType's rows: seeds 201, 200, 201
            np.testing.assert_allclose(
                values[row], scores[key][0, [1, 0, 1]], rtol=1e-6, err_msg=key
            )
    assert in_blocks["time_s"][1, 0] != in_blocks["time_s"][0, 0]  # tau 0.5 differs
    assert blocked._compiled["constant"]._cache_size() == 1  # one shape compiled
