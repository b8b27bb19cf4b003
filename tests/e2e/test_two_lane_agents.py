"""Training, evaluation and the search on two lanes: `jaxround train` on
`two_lane`'s roads gives a policy with three lane choices (no request,
left, right) that `jaxround evaluate` drives in JAX and, through the
exported controller, in SUMO; the lane choices it makes reach both
simulators as lane requests; `jaxround search` finds a constant AV setting
on them.

One tiny run (two roundabouts, two updates of 8 steps, 20 s of demand) is
shared by the tests; what it learns does not matter here, only that the
pieces fit. What a full run learns is in docs/two_lane.md.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from agents.common.config import load_ppo_config
from agents.common.export import load_policy
from jaxround.apps.cli.main import main
from tests.e2e.test_train_cli import small_scenario
from tests.unit.test_ppo import tiny_config


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("two_lane")
    cfg = tiny_config(
        scenario="two_lane", observer="lanes", max_vehicles=16, n_envs=2,
        total_env_steps=2 * 8 * 2, demand_window_s=20.0, episode_s=15.0,
    )  # fmt: skip
    (folder / "tiny.yaml").write_text(cfg.to_yaml())
    out = folder / "run"
    argv = ["train", "--config", str(folder / "tiny.yaml"), "--out", str(out)]
    assert main([*argv, "--no-progress"]) == 0
    return out


def test_training_on_two_lanes_gives_three_lane_choices(run: Path) -> None:
    arrays, layout = load_policy(run)
    assert layout.lane_choices == 3 and layout.observer == "lanes"
    assert layout.obs_size == 24  # the rich observer's 17 and 7 lane columns
    assert arrays["lane_logits/kernel"].shape == (16, 3)
    assert load_ppo_config(run / "config.yaml").scenario == "two_lane"
    assert layout.scenario_fingerprint  # evaluation checks the roads


def test_the_builtin_two_lane_config_reads() -> None:
    cfg = load_ppo_config("ppo_two_lane")
    assert cfg.scenario == "two_lane" and cfg.observer == "lanes"
    assert cfg.training_scenario().network.ring_lanes == 2


def test_evaluate_a_two_lane_policy_in_jax_and_sumo(
    run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Both simulators drive every vehicle of a small two-lane demand to its
    exit with the policy, with uncontrolled AVs and with the scenario's best
    constant (configs/best_constant/two_lane.json, the scenario's name)."""
    scenario = small_scenario(tmp_path, "two_lane", n_vehicles=16)
    argv = [
        "evaluate", "--policy", str(run), "--config", str(scenario),
        "--penetrations", "50", "--max-vehicles", "16", "--json",
    ]  # fmt: skip
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report["results"]) == {"policy", "uncontrolled", "best_constant"}
    source = "configs/best_constant/two_lane.json"
    assert report["best_constant"]["source"] == source
    for driver in report["results"].values():
        assert driver["50"]["all"]["n_arrived"] == 16
    out = tmp_path / "sumo"
    argv += ["--sim", "sumo", "--out", str(out), "--workers", "1"]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert (out / "evaluation.json").exists()
    sims = ["sumo", "sumo_uncontrolled", "jax", "jax_uncontrolled"]
    for sim in [*sims, "sumo_best_constant", "jax_best_constant"]:
        assert report[sim]["50"]["all"]["n_arrived"] == 16, sim


def test_each_lane_choice_is_its_request(run: Path, tmp_path: Path) -> None:
    """The trained policy with lane logits that say "right" everywhere asks
    for every AV's lane to the right (-1.0); "left", 1.0; "none", NaN
    (LC2013 decides), as SUMO's controller and the JAX step read them."""
    from agents.common.export import load_policy_numpy, policy_paths

    npz, js = policy_paths(tmp_path / "policy")
    arrays, layout = load_policy(run)
    js.write_text((run / "policy.json").read_text())
    obs = np.zeros((4, layout.obs_size), np.float32)
    mask = np.ones(4, bool)
    for choice, expected in ((0, np.nan), (1, 1.0), (2, -1.0)):
        bias = np.full(3, -50.0, np.float32)
        bias[choice] = 50.0
        np.savez(npz, **{**arrays, "lane_logits/bias": bias})
        _, lane = load_policy_numpy(js)(obs, mask)
        np.testing.assert_array_equal(lane, np.full(4, expected))


def test_search_on_two_lanes(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    """The search of constant AV settings runs on two lanes (a tiny one: one
    generation of two settings on 30 s of demand) and writes its best
    constant, every vehicle of its runs arrived."""
    out = tmp_path / "out"
    argv = [
        "search", "--config", "two_lane", "--out", str(out), "--window-s", "30",
        "--search-seeds", "1", "--eval-seeds", "1", "--population", "2",
        "--generations", "1", "--state-generations", "1", "--max-vehicles", "32",
    ]  # fmt: skip
    assert main(argv) == 0
    result = json.loads((out / "search.json").read_text())
    assert result["scenario"] == "two_lane"
    for runs in result["eval"].values():
        assert runs["missing"] == 0 and runs["overflow"] == 0
    assert (out / "best_constant.json").exists()
    assert "best constant" in capsys.readouterr().out
