"""The main job end to end on a small scenario: train, export, JAX and SUMO
evaluation, tables and results.json (real SUMO); `export` and its errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from jaxround.apps.cli.main import main
from tests.conftest import builtin_dict

pytestmark = pytest.mark.sumo


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("pipeline")
    scenario = builtin_dict("milan")
    scenario["name"] = "milan_small"
    scenario["demand"]["n_vehicles"] = 60
    scenario["demand"]["duration_s"] = 150.0
    (root / "small.yaml").write_text(yaml.safe_dump(scenario))
    ppo = {
        "scenario": str(root / "small.yaml"),
        "demand_window_s": 60.0,
        "episode_s": 60.0,
        "max_vehicles": 16,
        "n_envs": 4,
        "n_steps": 16,
        "total_env_steps": 4 * 16 * 2,
        "hidden": [16, 16],
        "epochs": 1,
        "minibatches": 2,
        "checkpoint_every": 1,
        "action": "assertiveness",
        "reward": "system",
        "trip_noise": True,
        "conflict_constraint": {"measure_episodes": 1},
    }
    (root / "ppo.yaml").write_text(yaml.safe_dump(ppo))
    out = root / "run"
    argv = ["run", "--config", str(root / "small.yaml"), "--out", str(out)]
    argv += ["--train-config", str(root / "ppo.yaml"), "--quick", "--no-progress"]
    argv += ["--best-constant", "milan"]  # the small scenario has none of its own
    assert main(argv) == 0
    return out


def test_main_job_writes_every_result(finished_run: Path) -> None:
    results = json.loads((finished_run / "results.json").read_text())
    assert set(results["sumo"]) == set(results["jax"]) == {"0", "50", "100"}
    for sim in ("sumo", "jax", "jax_uncontrolled"):
        zero, full = results[sim]["0"], results[sim]["100"]
        assert zero["all"]["n_arrived"] == 60  # no AVs: the policy plays no part
        assert zero["av"]["n_vehicles"] == 0 and full["hv"]["n_vehicles"] == 0
        assert full["av"]["n_vehicles"] == 60 and full["collisions"] == 0
    # two updates teach nothing: only the uncontrolled AVs surely all arrive
    assert results["jax_uncontrolled"]["100"]["all"]["n_arrived"] == 60
    assert results["sumo_uncontrolled"]["100"]["all"]["n_arrived"] == 60
    # the policy against uncontrolled AVs, paired on the same schedules
    for sim in ("sumo", "jax"):
        pair = results["comparison"][sim]["100"]["all"]["crossing_time_s"]
        assert pair["n_vehicles"] == 60
        mean_policy = results[sim]["100"]["all"]["mean_crossing_time_s"]
        mean_plain = results[sim + "_uncontrolled"]["100"]["all"][
            "mean_crossing_time_s"
        ]
        assert pair["diff"] == pytest.approx(mean_policy - mean_plain, abs=1e-6)
    assert "100" in results["comparison"]["sumo_to_jax_gain"]
    # the best constant beside them, on the same vehicles, in both simulators
    assert results["best_constant"]["source"] == "configs/best_constant/milan.json"
    for sim in ("sumo", "jax"):
        best = results[sim + "_best_constant"]
        assert set(best) == {"0", "50", "100"}
        assert best["100"]["all"]["n_arrived"] == 60
        for key in ("policy_vs_best_constant", "best_constant_vs_uncontrolled"):
            pair = results["comparison_best_constant"][key][sim]["100"]["all"]
            assert pair["crossing_time_s"]["n_vehicles"] == 60
        # no AVs: the constant plays no part
        assert best["0"]["all"]["mean_crossing_time_s"] == pytest.approx(
            results[sim]["0"]["all"]["mean_crossing_time_s"]
        )
    assert results["training"]["updates"] == 2
    # the conflict constraint's limit and price per share, as training ended
    training = results["training"]
    assert len(training["conflict_limit_per_1000"]) == len(training["conflict_price"])
    assert all(x >= 0 for x in training["conflict_limit_per_1000"])
    assert all(x >= 1 for x in training["conflict_price"])  # price_min
    assert "conflicts per 1,000 vehicles allowed" in training["conflict_summary"]
    # the JAX evaluation's slots: what the traffic needs, none overflowed
    assert results["max_vehicles"] < 76 and results["jax_slot_overflow"] == 0
    assert results["jax_not_arrived"] == 0 and results["cap_s"] > 0
    assert results["sumo_not_arrived"] == 0 and results["outside_at_cap"] == []
    # Table 4 on one scale over every run of both simulators, and saying so
    for name in ("sumo_policy_table4.md", "jax_policy_table4.md"):
        assert "every run of JAX and SUMO" in (finished_run / name).read_text()
    # one min and max: every run's score is the same line of its grams
    assert results["score_scale"] == results["sumo"]["0"]["score_scale"] == "joint"
    points = [
        (m["all"]["co2_g_per_veh"], m["all"]["emission_score"])
        for sim in ("sumo", "jax")
        for suffix in ("", "_uncontrolled", "_best_constant")
        for m in results[sim + suffix].values()
    ]
    co2, score = np.array(points).T
    slope, intercept = np.polyfit(co2, score, 1)
    assert np.abs(slope * co2 + intercept - score).max() < 1e-6
    for name in (
        "train/policy.npz",
        "train/policy.json",
        "train/metrics.csv",
        "train/learning_curves.png",
        "sumo_policy_table3.md",
        "sumo_policy_table4.md",
        "sumo_policy.png",
        "jax_policy_table3.md",
        "sumo_uncontrolled_table3.md",
        "sumo_best_constant_table3.md",
        "jax_best_constant_table3.md",
        "beside.md",
        "paired.md",
        "readme_tables.md",
        "front.png",
        "behaviour.png",
        "evaluation.json",
        "scenario/milan_small.sumocfg",
    ):
        assert (finished_run / name).is_file(), name


def test_main_job_refuses_to_overwrite(finished_run: Path, capsys) -> None:
    argv = ["run", "--out", str(finished_run), "--quick", "--no-progress"]
    assert main(argv) == 2
    assert "--force" in capsys.readouterr().err


def test_export_copies_and_checks(finished_run: Path, tmp_path: Path, capsys) -> None:
    dst = tmp_path / "p.npz"
    assert main(["export", str(finished_run / "train"), "--out", str(dst)]) == 0
    assert dst.is_file() and dst.with_suffix(".json").is_file()
    assert main(["export", str(finished_run / "train"), "--out", str(dst)]) == 2
    assert "--force" in capsys.readouterr().err
    # a truncated file is refused with its name
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "policy.npz").write_bytes(dst.read_bytes()[:100])
    (bad / "policy.json").write_text(dst.with_suffix(".json").read_text())
    assert main(["export", str(bad), "--out", str(tmp_path / "q.npz")]) == 2
    assert "policy.npz" in capsys.readouterr().err
    # a policy of these roads is refused on other roads, before any work
    argv = ["evaluate", "--policy", str(dst), "--config", "three_leg", "--json"]
    assert main(argv) == 2
    assert "other roads or drivers" in capsys.readouterr().err
