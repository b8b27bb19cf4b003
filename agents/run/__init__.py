"""A training run in a folder (`train_to_dir`), for `jaxround train`.

    from agents.run import train_to_dir
    train_to_dir(cfg, Path("runs/ppo"))                 # fresh run
    train_to_dir(cfg, Path("runs/ppo"), resume=True)    # after a kill

The folder holds

- ``config.yaml``: the config of the run (written by the caller);
- ``metrics.csv``: one row per update (the algorithm's `METRICS`), appended
  as the run goes; deterministic: the same config and seed on the same
  machine give the same file (`metrics_csv`);
- ``timing.csv``: wall time and env steps per second of each update (kept out
  of ``metrics.csv`` so that file stays deterministic);
- ``checkpoints/``: Orbax checkpoints of the whole runner state every
  `checkpoint_every` updates and at the end, the last `keep_checkpoints`
  of them (`checkpoints`);
- ``learning_curves.png``: redrawn at every checkpoint and at the end
  (`curves`);
- ``policy.npz`` + ``policy.json``: the final policy (`agents.common.export`).

Modules: `algorithms` (the trainers by `--algo` name), `train` (the loop and
its progress callbacks), `metrics_csv`, `checkpoints`, `curves`,
`progress_bar`.
"""

from agents.run.algorithms import ALGORITHMS, algorithm_of, load_run_config
from agents.run.train import RUN_FILES, ProgressFn, clear_run, train_to_dir

__all__ = [
    "ALGORITHMS",
    "RUN_FILES",
    "ProgressFn",
    "algorithm_of",
    "clear_run",
    "load_run_config",
    "train_to_dir",
]
