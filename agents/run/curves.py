"""A run's learning curves: ``learning_curves.png`` drawn from ``metrics.csv``.

    window = updates_per_episode(config, env.dt)
    plot_learning_curves(out / "metrics.csv", out / "learning_curves.png", window)

Each algorithm draws six of its metrics (`PPO_CURVES`, `APG_CURVES`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from agents.run.metrics_csv import read_csv

#: Curves drawn in a PPO run's learning_curves.png: (column, label).
PPO_CURVES = (
    ("episode_return", "return of finished AVs"),
    ("reward_per_agent_step", "reward per AV step"),
    ("av_crossing_time_s", "AV crossing time (s)"),
    ("conflicts_per_1000", "conflicts per 1,000 vehicles"),
    ("conflict_price", "price of a conflict (veh-s)"),
    ("entropy", "entropy"),
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


def updates_per_episode(config: Any, dt: float) -> int:
    """Updates whose rollouts make up one training episode (at least 1).

    Args:
        config: a `agents.common.config.TrainerConfig`.
        dt: the environment's step length, s.
    """
    steps_per_update = config.env_steps_per_update // config.n_envs  # per roundabout
    return max(1, round(config.episode_s / dt / steps_per_update))


def trailing_mean(y: np.ndarray, window: int) -> np.ndarray:
    """Mean of the last `window` finite values up to each index (nan before any).

    Args:
        y: float (N,) values, nan where missing.
        window: values per mean.

    Returns:
        float (N,) the trailing means.
    """
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
    curves: tuple[tuple[str, str], ...] = PPO_CURVES,
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


__all__ = [
    "APG_CURVES",
    "PPO_CURVES",
    "plot_learning_curves",
    "trailing_mean",
    "updates_per_episode",
]
