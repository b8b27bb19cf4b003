"""The tqdm progress bar of a run, as a progress callback.

    bar = ProgressBar(total=100, initial=0)
    bar(update, metrics)                # one update done; speed and return shown
    bar.close()

`agents.run.train.train_to_dir` shows it unless told not to (``progress=False``,
``jaxround train --no-progress``).
"""

from __future__ import annotations

import math
from typing import Any


class ProgressBar:
    """A progress callback advancing a tqdm bar by one update per call and
    showing env steps per second, the return and the AV crossing time."""

    def __init__(self, total: int, initial: int) -> None:
        """
        Args:
            total: the run's updates.
            initial: updates done before this session.
        """
        from tqdm import tqdm

        self.bar = tqdm(total=total, initial=initial, desc="train", unit="update")

    def __call__(self, update: int, metrics: dict[str, Any]) -> None:
        """One more update done, with these metrics."""
        self.bar.update(1)
        speed = f"{metrics['env_steps_per_s']:,.0f} env-steps/s"
        ret, crossing = metrics["episode_return"], metrics["av_crossing_time_s"]
        if math.isfinite(ret) and math.isfinite(crossing):
            episodes = f"return {ret:.2f}, AV crossing {crossing:.1f} s"
        else:  # the means over AVs that left in this update: none did
            episodes = "no AV left the roundabouts in this update"
        self.bar.set_postfix_str(f"{speed}, {episodes}")

    def close(self) -> None:
        self.bar.close()


__all__ = ["ProgressBar"]
