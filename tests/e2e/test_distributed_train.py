"""``jaxround train --num-processes 2``: two processes on this machine (CPU
collectives through Gloo) split the roundabout batch and give the learning
curve of one process with the same global batch and seed.

The cross-process sums round differently from one process's: metrics and the
policy agree to float32 rounding (measured up to 1.2e-7 absolute), the test
allows 1e-5 relative.
"""

from __future__ import annotations

import csv
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from agents.common.export import load_policy
from tests.unit.test_ppo import tiny_config

#: The runs' time limit, s (three compilations side by side on two cores).
TIMEOUT_S = 900


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def train(config: Path, out: Path, *extra: str) -> subprocess.Popen:
    env = dict(os.environ)
    argv = [sys.executable, "-m", "jaxround", "train", "--config", str(config),
            "--out", str(out), "--no-progress", *extra]  # fmt: skip
    return subprocess.Popen(
        argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


def metrics(folder: Path) -> dict[str, np.ndarray]:
    with (folder / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("distributed")
    config = tmp / "tiny.yaml"
    config.write_text(tiny_config().to_yaml())
    address = f"127.0.0.1:{free_port()}"
    procs = {
        "one": train(config, tmp / "one"),
        **{
            f"two_{i}": train(
                config,
                tmp / "two",
                "--num-processes",
                "2",
                "--process-id",
                str(i),
                "--coordinator",
                address,
            )
            for i in range(2)
        },  # fmt: skip
    }
    for name, proc in procs.items():
        out, _ = proc.communicate(timeout=TIMEOUT_S)
        assert proc.returncode == 0, f"{name}:\n{out}"
    return {"one": tmp / "one", "two": tmp / "two"}


def test_two_processes_learn_as_one(runs: dict[str, Path]) -> None:
    one, two = metrics(runs["one"]), metrics(runs["two"])
    assert one.keys() == two.keys() and len(one["update"]) == 4
    for name in one:
        np.testing.assert_allclose(
            two[name], one[name], rtol=1e-5, atol=1e-6, equal_nan=True, err_msg=name
        )
    assert np.isfinite(one["policy_loss"]).all()
    a, _ = load_policy(runs["one"] / "policy.npz")
    b, _ = load_policy(runs["two"] / "policy.npz")
    for name in a:
        np.testing.assert_allclose(b[name], a[name], rtol=1e-5, atol=1e-6)
    # both processes wrote their shards into one checkpoint per saved update
    assert sorted(p.name for p in (runs["two"] / "checkpoints").iterdir()) == sorted(
        p.name for p in (runs["one"] / "checkpoints").iterdir()
    )


def test_bad_process_arguments_are_named_before_any_work(tmp_path: Path) -> None:
    from jaxround.apps.cli.main import main

    base = ["train", "--out", str(tmp_path / "x")]
    assert main([*base, "--num-processes", "2"]) == 2
    assert main([*base, "--process-id", "1"]) == 2
    argv = [*base, "--num-processes", "2", "--process-id", "2",
            "--coordinator", "127.0.0.1:1"]  # fmt: skip
    assert main(argv) == 2
    argv = [*base, "--num-processes", "2", "--coordinator", "nowhere"]
    assert main(argv) == 2
    assert not (tmp_path / "x").exists()
