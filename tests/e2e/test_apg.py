"""APG (`agents.apg`): the config, a tiny run through `jaxround train --algo apg`,
its gradient, the NaN guard, determinism and the exported policy.

Compiling an APG update (the environment's step, its derivative and the
recomputation of each checkpointed step) takes the longest here, so it is
compiled once, for the tiny config below, with few optimisations (as in
`test_ppo.py`), and every test reuses that program (`compiled_trainer`
keeps it per config).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from agents.apg import METRICS, APGTrainer
from agents.common.config import (
    APGConfig,
    PPOConfig,
    apg_config_from_dict,
    load_apg_config,
    load_ppo_config,
)
from agents.common.export import load_policy, load_policy_numpy
from agents.run.algorithms import compiled_trainer, csv_columns, load_run_config
from agents.run.metrics_csv import read_csv
from jaxround.apps.cli.main import main
from jaxround.scenario.config import AgentConfig, ConfigError

#: The tiny run: milan's network, 9 vehicles in 20 s, 10 s episodes (20 steps),
#: 8 slots, 4 roundabouts, windows of 5 steps, 4 updates.
TINY = dict(
    demand_window_s=20.0,
    episode_s=10.0,
    max_vehicles=8,
    n_envs=4,
    horizon=5,
    total_env_steps=4 * 5 * 4,
    hidden=(16, 16),
    lr=0.01,
    checkpoint_every=2,
)


def tiny_config(**changes: Any) -> APGConfig:
    return APGConfig(**TINY).replace(**changes)


# --------------------------------------------------------------------------- config


def test_builtin_config_shares_the_ppo_scenario() -> None:
    cfg = load_apg_config()
    assert cfg == load_apg_config("apg_milan")
    assert cfg.num_updates == cfg.total_env_steps // (cfg.n_envs * cfg.horizon)
    assert cfg.relax_temperature > 0
    ppo = load_ppo_config()
    for name in (
        "scenario", "demand_window_s", "episode_s", "max_vehicles", "penetrations",
        "observer", "n_envs", "hidden", "activation", "centralised",
    ):  # fmt: skip
        assert getattr(cfg, name) == getattr(ppo, name), name
    # the same roads, drivers and demand; what the AVs do and are paid for
    # differs (APG differentiates speed commands, PPO retunes assertiveness)
    no_agent = AgentConfig()
    assert dataclasses.replace(
        cfg.training_scenario(), agent=no_agent
    ) == dataclasses.replace(ppo.training_scenario(), agent=no_agent)
    assert apg_config_from_dict(yaml.safe_load(cfg.to_yaml())) == cfg


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"n_steps": 64}, r"APG config: unknown key 'n_steps'"),
        ({"horizon": 0}, r"horizon: 0, expected >= 1"),
        ({"horizon": 8.0}, r"horizon: expected an integer"),
        ({"relax_temperature": -0.1}, r"relax_temperature: -0.1, expected >= 0"),
        ({"relax_temperature": "hot"}, r"relax_temperature: expected a number"),
        ({"lr": 0}, r"lr: 0.0, expected > 0"),
        ({"max_grad_norm": 0.0}, r"max_grad_norm: 0.0, expected > 0"),
        ({"penetrations": [1.5]}, r"penetrations\[0\]: 1.5"),
        ({"total_env_steps": 19}, r"less than one update \(20 env steps\)"),
    ],
)
def test_config_errors_name_the_field(changes: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        apg_config_from_dict({**APGConfig(**TINY).to_dict(), **changes})


def test_run_config_is_told_by_its_fields(tmp_path: Path) -> None:
    for cfg in (tiny_config(), PPOConfig()):
        path = tmp_path / "config.yaml"
        path.write_text(cfg.to_yaml())
        assert load_run_config(path) == cfg
    path.write_text("horizon: 8\nn_steps: 8\n")
    with pytest.raises(ConfigError, match="not a training config"):
        load_run_config(path)


# --------------------------------------------------------------------------- training


@pytest.fixture(scope="module")
def apg_yaml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "tiny_apg.yaml"
    path.write_text(tiny_config().to_yaml())
    return path


@pytest.fixture(scope="module")
def first_run(tmp_path_factory: pytest.TempPathFactory, apg_yaml: Path) -> Path:
    out = tmp_path_factory.mktemp("runs") / "apg"
    args = ["train", "--algo", "apg", "--config", str(apg_yaml), "--out", str(out)]
    assert main([*args, "--no-progress"]) == 0
    return out


def metrics_of(folder: Path) -> dict[str, np.ndarray]:
    rows = read_csv(folder / "metrics.csv")
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def test_train_writes_the_run_and_a_loadable_policy(first_run: Path) -> None:
    cfg = tiny_config()
    assert load_run_config(first_run / "config.yaml") == cfg
    rows = read_csv(first_run / "metrics.csv")
    assert tuple(rows[0]) == csv_columns(cfg) == ("update", "env_steps", *METRICS)
    assert [int(r["update"]) for r in rows] == list(range(1, cfg.num_updates + 1))
    steps = sorted(int(p.name) for p in (first_run / "checkpoints").iterdir())
    assert steps == [2, 4]
    assert (first_run / "learning_curves.png").stat().st_size > 1000
    arrays, layout = load_policy(first_run)
    assert layout.hidden == cfg.hidden
    assert layout.accel_bounds[0] < 0 < layout.accel_bounds[1]
    act = load_policy_numpy(first_run)
    obs = np.zeros((cfg.max_vehicles, layout.obs_size), np.float32)
    accel, lane = act(obs, np.ones(cfg.max_vehicles, bool))
    assert accel.shape == lane.shape == (cfg.max_vehicles,)
    assert np.all((lane == 1.0) | np.isnan(lane))  # "left" or no request
    assert np.all(np.isfinite(arrays["accel_mean/kernel"]))


def test_gradient_is_finite_and_moves_the_actor(first_run: Path) -> None:
    """Every window held AVs; the APG loss had a finite gradient (no update
    was skipped), non-zero once the AVs had been in the network for a window
    (just after their insertion every AV drives at its IDM cap, where the
    command has no effect), and the exported actor is not the initial one."""
    cfg = tiny_config()
    m = metrics_of(first_run)
    assert np.all(m["agent_steps"] > 0)
    assert np.all(np.isfinite(m["grad_norm"])), m["grad_norm"]
    assert np.all(m["grad_norm"][1:] > 0), m["grad_norm"]
    assert m["skipped_updates"][-1] == 0
    trainer, init, _ = compiled_trainer(cfg)
    initial = init(jax.random.PRNGKey(cfg.seed)).params["params"]
    arrays, _ = load_policy(first_run)
    moved = [
        not np.allclose(arrays[f"{layer}/kernel"], np.asarray(initial[layer]["kernel"]))
        for layer in ("actor_0", "actor_1", "accel_mean")
    ]
    assert all(moved)
    assert isinstance(trainer, APGTrainer)
    assert float(trainer.env_params.relax_temperature[0]) == cfg.relax_temperature


def test_same_seed_same_numbers(
    first_run: Path, apg_yaml: Path, tmp_path: Path
) -> None:
    out = tmp_path / "again"
    args = ["train", "--algo", "apg", "--config", str(apg_yaml), "--out", str(out)]
    assert main([*args, "--no-progress"]) == 0
    metrics = (out / "metrics.csv").read_bytes()
    assert metrics == (first_run / "metrics.csv").read_bytes()
    a, _ = load_policy(first_run)
    b, _ = load_policy(out)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_nan_guard_skips_and_counts() -> None:
    """A non-finite gradient leaves parameters and Adam state alone; the
    environments still move on and the skip is counted."""
    cfg = tiny_config()
    _, init, update = compiled_trainer(cfg)
    runner = init(jax.random.PRNGKey(1))
    params = runner.params
    kernel = params["params"]["accel_mean"]["kernel"]
    poisoned = jax.tree.map(lambda x: x, params)
    poisoned["params"]["accel_mean"]["kernel"] = kernel.at[0, 0].set(jnp.nan)
    after, metrics = update(runner._replace(params=poisoned))
    assert float(metrics["skipped_updates"][0]) == 1.0
    assert int(after.skipped) == 1 and int(after.update) == 1
    assert int(after.env_state.step[0]) == int(runner.env_state.step[0]) + cfg.horizon
    for new, old in zip(
        jax.tree.leaves(after.opt_state), jax.tree.leaves(runner.opt_state), strict=True
    ):
        np.testing.assert_array_equal(np.asarray(new), np.asarray(old))


def test_train_cli_refuses_a_mismatched_resume(
    first_run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["train", "--resume", str(first_run), "--algo", "ppo"]) == 2
    assert "trains with apg, not --algo ppo" in capsys.readouterr().err
