"""Minimising a batched black-box objective with CMA-ES (evosax).

`minimise` asks evosax's CMA-ES for a population of points, scores them all
in one call of the objective (one compiled JAX program scores the whole
population) and tells it the scores, for a number of generations. It keeps
every point scored, so a caller can draw the front of what was tried.

Shapes: K the population, P the number of parameters.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from evosax.algorithms import CMA_ES
from tqdm import tqdm

#: fitness(points float (K, P)) -> float (K,), lower is better.
Fitness = Callable[[np.ndarray], np.ndarray]


@dataclass
class SearchTrace:
    """What a search tried.

    Attributes:
        best: float (P,) the best point scored.
        best_fitness: its score.
        points: float (G * K, P) every point scored, in order.
        fitness: float (G * K,) their scores.
    """

    best: np.ndarray
    best_fitness: float
    points: np.ndarray
    fitness: np.ndarray
    generations: list[float] = field(default_factory=list)  # best per generation


def minimise(
    fitness: Fitness,
    start: np.ndarray,
    std: float = 0.3,
    population: int = 16,
    generations: int = 10,
    seed: int = 0,
    desc: str = "CMA-ES",
    progress: bool = True,
) -> SearchTrace:
    """Minimise `fitness` from `start` (float (P,)) by CMA-ES.

    The start point itself is scored first (generation 0 of one point), so
    the result is never worse than where the search began.
    """
    start = np.asarray(start, np.float32)
    if start.ndim != 1 or population < 2 or generations < 1:
        raise ValueError(
            f"minimise: start of shape {start.shape} (expected (P,)), population "
            f"{population} (>= 2), generations {generations} (>= 1)"
        )
    strategy = CMA_ES(population_size=population, solution=jnp.asarray(start))
    params = strategy.default_params.replace(std_init=std)
    key = jax.random.PRNGKey(seed)
    key, k_init = jax.random.split(key)
    state = strategy.init(k_init, jnp.asarray(start), params)
    ask, tell = jax.jit(strategy.ask), jax.jit(strategy.tell)
    first = np.asarray(fitness(start[None]), np.float64)
    points, scores, per_generation = [start[None]], [first], [float(first[0])]
    for _ in tqdm(range(generations), desc=desc, unit="gen", disable=not progress):
        key, k_ask, k_tell = jax.random.split(key, 3)
        pop, state = ask(k_ask, state, params)
        fit = np.asarray(fitness(np.asarray(pop)), np.float64)
        state, _ = tell(k_tell, pop, jnp.asarray(fit, jnp.float32), state, params)
        points.append(np.asarray(pop))
        scores.append(fit)
        per_generation.append(float(fit.min()))
    all_points, all_scores = np.concatenate(points), np.concatenate(scores)
    i = int(np.argmin(all_scores))
    return SearchTrace(
        best=all_points[i],
        best_fitness=float(all_scores[i]),
        points=all_points,
        fitness=all_scores,
        generations=per_generation,
    )
