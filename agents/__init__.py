"""Trainers for the AVs of the roundabout, and the trained policy's use.

- `agents.common`: configs, the network, the batch of roundabouts, export,
  evaluation: what every algorithm shares;
- `agents.ppo`: PPO (`train`: the trainer; `losses`: GAE and the PPO loss);
- `agents.apg`: analytic policy gradients through the environment;
- `agents.run`: a training run in a folder (`train_to_dir`: CSV files,
  checkpoints, learning curves, reported through progress callbacks), for
  ``jaxround train``.
"""
