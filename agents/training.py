"""A training run in a folder: metrics, curves, checkpoints, the exported policy.

    train_to_dir(cfg, Path("runs/ppo"))                 # fresh run
    train_to_dir(cfg, Path("runs/ppo"), resume=True)    # after a kill

The config's class picks the algorithm (`ALGORITHMS`): a `PPOConfig` trains
with `agents.ppo`, an `APGConfig` with `agents.apg`. The folder holds

- ``config.yaml``: the config of the run (written by the caller);
- ``metrics.csv``: one row per update (the algorithm's `METRICS`), appended
  as the run goes; deterministic: the same config and seed on the same
  machine give the same file;
- ``timing.csv``: wall time and env steps per second of each update (kept out
  of ``metrics.csv`` so that file stays deterministic);
- ``checkpoints/``: Orbax checkpoints of the whole `RunnerState` every
  `checkpoint_every` updates and at the end (the last `keep_checkpoints`);
- ``learning_curves.png``: redrawn at every checkpoint and at the end;
- ``policy.npz`` + ``policy.json``: the final policy (`agents.common.export`).

A resumed run restarts from the last checkpoint and cuts both CSVs back to
it, so a kill loses at most one checkpoint interval and the curve has no
duplicate rows. Updates run one jitted call each (`update_chunk(1)`), which
chain bit-identically to the trainer's `train`.
"""

from __future__ import annotations

import csv
import functools
import math
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from agents import apg, ppo
from agents.common.batch import BatchTrainer
from agents.common.config import (
    APGConfig,
    PPOConfig,
    TrainerConfig,
    trainer_config_from_dict,
)
from agents.common.export import POLICY_STEM, PolicyLayout, export_policy
from jaxround.config import ConfigError, read_yaml

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
#: Columns of a PPO run's metrics.csv (`csv_columns` for any config).
CSV_COLUMNS = ("update", "env_steps", *ppo.METRICS)
TIMING_COLUMNS = ("update", "wall_s", "env_steps_per_s")
#: Curves drawn in a PPO run's learning_curves.png: (column, label).
CURVES = (
    ("episode_return", "return of finished AVs"),
    ("reward_per_agent_step", "reward per AV step"),
    ("av_crossing_time_s", "AV crossing time (s)"),
    ("value_loss", "value loss"),
    ("entropy", "entropy"),
    ("approx_kl", "approx. KL"),
)
#: Curves of an APG run.
APG_CURVES = (
    ("episode_return", "return of finished AVs"),
    ("reward_per_agent_step", "reward per AV step"),
    ("av_crossing_time_s", "AV crossing time (s)"),
    ("grad_norm", "gradient norm (before clipping)"),
    ("mean_command", "mean AV command (m/s^2)"),
    ("skipped_updates", "skipped (non-finite) updates"),
)


class Algorithm(NamedTuple):
    """What the driver needs to know of a trainer."""

    name: str  # "PPO", as in titles and `--algo` (lower case)
    config: type[TrainerConfig]  # its config class
    trainer: type[BatchTrainer]  # its trainer class
    metrics: tuple[str, ...]  # per-update metrics, in CSV order
    curves: tuple[tuple[str, str], ...]  # (column, label) of learning_curves.png


#: The trainers, by `--algo` name.
ALGORITHMS = {
    "ppo": Algorithm("PPO", PPOConfig, ppo.Trainer, ppo.METRICS, CURVES),
    "apg": Algorithm("APG", APGConfig, apg.APGTrainer, apg.METRICS, APG_CURVES),
}


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


def policy_layout(trainer: BatchTrainer) -> PolicyLayout:
    """The exported layout of a trainer's network."""
    cfg, scenario = trainer.config, trainer.scenario
    return PolicyLayout(
        observer=scenario.agent.observer,
        obs_size=trainer.obs_size,
        hidden=tuple(cfg.hidden),
        activation=cfg.activation,
        centralised=cfg.centralised,
        accel_bounds=action_bounds(scenario),
        action=scenario.agent.action,
        scenario=cfg.scenario,
        scenario_fingerprint=scenario.roads_and_drivers_fingerprint(),
    )


def action_bounds(scenario: Any) -> tuple[float, float]:
    """The exported policy's action bounds: the AV's [-decel, accel] for a
    speed command, `jaxround.assertiveness.RAW_BOUND` for assertiveness."""
    if scenario.agent.action == "assertiveness":
        from jaxround.assertiveness import RAW_BOUND

        return (-RAW_BOUND, RAW_BOUND)
    return (-scenario.drivers.av.decel, scenario.drivers.av.accel)


def train_to_dir(
    config: TrainerConfig,
    out: Path,
    resume: bool = False,
    progress: bool = True,
    stop_after: int | None = None,
    say: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Train `config` into the folder `out` (see the module doc).

    Args:
        config: the run's settings (`PPOConfig` or `APGConfig`).
        out: the run's folder; it exists (with ``config.yaml``).
        resume: continue from the last checkpoint in ``out/checkpoints``.
        progress: show a tqdm progress bar.
        stop_after: stop once this many updates are done (tests use it to
            imitate a killed run); no export then.
        say: where to print messages.

    Returns:
        ``{"updates": done, "env_steps_per_s": mean over this session (first,
        compiling update excluded), "last": last metrics row, "policy": path}``.
    """
    import orbax.checkpoint as ocp

    out = Path(out).absolute()
    n_updates = config.num_updates
    algo = algorithm_of(config)
    columns = csv_columns(config)
    trainer, init, update = compiled_trainer(config)
    runner = init(jax.random.PRNGKey(config.seed))
    manager = ocp.CheckpointManager(
        out / "checkpoints",
        options=ocp.CheckpointManagerOptions(
            max_to_keep=config.keep_checkpoints, create=True
        ),
    )
    start = 0
    if resume and manager.latest_step() is not None:
        start = int(manager.latest_step())
        runner = restore(manager, start, runner)
        say(f"resuming {out} at update {start} of {n_updates}")
    elif resume:
        say(f"no checkpoint in {out}: starting from update 0")
    cut_csv(out / "metrics.csv", columns, start)
    cut_csv(out / "timing.csv", TIMING_COLUMNS, start)

    curves = out / "learning_curves.png"
    window = updates_per_episode(config, trainer.env.dt)
    bar = _progress_bar(n_updates, start, progress)
    rates: list[float] = []
    row: dict[str, Any] = {}
    try:
        end = n_updates if stop_after is None else min(n_updates, stop_after)
        for u in range(start, end):
            t0 = time.perf_counter()
            runner, metrics = update(runner)
            metrics = {k: float(v[0]) for k, v in jax.device_get(metrics).items()}
            wall = time.perf_counter() - t0
            rate = config.env_steps_per_update / wall
            if u > start:  # the first call of a session compiles
                rates.append(rate)
            row = {"update": u + 1, "env_steps": (u + 1) * config.env_steps_per_update}
            row.update(metrics)
            append_csv(out / "metrics.csv", columns, row)
            append_csv(
                out / "timing.csv",
                TIMING_COLUMNS,
                {"update": u + 1, "wall_s": wall, "env_steps_per_s": rate},
            )
            if bar is not None:
                bar.update(1)
                bar.set_postfix_str(
                    f"{rate:,.0f} env-steps/s, return {row['episode_return']:.2f}, "
                    f"AV crossing {row['av_crossing_time_s']:.1f} s"
                )
            if (u + 1) % config.checkpoint_every == 0 or u + 1 == n_updates:
                manager.save(u + 1, args=ocp.args.StandardSave(runner))
                plot_learning_curves(
                    out / "metrics.csv", curves, window, algo.curves, algo.name
                )
        manager.wait_until_finished()
    finally:
        manager.close()
        if bar is not None:
            bar.close()
    done = int(runner.update)
    result: dict[str, Any] = {
        "updates": done,
        "env_steps_per_s": float(np.mean(rates)) if rates else None,
        "last": row,
        "policy": None,
    }
    if done == n_updates:
        npz, _ = export_policy(
            jax.device_get(runner.params), policy_layout(trainer), out / POLICY_STEM
        )
        plot_learning_curves(
            out / "metrics.csv", curves, window, algo.curves, algo.name
        )
        result["policy"] = str(npz)
    return result


def clear_run(out: Path) -> None:
    """Remove the `RUN_FILES` of an earlier run from `out` (nothing else)."""
    for name in RUN_FILES:
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()


def enable_compilation_cache() -> None:
    """Keep compiled XLA programs in ``$XDG_CACHE_HOME/jaxround/xla`` so that a
    resumed or repeated run skips the compilation; a cache folder set already
    (``JAX_COMPILATION_CACHE_DIR``) is left alone."""
    if jax.config.jax_compilation_cache_dir:
        return
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    jax.config.update("jax_compilation_cache_dir", str(cache / "jaxround" / "xla"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def restore(manager: Any, step: int, like: Any) -> Any:
    """The checkpoint of `step`, placed like `like` (same shapes and shardings)."""
    import orbax.checkpoint as ocp

    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, like)
    return manager.restore(step, args=ocp.args.StandardRestore(abstract))


# --------------------------------------------------------------------------- CSV


def _format(value: Any) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.9g}"
    return str(value)


def append_csv(path: Path, columns: tuple[str, ...], row: dict[str, Any]) -> None:
    """Append one row (writing the header first if the file is new)."""
    new = not path.exists()
    with path.open("a", newline="") as f:
        writer = csv.writer(f)
        if new:
            writer.writerow(columns)
        writer.writerow([_format(row[c]) for c in columns])


def cut_csv(path: Path, columns: tuple[str, ...], last_update: int) -> None:
    """Keep the header and the rows up to `last_update` (all others are dropped)."""
    rows = read_csv(path) if path.exists() else []
    kept = [r for r in rows if int(r["update"]) <= last_update]
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        writer.writerows([[r[c] for c in columns] for r in kept])
    tmp.replace(path)


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


# --------------------------------------------------------------------------- curves


def updates_per_episode(config: TrainerConfig, dt: float) -> int:
    """Updates whose rollouts make up one training episode (at least 1)."""
    c: Any = config
    steps_per_update = c.env_steps_per_update // c.n_envs  # per roundabout
    return max(1, round(c.episode_s / dt / steps_per_update))


def trailing_mean(y: np.ndarray, window: int) -> np.ndarray:
    """Mean of the last `window` finite values up to each index (nan before any)."""
    out = np.full(y.shape, np.nan)
    for i in range(len(y)):
        part = y[max(0, i - window + 1) : i + 1]
        part = part[np.isfinite(part)]
        if part.size:
            out[i] = part.mean()
    return out


def plot_learning_curves(
    metrics_csv: Path,
    path: Path,
    window: int = 1,
    curves: tuple[tuple[str, str], ...] = CURVES,
    title: str = "PPO",
) -> None:
    """Draw six `curves` (PPO's by default) against env steps into a PNG
    (nothing if no rows yet).

    The roundabouts' episodes start together, so an update's statistics
    depend on where in the episode its rollout fell (early in an episode
    only the quick vehicles have finished); the bold line is the mean over
    the last `window` updates (one episode), the thin one each update.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_csv(metrics_csv)
    if not rows:
        return
    steps = np.array([float(r["env_steps"]) for r in rows])
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5), constrained_layout=True)
    for ax, (column, label) in zip(axes.flat, curves, strict=True):
        y = np.array([float(r[column]) for r in rows])
        ok = np.isfinite(y)
        ax.plot(steps[ok], y[ok], "-", color="tab:blue", alpha=0.35, linewidth=0.8)
        smooth = trailing_mean(y, window)
        ok = np.isfinite(smooth)
        ax.plot(steps[ok], smooth[ok], "-", color="tab:blue", linewidth=1.8)
        ax.set_xlabel("env steps")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{title}: {len(rows)} updates (bold: mean over {window} updates)")
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    tmp.replace(path)


def _progress_bar(total: int, initial: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc="train", unit="update")


__all__ = [
    "ALGORITHMS",
    "APG_CURVES",
    "CSV_COLUMNS",
    "CURVES",
    "Algorithm",
    "RUN_FILES",
    "TIMING_COLUMNS",
    "append_csv",
    "clear_run",
    "algorithm_of",
    "compiled_trainer",
    "csv_columns",
    "cut_csv",
    "enable_compilation_cache",
    "load_run_config",
    "plot_learning_curves",
    "policy_layout",
    "read_csv",
    "restore",
    "trailing_mean",
    "train_to_dir",
    "updates_per_episode",
]
