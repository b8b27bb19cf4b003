"""Analytic policy gradients on the roundabout (`train`: the trainer).

    from agents.apg import APGConfig, make_train
    runner, metrics = jax.jit(make_train(APGConfig()))(key)

The package re-exports the trainer's main names and its config (defined with
the other trainer's in `agents.common.config`).
"""

from agents.apg.train import METRICS, APGTrainer, RunnerState, make_train
from agents.common.config import APGConfig

__all__ = ["METRICS", "APGConfig", "APGTrainer", "RunnerState", "make_train"]
