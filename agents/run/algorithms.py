"""The trainers a run folder can hold, by `--algo` name, and what a run needs
of each: its config class, trainer class, metrics and learning curves.

    algo = algorithm_of(config)                  # by the config's class
    trainer, init, update = compiled_trainer(config)
    config = load_run_config(Path("runs/ppo/config.yaml"))
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import jax

from agents import apg, ppo
from agents.common.batch import BatchTrainer
from agents.common.config import TrainerConfig, trainer_config_from_dict
from agents.run.curves import APG_CURVES, PPO_CURVES
from jaxround.scenario.loader import ConfigError, read_yaml


class Algorithm(NamedTuple):
    """What the run needs to know of a trainer."""

    name: str  # "PPO", as in titles and `--algo` (lower case)
    config: type[TrainerConfig]  # its config class
    trainer: type[BatchTrainer]  # its trainer class
    metrics: tuple[str, ...]  # per-update metrics, in CSV order
    curves: tuple[tuple[str, str], ...]  # (column, label) of learning_curves.png


#: The trainers, by `--algo` name.
ALGORITHMS = {
    "ppo": Algorithm("PPO", ppo.PPOConfig, ppo.Trainer, ppo.METRICS, PPO_CURVES),
    "apg": Algorithm("APG", apg.APGConfig, apg.APGTrainer, apg.METRICS, APG_CURVES),
}
#: Columns of a PPO run's metrics.csv (`csv_columns` for any config).
CSV_COLUMNS = ("update", "env_steps", *ppo.METRICS)


def algorithm_of(config: TrainerConfig) -> Algorithm:
    """The `Algorithm` a config trains with (by its class)."""
    for algo in ALGORITHMS.values():
        if type(config) is algo.config:
            return algo
    raise TypeError(f"no trainer for a {type(config).__name__}")


def csv_columns(config: TrainerConfig) -> tuple[str, ...]:
    """Columns of a run's metrics.csv."""
    return ("update", "env_steps", *algorithm_of(config).metrics)


def load_run_config(path: Path) -> TrainerConfig:
    """The config of a run folder's ``config.yaml``, of whichever algorithm
    accepts it (each refuses the others' fields).

    Raises:
        ConfigError: no algorithm's config accepts the file.
    """
    data = read_yaml(path, [], "training")
    errors = []
    for name, algo in ALGORITHMS.items():
        try:
            return trainer_config_from_dict(algo.config, data)
        except ConfigError as err:
            errors.append(f"as {name}: {err}")
    raise ConfigError(f"{path}: not a training config ({'; '.join(errors)})")


@functools.lru_cache(maxsize=2)
def compiled_trainer(config: TrainerConfig) -> tuple[Any, Callable, Callable]:
    """(trainer, jitted init, jitted single update) of a config, built once per
    process: repeated runs of one config (a notebook, the tests) reuse them."""
    trainer = algorithm_of(config).trainer(config)
    return trainer, jax.jit(trainer.init), trainer.update_chunk(1)


__all__ = [
    "ALGORITHMS",
    "CSV_COLUMNS",
    "Algorithm",
    "algorithm_of",
    "compiled_trainer",
    "csv_columns",
    "load_run_config",
]
