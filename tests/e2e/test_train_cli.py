"""`jaxround train` and `jaxround evaluate`: the run folder, determinism, resume.

One tiny training run (the config of `test_ppo.py`, 4 updates, a checkpoint
every 2) is shared by the tests; the others repeat or resume it and must
give the very same files.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from agents.common.config import load_ppo_config
from agents.common.evaluation import DRIVERS
from agents.run import train_to_dir
from agents.run.algorithms import CSV_COLUMNS
from agents.run.metrics_csv import read_csv
from jaxround.apps.cli.main import main
from jaxround.scenario.config import DRAIN_S, load_config
from tests.conftest import builtin_dict
from tests.unit.test_ppo import tiny_config


@pytest.fixture(scope="module")
def ppo_yaml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "tiny.yaml"
    path.write_text(tiny_config().to_yaml())
    return path


@pytest.fixture(scope="module")
def first_run(tmp_path_factory: pytest.TempPathFactory, ppo_yaml: Path) -> Path:
    out = tmp_path_factory.mktemp("runs") / "a"
    args = ["train", "--config", str(ppo_yaml), "--out", str(out), "--no-progress"]
    assert main(args) == 0
    return out


def policy_arrays(folder: Path) -> dict[str, np.ndarray]:
    with np.load(folder / "policy.npz") as data:
        return {k: data[k] for k in data.files}


def assert_same_run(a: Path, b: Path) -> None:
    assert (a / "metrics.csv").read_bytes() == (b / "metrics.csv").read_bytes()
    pa, pb = policy_arrays(a), policy_arrays(b)
    assert pa.keys() == pb.keys()
    for k in pa:
        np.testing.assert_array_equal(pa[k], pb[k], err_msg=k)


def test_train_writes_the_run(first_run: Path) -> None:
    cfg = tiny_config()
    assert load_ppo_config(first_run / "config.yaml") == cfg
    rows = read_csv(first_run / "metrics.csv")
    assert [int(r["update"]) for r in rows] == list(range(1, cfg.num_updates + 1))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert float(rows[-1]["env_steps"]) == cfg.total_env_steps
    assert len(read_csv(first_run / "timing.csv")) == cfg.num_updates
    steps = sorted(int(p.name) for p in (first_run / "checkpoints").iterdir())
    assert steps == [2, 4]
    assert (first_run / "learning_curves.png").stat().st_size > 1000
    meta = json.loads((first_run / "policy.json").read_text())
    assert meta["hidden"] == list(cfg.hidden)
    assert meta["obs_size"] > 0


def test_same_seed_same_curve(first_run: Path, ppo_yaml: Path, tmp_path: Path) -> None:
    out = tmp_path / "b"
    args = ["train", "--config", str(ppo_yaml), "--out", str(out), "--no-progress"]
    assert main(args) == 0
    assert_same_run(first_run, out)


def test_resume_after_a_kill(
    first_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run stopped after update 3 (last checkpoint: 2) and resumed ends as
    the uninterrupted run: same curve, no duplicate rows, same policy. A
    caller's progress callback hears of every update, with its row."""
    cfg = tiny_config()
    out = tmp_path / "c"
    out.mkdir()
    (out / "config.yaml").write_text(cfg.to_yaml())
    reported: list[tuple[int, dict]] = []
    train_to_dir(
        cfg, out, progress=False, stop_after=3, say=lambda msg: None,
        progress_fns=[lambda update, metrics: reported.append((update, metrics))],
    )  # fmt: skip
    assert [update for update, _ in reported] == [1, 2, 3]
    rows = read_csv(out / "metrics.csv")
    for (update, metrics), row in zip(reported, rows, strict=True):
        assert set(metrics) == {*CSV_COLUMNS[1:], "wall_s", "env_steps_per_s"}
        assert row["env_steps"] == str(metrics["env_steps"]), update
    assert not (out / "policy.npz").exists()
    assert main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert_same_run(first_run, out)

    capsys.readouterr()
    assert main(["train", "--resume", str(out), "--seed", "7"]) == 2
    assert "another config (seed: 0 -> 7)" in capsys.readouterr().err


def stopped_copy(first_run: Path, out: Path) -> Path:
    """`first_run` as if killed after its last checkpoint was written: no
    policy yet (its checkpoints at updates 2 and 4)."""
    shutil.copytree(first_run, out)
    for name in ("policy.npz", "policy.json"):
        (out / name).unlink()
    return out


def test_resume_skips_a_truncated_checkpoint(
    first_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The last checkpoint with a data file cut short: one line names it, the
    run resumes from the one before and ends as the uninterrupted run; the
    damaged folder is kept aside."""
    out = stopped_copy(first_run, tmp_path / "d")
    # the data file of the OCDBT root (orbax: OUT_OF_RANGE reading the arrays)
    (data,) = (out / "checkpoints" / "4" / "default" / "d").iterdir()
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    capsys.readouterr()
    assert main(["train", "--resume", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err
    damaged = [line for line in err.splitlines() if "is damaged" in line]
    assert len(damaged) == 1 and str(out / "checkpoints" / "4") in damaged[0]
    assert f"resuming from checkpoint {out / 'checkpoints' / '2'}" in err
    assert "Traceback" not in err
    assert_same_run(first_run, out)
    assert (out / "checkpoints" / "4.damaged").is_dir()


def test_resume_refuses_checkpoints_of_another_shape(
    first_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run folder whose config.yaml builds other layers than its
    checkpoints hold: a clear error, exit 2, nothing changed."""
    out = stopped_copy(first_run, tmp_path / "e")
    wider = tiny_config(hidden=tuple(h + 3 for h in tiny_config().hidden))
    (out / "config.yaml").write_text(wider.to_yaml())
    before = sorted(p.name for p in (out / "checkpoints").iterdir())
    capsys.readouterr()
    assert main(["train", "--resume", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "does not fit this run's config" in err and "has shape" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == before


def test_train_refuses_bad_requests(
    first_run: Path, ppo_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = (first_run / "metrics.csv").read_bytes()
    assert main(["train", "--config", str(ppo_yaml), "--out", str(first_run)]) == 2
    assert "pass --force" in capsys.readouterr().err
    assert (first_run / "metrics.csv").read_bytes() == before
    assert main(["train"]) == 2
    assert "--out DIR" in capsys.readouterr().err
    assert main(["train", "--resume", str(tmp_path)]) == 2
    assert "not a run folder" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**tiny_config().to_dict(), "gamma": 2.0}))
    assert main(["train", "--config", str(bad), "--out", str(tmp_path / "x")]) == 2
    assert "gamma: 2.0" in capsys.readouterr().err


def small_scenario(tmp_path: Path, name: str = "milan", n_vehicles: int = 12) -> Path:
    """A built-in scenario (its name kept) cut to `n_vehicles` in 30 s."""
    d = builtin_dict(name)
    d["demand"].update(n_vehicles=n_vehicles, duration_s=30.0)
    path = tmp_path / f"small_{name}.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def test_evaluate_json(
    first_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "eval"
    scenario = small_scenario(tmp_path)
    args = [
        "evaluate", "--policy", str(first_run), "--config", str(scenario),
        "--penetrations", "0,50,100", "--max-vehicles", "16", "--json",
        "--out", str(out),
    ]  # fmt: skip
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    results = report["results"]
    # the scenario is Milan's: its best constant is the third driver
    assert set(results) == {"policy", "uncontrolled", "best_constant"}
    assert report["best_constant"]["source"] == "configs/best_constant/milan.json"
    assert (out / "jax_best_constant_table3.md").exists()
    for driver in results.values():
        assert set(driver) == {"0", "50", "100"}
        assert driver["50"]["av"]["n_vehicles"] == 6
        assert driver["100"]["hv"]["n_vehicles"] == 0
        assert "collisions" in driver["50"]
    # without AVs the policy has nothing to drive
    assert results["policy"]["0"] == results["uncontrolled"]["0"]
    assert (out / "evaluation.json").exists()
    assert (out / "jax_policy_table3.md").exists()
    assert report["max_vehicles"] == 16 and report["jax_slot_overflow"] == 0
    # every run went on until its vehicles had left, as in SUMO, within the cap
    horizon = load_config(scenario).demand.duration_s
    assert report["cap_s"] == horizon + DRAIN_S and report["jax_not_arrived"] == 0
    assert report["outside_at_cap"] == [] and report["score_scale"] == "sweep"
    assert "one scale" in (out / "jax_policy_table4.md").read_text()


def test_evaluate_compares_the_same_vehicles(
    first_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """No time to drain: the runs leave vehicles outside at the cap, the
    command names them, and policy and baseline are means over the same
    vehicles (those arrived in both)."""
    scenario = small_scenario(tmp_path)
    args = [
        "evaluate", "--policy", str(first_run), "--config", str(scenario),
        "--penetrations", "50", "--max-vehicles", "16", "--drain-s", "0",
        "--score-scale", "run", "--json", "--best-constant", "none",
    ]  # fmt: skip
    assert main(args) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    assert report["cap_s"] == load_config(scenario).demand.duration_s
    assert report["jax_not_arrived"] > 0 and report["score_scale"] == "run"
    assert "vehicles still outside at the cap" in captured.err
    for r in report["outside_at_cap"]:
        assert f"{r['driver']} 50% AVs seed 0: {r['not_arrived']}" in captured.err
    assert set(report["results"]) == set(DRIVERS)  # --best-constant none
    policy, baseline = (report["results"][d]["50"]["all"] for d in DRIVERS)
    assert policy["n_compared"] == baseline["n_compared"] > 0
    assert policy["n_compared"] <= min(policy["n_arrived"], baseline["n_arrived"])


def test_evaluate_refuses(
    first_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["evaluate", "--policy", str(first_run), "--sim", "sumo"]) == 2
    assert "give --out DIR" in capsys.readouterr().err
    assert main(["evaluate", "--policy", str(tmp_path / "none")]) == 2
    assert "does not exist" in capsys.readouterr().err
    missing = tmp_path / "no_constant.json"
    argv = ["evaluate", "--policy", str(first_run), "--best-constant", str(missing)]
    assert main(argv) == 2
    assert "--best-constant" in capsys.readouterr().err


def test_n_envs_auto_on_the_cpu_is_the_run_of_64(tmp_path: Path, capsys) -> None:
    """`n_envs: auto` on a CPU trains exactly the run of ``n_envs: 64``, says
    so, and heads the run's config.yaml with the choice."""
    data = {**tiny_config().to_dict(), "n_envs": 64, "total_env_steps": 64 * 8}
    data["n_steps"], data["minibatches"] = 8, 2
    runs = {}
    for label, n_envs in (("auto", "auto"), ("64", 64)):
        path = tmp_path / f"{label}.yaml"
        path.write_text(yaml.safe_dump({**data, "n_envs": n_envs}))
        out = tmp_path / label
        argv = ["train", "--config", str(path), "--out", str(out), "--no-progress"]
        assert main(argv) == 0
        runs[label] = out
    err = capsys.readouterr().err
    assert "n_envs: auto -> 64 roundabouts" in err and "cpu" in err
    header = (runs["auto"] / "config.yaml").read_text().splitlines()[:2]
    assert header[0].startswith("# n_envs: auto -> 64")
    assert json.loads(header[1][2:])["n_envs"] == 64
    assert load_ppo_config(runs["auto"] / "config.yaml") == load_ppo_config(
        runs["64"] / "config.yaml"
    )
    assert_same_run(runs["auto"], runs["64"])
