"""Resuming from damaged checkpoints, on a tiny tree (no training)."""

from __future__ import annotations

import logging
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from agents.run.checkpoints import (
    CheckpointMismatchError,
    open_checkpoints,
    restore_newest_intact,
)

TREE = {"a": jnp.arange(10.0), "b": {"c": jnp.ones((4, 3))}}


def two_checkpoints(folder: Path) -> None:
    """Steps 1 and 2 of TREE times the step."""
    import orbax.checkpoint as ocp

    manager = open_checkpoints(folder, keep=3)
    for step in (1, 2):
        tree = {"a": TREE["a"] * step, "b": {"c": TREE["b"]["c"] * step}}
        manager.save(step, args=ocp.args.StandardSave(tree))
    manager.wait_until_finished()
    manager.close()


def resume(folder: Path, like: dict) -> tuple[int | None, dict, list[str]]:
    lines: list[str] = []
    manager = open_checkpoints(folder, keep=3)
    try:
        step, tree = restore_newest_intact(manager, like, lines.append)
    finally:
        manager.close()
    return step, tree, lines


def test_a_truncated_last_checkpoint_falls_back_to_the_one_before(
    tmp_path: Path,
) -> None:
    two_checkpoints(tmp_path)
    (data,) = (tmp_path / "2" / "default" / "d").iterdir()
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    step, tree, lines = resume(tmp_path, TREE)
    assert step == 1
    np.testing.assert_array_equal(tree["a"], np.arange(10.0))
    assert len(lines) == 2
    assert f"checkpoint {tmp_path / '2'} is damaged" in lines[0]
    assert f"resuming from checkpoint {tmp_path / '1'}" in lines[1]
    assert (tmp_path / "2.damaged").is_dir() and not (tmp_path / "2").exists()


def test_an_unreadable_metadata_file_is_said_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    two_checkpoints(tmp_path)
    (tmp_path / "2" / "_CHECKPOINT_METADATA").write_text("")
    with caplog.at_level(logging.ERROR):
        step, tree, lines = resume(tmp_path, TREE)
    assert step == 2 and float(tree["a"][1]) == 2.0
    assert lines == [
        f"checkpoint {tmp_path / '2'}: _CHECKPOINT_METADATA is unreadable "
        "(JSONDecodeError); its arrays restored intact"
    ]
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]


def test_other_shapes_than_the_checkpoints_are_refused(tmp_path: Path) -> None:
    two_checkpoints(tmp_path)
    wider = {"a": jnp.arange(11.0), "b": TREE["b"]}
    with pytest.raises(CheckpointMismatchError, match=r"a has shape \(10,\) there"):
        resume(tmp_path, wider)
    missing = {**TREE, "z": jnp.ones(2)}
    with pytest.raises(CheckpointMismatchError, match="it has no array 'z'"):
        resume(tmp_path, missing)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["1", "2"]


def test_no_checkpoint_gives_none(tmp_path: Path) -> None:
    step, tree, lines = resume(tmp_path / "new", TREE)
    assert step is None and tree is TREE and lines == []
