"""Orbax checkpoints of a run: the whole runner state every `checkpoint_every`
updates and at the end, the last `keep_checkpoints` of them kept.

    manager = open_checkpoints(out / "checkpoints", keep=3)
    step, runner = restore_newest_intact(manager, like=runner, say=print)
    save = CheckpointSaver(manager, lambda: runner, every=10, last_update=100)
    save(update, metrics)               # a progress_fn: saves on its updates
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import jax


def open_checkpoints(folder: Path, keep: int) -> Any:
    """An Orbax `CheckpointManager` on `folder` (made if missing) keeping the
    last `keep` checkpoints; close it when done."""
    import orbax.checkpoint as ocp

    options = ocp.CheckpointManagerOptions(max_to_keep=keep, create=True)
    # orbax logs an unreadable step metadata file here already; resuming says
    # it once (`restore_newest_intact`)
    with quiet_orbax():
        return ocp.CheckpointManager(folder, options=options)


def restore(manager: Any, step: int, like: Any) -> Any:
    """The checkpoint of `step`, placed like `like` (same shapes and shardings)."""
    import orbax.checkpoint as ocp

    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, like)
    return manager.restore(step, args=ocp.args.StandardRestore(abstract))


class CheckpointMismatchError(ValueError):
    """The run's config builds a runner of other shapes than its checkpoints."""


def restore_newest_intact(
    manager: Any, like: Any, say: Callable[[str], None]
) -> tuple[int | None, Any]:
    """The newest checkpoint that restores, and its step; (None, `like`) if
    there is none.

    A damaged or unreadable checkpoint gets one line through `say` naming it,
    is moved aside (`set_aside`) and the one before it is tried; the one
    restored after such a line is named too.

    Raises:
        CheckpointMismatchError: a checkpoint's tree metadata names other
            arrays or shapes than `like` has (the run folder's config does
            not build the runner its checkpoints were saved from).
    """
    folder = Path(manager.directory)
    skipped = False
    for step in sorted(manager.all_steps(), reverse=True):
        where = folder / str(step)
        mismatch = shape_mismatch(where, like)
        if mismatch is not None:
            raise CheckpointMismatchError(
                f"checkpoint {where} does not fit this run's config: {mismatch}"
            )
        problem = unreadable_metadata(where)
        try:
            with quiet_orbax():
                runner = restore(manager, step, like)
        except Exception as err:  # orbax and tensorstore raise bare Exception
            first = str(err).strip().splitlines()[0][:160] if str(err) else ""
            aside = set_aside(where)
            say(f"checkpoint {where} is damaged ({type(err).__name__}: {first}); "
                f"moved to {aside.name}, trying the one before")  # fmt: skip
            skipped = True
            continue
        if problem:
            say(f"checkpoint {where}: {problem}; its arrays restored intact")
        if skipped:
            manager.reload()
            say(f"resuming from checkpoint {where}, the newest intact one")
        return step, runner
    manager.reload()
    return None, like


def set_aside(where: Path) -> Path:
    """Rename a damaged checkpoint folder out of the manager's sight (kept, not
    deleted: the run will save that step again): ``<step>.damaged[.k]``."""
    aside = where.with_name(f"{where.name}.damaged")
    k = 1
    while aside.exists():
        aside = where.with_name(f"{where.name}.damaged.{k}")
        k += 1
    where.rename(aside)
    return aside


def shape_mismatch(where: Path, like: Any) -> str | None:
    """What differs between the arrays saved in `where` (by its tree metadata,
    ``default/_METADATA``) and `like`'s: the first name missing or shape
    differing; None if they agree or the metadata does not read (a damaged
    checkpoint, left to `restore`)."""
    import orbax.checkpoint as ocp

    try:
        saved = json.loads((where / "default" / "_METADATA").read_text())
        stored = {
            "/".join(str(k["key"]) for k in entry["key_metadata"]): entry[
                "value_metadata"
            ].get("write_shape")
            for _, entry in saved["tree_metadata"].items()
        }
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    leaves = jax.tree_util.tree_flatten_with_path(
        ocp.utils.serialize_tree(like, keep_empty_nodes=True)
    )[0]
    for path, leaf in leaves:
        name = "/".join(str(_key_name(k)) for k in path)
        if name not in stored:
            return f"it has no array {name!r}"
        shape = tuple(getattr(leaf, "shape", ()))
        there = stored[name]
        if there is not None and tuple(there) != shape:
            return f"{name} has shape {tuple(there)} there, the config gives {shape}"
    return None


def _key_name(key: Any) -> Any:
    for attr in ("key", "name", "idx"):
        if hasattr(key, attr):
            return getattr(key, attr)
    return key


def unreadable_metadata(where: Path) -> str | None:
    """Why the step's `_CHECKPOINT_METADATA` does not read (None if it does)."""
    path = where / "_CHECKPOINT_METADATA"
    try:
        json.loads(path.read_text())
    except (OSError, ValueError) as err:
        return f"{path.name} is unreadable ({type(err).__name__})"
    return None


@contextmanager
def quiet_orbax() -> Iterator[None]:
    """Orbax logs its own errors (absl); the caller says what matters once."""
    log = logging.getLogger("absl")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        log.setLevel(level)


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


__all__ = [
    "CheckpointMismatchError",
    "CheckpointSaver",
    "open_checkpoints",
    "restore",
    "restore_newest_intact",
    "set_aside",
]
