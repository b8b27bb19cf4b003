"""Orbax checkpoints of a run: the whole runner state every `checkpoint_every`
updates and at the end, the last `keep_checkpoints` of them kept.

    manager = open_checkpoints(out / "checkpoints", keep=3)
    runner = restore(manager, manager.latest_step(), like=runner)
    save = CheckpointSaver(manager, lambda: runner, every=10, last_update=100)
    save(update, metrics)               # a progress_fn: saves on its updates
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax


def open_checkpoints(folder: Path, keep: int) -> Any:
    """An Orbax `CheckpointManager` on `folder` (made if missing) keeping the
    last `keep` checkpoints; close it when done."""
    import orbax.checkpoint as ocp

    options = ocp.CheckpointManagerOptions(max_to_keep=keep, create=True)
    return ocp.CheckpointManager(folder, options=options)


def restore(manager: Any, step: int, like: Any) -> Any:
    """The checkpoint of `step`, placed like `like` (same shapes and shardings)."""
    import orbax.checkpoint as ocp

    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, like)
    return manager.restore(step, args=ocp.args.StandardRestore(abstract))


class CheckpointSaver:
    """A progress callback saving the runner every `every` updates and at the
    last one, then calling `after_save` (the run redraws its curves there)."""

    def __init__(
        self,
        manager: Any,
        runner_now: Callable[[], Any],
        every: int,
        last_update: int,
        after_save: Callable[[], None] = lambda: None,
    ) -> None:
        """
        Args:
            manager: from `open_checkpoints`.
            runner_now: returns the runner state after the update reported.
            every: updates between checkpoints.
            last_update: the run's last update (always saved).
            after_save: called after each save.
        """
        self.manager = manager
        self.runner_now = runner_now
        self.every = every
        self.last_update = last_update
        self.after_save = after_save

    def __call__(self, update: int, metrics: dict[str, Any]) -> None:
        """Save the runner as checkpoint `update` if it is one of the saved."""
        import orbax.checkpoint as ocp

        if update % self.every == 0 or update == self.last_update:
            self.manager.save(update, args=ocp.args.StandardSave(self.runner_now()))
            self.after_save()


__all__ = ["CheckpointSaver", "open_checkpoints", "restore"]
