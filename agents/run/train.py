"""A training run in a folder: metrics, curves, checkpoints, the exported policy.

    train_to_dir(cfg, Path("runs/ppo"))                 # fresh run
    train_to_dir(cfg, Path("runs/ppo"), resume=True)    # after a kill
    train_to_dir(cfg, out, progress_fns=[lambda update, metrics: ...])

The config's class picks the algorithm (`agents.run.algorithms`). Updates run
one jitted call each (`update_chunk(1)`, which chains bit-identically to the
trainer's `train`). After each, the loop reports to progress callbacks, as
Brax's trainers report to their ``progress_fn``::

    progress_fn(update: int, metrics: dict[str, float]) -> None

`update` is the number of updates done (1 after the first); `metrics` holds
``env_steps`` (done so far), the algorithm's `METRICS` of that update,
``wall_s`` (its wall time) and ``env_steps_per_s``. The run folder is written
by such callbacks, called in this order:

- `agents.run.metrics_csv.CsvLog`: a row of ``metrics.csv`` and ``timing.csv``;
- `agents.run.progress_bar.ProgressBar`: the tqdm bar (`progress=True`);
- `agents.run.checkpoints.CheckpointSaver`: every `checkpoint_every` updates
  and at the last one, an Orbax checkpoint of the whole runner state, then
  ``learning_curves.png`` redrawn;
- then the caller's `progress_fns`.

With several processes (`agents.run.distributed`) only process 0 writes
the CSV files, the curves and the policy, and shows the bar.

At the end the policy is exported (``policy.npz`` + ``policy.json``). A
resumed run restarts from the last checkpoint and cuts both CSVs back to it,
so a kill loses at most one checkpoint interval and the curve has no
duplicate rows.
"""

from __future__ import annotations

import functools
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from agents.common.config import TrainerConfig
from agents.common.export import POLICY_STEM, export_policy, policy_layout
from agents.run.algorithms import algorithm_of, compiled_trainer, csv_columns
from agents.run.checkpoints import (
    CheckpointSaver,
    open_checkpoints,
    restore_newest_intact,
)
from agents.run.curves import plot_learning_curves, updates_per_episode
from agents.run.distributed import is_primary
from agents.run.metrics_csv import CsvLog
from agents.run.progress_bar import ProgressBar

#: A progress callback: ``progress_fn(update, metrics)`` after each update.
ProgressFn = Callable[[int, dict[str, Any]], None]
#: Files and folders a training run writes into its folder.
RUN_FILES = (
    "config.yaml",
    "metrics.csv",
    "timing.csv",
    "checkpoints",
    "learning_curves.png",
    f"{POLICY_STEM}.npz",
    f"{POLICY_STEM}.json",
)


def train_to_dir(
    config: TrainerConfig,
    out: Path,
    resume: bool = False,
    progress: bool = True,
    stop_after: int | None = None,
    say: Callable[[str], None] = print,
    progress_fns: Sequence[ProgressFn] = (),
    warn: Callable[[str], None] = lambda msg: print(msg, file=sys.stderr),
) -> dict[str, Any]:
    """Train `config` into the folder `out` (see the module doc).

    Args:
        config: the run's settings (`PPOConfig` or `APGConfig`).
        out: the run's folder; it exists (with ``config.yaml``, written by
            the caller).
        resume: continue from the newest intact checkpoint in
            ``out/checkpoints`` (`restore_newest_intact`).
        progress: show a tqdm progress bar.
        stop_after: stop once this many updates are done (tests use it to
            imitate a killed run); no export then.
        say: where to print messages.
        progress_fns: more progress callbacks, called after the run's own.
        warn: where to print what must be seen (a damaged checkpoint skipped).

    Raises:
        CheckpointMismatchError: the checkpoints hold another runner than
            `config` builds (resume only).

    Returns:
        ``{"updates": done, "env_steps_per_s": mean over this session (first,
        compiling update excluded), "last": last metrics.csv row, "policy":
        path}``.
    """
    out = Path(out).absolute()
    primary = is_primary()  # the process that writes files (agents.run.distributed)
    n_updates = config.num_updates
    algo = algorithm_of(config)
    trainer, init, update = compiled_trainer(config)
    runner = init(jax.random.PRNGKey(config.seed))
    manager = open_checkpoints(out / "checkpoints", config.keep_checkpoints)
    start = 0
    if resume:
        try:
            step, runner = restore_newest_intact(manager, runner, warn)
        except Exception:
            manager.close()
            raise
        if step is not None:
            start = int(step)
            say(f"resuming {out} at update {start} of {n_updates}")
        else:
            say(f"no intact checkpoint in {out}: starting from update 0")

    if getattr(config, "conflict_constraint", None) is not None and start == 0:
        say(conflict_limit_line(config, runner.ledger.limit))
    draw_curves = functools.partial(
        plot_learning_curves,
        out / "metrics.csv",
        out / "learning_curves.png",
        updates_per_episode(config, trainer.env.dt),
        algo.curves,
        algo.name,
    )
    bar = ProgressBar(n_updates, start) if progress and primary else None
    callbacks: list[ProgressFn] = [
        *([CsvLog(out, csv_columns(config), start)] if primary else []),
        *([bar] if bar is not None else []),
        # `lambda: runner` reads the loop's latest runner when it is called;
        # every process takes part in a checkpoint
        CheckpointSaver(
            manager, lambda: runner, config.checkpoint_every, n_updates,
            draw_curves if primary else (lambda: None),
        ),
        *progress_fns,
    ]  # fmt: skip
    rates: list[float] = []
    last: dict[str, Any] = {}
    try:
        end = n_updates if stop_after is None else min(n_updates, stop_after)
        for u in range(start, end):
            t0 = time.perf_counter()
            runner, stats = update(runner)
            stats = {k: float(v[0]) for k, v in jax.device_get(stats).items()}
            wall = time.perf_counter() - t0
            rate = config.env_steps_per_update / wall
            if u > start:  # the first call of a session compiles
                rates.append(rate)
            env_steps = (u + 1) * config.env_steps_per_update
            metrics = {"env_steps": env_steps, **stats}
            metrics.update(wall_s=wall, env_steps_per_s=rate)
            for progress_fn in callbacks:
                progress_fn(u + 1, metrics)
            last = {"update": u + 1, "env_steps": env_steps, **stats}
        manager.wait_until_finished()
    finally:
        manager.close()
        if bar is not None:
            bar.close()
    done = int(runner.update)
    result: dict[str, Any] = {
        "updates": done,
        "env_steps_per_s": float(np.mean(rates)) if rates else None,
        "last": last,
        "policy": None,
    }
    if hasattr(runner, "ledger"):  # PPO: the conflict limit and price of each share
        result["conflict_limit_per_1000"] = np.asarray(runner.ledger.limit).tolist()
        result["conflict_price"] = np.asarray(runner.ledger.price).tolist()
        if config.conflict_constraint is not None:
            result["conflict_summary"] = conflict_limit_line(
                config, runner.ledger.limit, runner.ledger.price
            )
    if done == n_updates and primary:
        npz, _ = export_policy(
            jax.device_get(runner.params), policy_layout(trainer), out / POLICY_STEM
        )
        draw_curves()
        result["policy"] = str(npz)
    return result


def conflict_limit_line(config: Any, limit: Any, price: Any = None) -> str:
    """What the conflict constraint holds each penetration to, in words (and
    the price it has come to, when given)."""
    given = config.conflict_constraint.limit
    where = "given" if given else "uncontrolled AVs, measured"
    limits = np.asarray(limit).tolist()
    prices = [None] * len(limits) if price is None else np.asarray(price).tolist()
    per_share = ", ".join(
        f"{share:.0%} AVs {x:.1f}" + ("" if p is None else f" (price {p:.0f})")
        for share, x, p in zip(config.penetrations, limits, prices)
    )
    return f"conflicts per 1,000 vehicles allowed ({where}): {per_share}"


def clear_run(out: Path) -> None:
    """Remove the `RUN_FILES` of an earlier run from `out` (nothing else)."""
    for name in RUN_FILES:
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()


__all__ = ["RUN_FILES", "ProgressFn", "clear_run", "train_to_dir"]
