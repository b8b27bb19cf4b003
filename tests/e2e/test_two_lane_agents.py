"""The main job, training, evaluation and the search on two lanes: `jaxround
run --config` on `two_lane`'s roads trains a policy with three lane choices
(no request, left, right) and evaluates it in JAX and, through the exported
controller, in SUMO, beside uncontrolled AVs and the best constant, lane
changes per vehicle in its tables (through `pipeline.evaluate_everywhere`,
which `jaxround evaluate --sim sumo` runs; the command's own arguments and
its JAX-only run are tested on Milan, tests/e2e/test_train_cli.py); the
lane choices it makes reach both simulators as lane requests; `jaxround
search` finds a constant AV setting on them.

One tiny main job (two roundabouts, two updates of 8 steps, 20 s of demand
in training, 16 vehicles in 30 s in evaluation) is shared by the tests; what
it learns does not matter here, only that the pieces fit. What a full run
learns is in docs/two_lane.md.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from agents.common.config import load_ppo_config
from agents.common.export import load_policy
from jaxround.apps.cli.main import main
from tests.e2e.test_train_cli import small_scenario
from tests.unit.test_ppo import tiny_config

#: Vehicles of the evaluation's small two-lane scenario.
N_VEHICLES = 16


@pytest.fixture(scope="module")
def main_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`jaxround run` on a small two-lane scenario (its name kept, so its best
    constant is two_lane's) with a tiny training config on its roads."""
    folder = tmp_path_factory.mktemp("two_lane")
    cfg = tiny_config(
        scenario="two_lane", observer="lanes", max_vehicles=16, n_envs=2,
        total_env_steps=2 * 8 * 2, demand_window_s=20.0, episode_s=15.0,
    )  # fmt: skip
    (folder / "tiny.yaml").write_text(cfg.to_yaml())
    scenario = small_scenario(folder, "two_lane", n_vehicles=N_VEHICLES)
    # slots for all its vehicles, so that the evaluation does not size them
    # from the traffic first (a run of the two-lane step at 48 slots, about
    # a minute; tests/e2e/test_pipeline.py's main job sizes its own)
    d = yaml.safe_load(scenario.read_text())
    d["simulation"]["max_vehicles"] = N_VEHICLES
    scenario.write_text(yaml.safe_dump(d))
    out = folder / "run"
    argv = ["run", "--config", str(scenario), "--out", str(out), "--quick"]
    argv += ["--train-config", str(folder / "tiny.yaml"), "--workers", "1"]
    assert main([*argv, "--no-progress"]) == 0
    return out


@pytest.fixture(scope="module")
def run(main_job: Path) -> Path:
    """The main job's training run."""
    return main_job / "train"


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


def test_main_job_on_two_lanes(main_job: Path) -> None:
    """Both simulators drive every vehicle to its exit with the policy,
    uncontrolled AVs and two_lane's best constant, and count lane changes
    per vehicle and class, shown in the tables."""
    results = json.loads((main_job / "results.json").read_text())
    assert results["best_constant"]["source"] == "configs/best_constant/two_lane.json"
    for sim in ("sumo", "jax"):
        for suffix in ("", "_uncontrolled", "_best_constant"):
            runs = results[sim + suffix]
            assert set(runs) == {"0", "50", "100"}
            for label, m in runs.items():
                assert m["all"]["n_arrived"] == N_VEHICLES, (sim + suffix, label)
                assert m["collisions"] == 0
                # the vehicles of every two-lane route change lanes at least
                # once (the roundabout bonus takes them to the left entry lane,
                # or their exit back to the outer ring lane)
                assert m["all"]["lane_changes_per_veh"] > 0.5, (sim + suffix, label)
            assert runs["0"]["av"]["lane_changes_per_veh"] is None  # no AVs
            assert runs["50"]["av"]["lane_changes_per_veh"] is not None
    beside = (main_job / "beside.md").read_text()
    assert "lane changes per vehicle, 0 / 50 / 100% AVs" in beside
    assert (
        "lane changes per veh AV" in (main_job / "sumo_policy_absolute.md").read_text()
    )


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
