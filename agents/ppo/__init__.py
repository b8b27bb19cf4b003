"""PPO on the roundabout (`train`: the trainer; `losses`: GAE and the PPO loss).

    from agents.ppo import PPOConfig, make_train
    runner, metrics = jax.jit(make_train(PPOConfig()))(key)

The package re-exports the trainer's main names and its config (defined with
the other trainer's in `agents.common.config`).
"""

from agents.common.config import PPOConfig
from agents.ppo.train import METRICS, RunnerState, Trainer, make_train

__all__ = ["METRICS", "PPOConfig", "RunnerState", "Trainer", "make_train"]
