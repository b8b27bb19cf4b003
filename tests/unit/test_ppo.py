"""PPO (`agents`): GAE by hand, the masked loss, the config, and the
training program (chunks against the whole run, two seeds on two devices).
The policy network and its export: `test_policy_network.py`.

Compiling a training update takes tens of seconds on a CPU (it holds the
environment's step), so only two tests build one, on the tiny config below
(with the few optimisations and the session's persistent cache that every
test compiles with, `conftest.pytest_configure`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.common import networks
from agents.common.config import PPOConfig, load_ppo_config, ppo_config_from_dict
from agents.ppo import Trainer
from agents.ppo.losses import Batch, compute_gae, ppo_loss
from jaxround.scenario.config import ConfigError
from tests.conftest import QUICK_ENV

ROOT = Path(__file__).resolve().parents[2]
#: The tiny training run of the tests: milan's network, 9 vehicles in 20 s,
#: 10 s episodes (a reset every 20 steps), 8 slots, 4 roundabouts, 4 updates.
TINY = dict(
    demand_window_s=20.0,
    episode_s=10.0,
    max_vehicles=8,
    n_envs=4,
    n_steps=8,
    total_env_steps=4 * 8 * 4,
    hidden=(16, 16),
    epochs=2,
    minibatches=2,
    checkpoint_every=2,
    reward_scale=0.1,
    action="assertiveness",
    reward="system",
    trip_noise=True,
)


def tiny_config(**changes: Any) -> PPOConfig:
    return PPOConfig(**TINY).replace(**changes)


# --------------------------------------------------------------------------- GAE


def test_gae_by_hand() -> None:
    """Three slots over T=4 steps, gamma 0.9, lambda 0.8 (gamma * lambda = 0.72).

    slot 0: its vehicle leaves in step 1 (no bootstrap), a new one enters;
            the episode ends with step 2 (bootstrap from its own value).
    slot 1: an agent until the reset at step 2, empty afterwards (garbage data).
    slot 2: an agent at t=0, 1, then no agent without a termination
            (bootstrap from its own value, defensively).
    """
    f, t = False, True
    reward = np.array([[1, 1, 1], [2, 1, 1], [3, 1, 0], [4, 99, 0]], np.float32)
    value = np.array([[0.5, 1, 2], [1, 1, 2], [1.5, 1, 0], [2, -50, 0]], np.float32)
    agent = np.array([[t, t, t], [t, t, t], [t, t, f], [t, f, f]])
    terminated = np.array([[f, f, f], [t, f, f], [f, f, f], [f, f, f]])
    truncated = np.array([[f] * 3, [f] * 3, [t] * 3, [f] * 3])
    adv, target = compute_gae(
        jnp.asarray(reward), jnp.asarray(value), jnp.asarray(agent),
        jnp.asarray(terminated), jnp.asarray(truncated),
        jnp.array([3.0, 7.0, 5.0]), jnp.array([t, f, f]), 0.9, 0.8,
    )  # fmt: skip
    expected = np.array(
        [
            [1.4 + 0.72 * 1.0, 0.9 + 0.72 * (0.9 + 0.72 * 0.9), 0.8 + 0.72 * 0.8],
            [2 - 1.0, 0.9 + 0.72 * 0.9, 1 + 0.9 * 2 - 2],
            [3 + 0.9 * 1.5 - 1.5, 1 + 0.9 * 1 - 1, 0],
            [4 + 0.9 * 3 - 2, 0, 0],
        ]
    )
    np.testing.assert_allclose(np.asarray(adv), expected, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(
        np.asarray(target), np.where(agent, expected + value, 0), rtol=1e-6, atol=1e-6
    )


def gae_reference(reward, value, agent, terminated, truncated, last_v, last_a, g, lam):
    """Per-slot loops: walk each trajectory backwards."""
    n_t, n_s = reward.shape
    value_ext = np.vstack([value, last_v[None]])
    agent_ext = np.vstack([agent, last_a[None]])
    adv = np.zeros((n_t, n_s))
    for s in range(n_s):
        acc = 0.0
        for t in reversed(range(n_t)):
            if not agent[t, s]:
                acc = 0.0
                continue
            if terminated[t, s]:
                nxt, cont = 0.0, False
            elif truncated[t, s] or not agent_ext[t + 1, s]:
                nxt, cont = value[t, s], False
            else:
                nxt, cont = value_ext[t + 1, s], True
            delta = reward[t, s] + g * nxt - value[t, s]
            acc = delta + (g * lam * acc if cont else 0.0)
            adv[t, s] = acc
    return adv


def test_gae_matches_per_slot_loops() -> None:
    rng = np.random.default_rng(0)
    n_t, n_s = 12, 7
    reward = rng.normal(size=(n_t, n_s)).astype(np.float32)
    value = rng.normal(size=(n_t, n_s)).astype(np.float32)
    agent = rng.uniform(size=(n_t, n_s)) < 0.7
    terminated = agent & (rng.uniform(size=(n_t, n_s)) < 0.2)
    truncated = np.repeat(rng.uniform(size=(n_t, 1)) < 0.15, n_s, axis=1)
    last_v = rng.normal(size=n_s).astype(np.float32)
    last_a = rng.uniform(size=n_s) < 0.5
    args = (reward, value, agent, terminated, truncated, last_v, last_a, 0.97, 0.9)
    adv, _ = compute_gae(*map(jnp.asarray, args[:7]), 0.97, 0.9)
    np.testing.assert_allclose(np.asarray(adv), gae_reference(*args), atol=1e-5)


# --------------------------------------------------------------------------- loss


def random_batch(rng: np.random.Generator, e: int, m: int, d: int) -> Batch:
    active = rng.uniform(size=(e, m)) < 0.8
    return Batch(
        obs=jnp.asarray(rng.normal(size=(e, m, d)) * active[..., None], jnp.float32),
        active=jnp.asarray(active),
        agent=jnp.asarray(active & (rng.uniform(size=(e, m)) < 0.6)),
        accel=jnp.asarray(rng.normal(size=(e, m)), jnp.float32),
        change=jnp.asarray(rng.integers(0, 2, (e, m)), jnp.int32),
        log_prob=jnp.asarray(rng.normal(size=(e, m)) - 2.0, jnp.float32),
        value=jnp.asarray(rng.normal(size=(e, m)), jnp.float32),
        advantage=jnp.asarray(rng.normal(size=(e, m)), jnp.float32),
        target=jnp.asarray(rng.normal(size=(e, m)), jnp.float32),
    )


def loss_and_grads(network: networks.ActorCritic, params: Any, batch: Batch):
    @jax.jit
    def fn(params: Any, batch: Batch):
        grad_fn = jax.value_and_grad(ppo_loss, has_aux=True)
        return grad_fn(params, network.apply, batch, 0.2, 0.5, 0.01)

    (loss, aux), grads = fn(params, batch)
    return loss, aux, grads


@pytest.mark.parametrize("centralised", [False, True])
def test_loss_ignores_non_agent_slots(centralised: bool) -> None:
    """Whatever HV and empty slots hold leaves the loss and its gradient alone
    (with the centralised input, HV rows' observations are inputs by design:
    there only empty slots' observations may change)."""
    rng = np.random.default_rng(1)
    batch = random_batch(rng, 6, 5, 7)
    network = networks.ActorCritic(hidden=(8, 8), centralised=centralised)
    params = networks.init_params(network, jax.random.PRNGKey(0), 7, 5)
    loss, aux, grads = loss_and_grads(network, params, batch)

    other = ~batch.agent
    may_change_obs = other if not centralised else ~batch.active

    def garble(x: jax.Array, where: jax.Array, scale: float) -> jax.Array:
        noise = jnp.asarray(rng.normal(size=x.shape) * scale, x.dtype)
        where = where.reshape(where.shape + (1,) * (x.ndim - where.ndim))
        return jnp.where(where, x + noise, x)

    garbled = batch._replace(
        obs=garble(batch.obs, may_change_obs, 100.0),
        accel=garble(batch.accel, other, 1e4),
        change=jnp.where(other, 1 - batch.change, batch.change),
        log_prob=garble(batch.log_prob, other, 1e3),
        value=garble(batch.value, other, 1e3),
        advantage=garble(batch.advantage, other, 1e3),
        target=garble(batch.target, other, 1e3),
    )
    loss2, aux2, grads2 = loss_and_grads(network, params, garbled)
    np.testing.assert_allclose(float(loss2), float(loss), rtol=1e-6)
    for k in aux:
        np.testing.assert_allclose(float(aux2[k]), float(aux[k]), rtol=1e-6, err_msg=k)
    for g, g2 in zip(jax.tree.leaves(grads), jax.tree.leaves(grads2), strict=True):
        np.testing.assert_allclose(np.asarray(g2), np.asarray(g), rtol=1e-5, atol=1e-7)
    # an agent's data does count
    moved = batch._replace(advantage=garble(batch.advantage, batch.agent, 1.0))
    assert float(loss_and_grads(network, params, moved)[0]) != float(loss)


# --------------------------------------------------------------------------- config


def test_builtin_config_and_derived_values() -> None:
    cfg = load_ppo_config()
    assert cfg == load_ppo_config("ppo_milan")
    assert cfg.num_updates == cfg.total_env_steps // (cfg.n_envs * cfg.n_steps)
    assert cfg.minibatch_size == cfg.n_envs * cfg.n_steps * cfg.max_vehicles // (
        cfg.minibatches
    )
    scenario = cfg.training_scenario()
    assert scenario.demand.n_vehicles == round(1540 * cfg.demand_window_s / 3600)
    assert scenario.demand.duration_s == cfg.demand_window_s
    assert ppo_config_from_dict(cfg.to_dict()) == cfg
    import yaml

    assert ppo_config_from_dict(yaml.safe_load(cfg.to_yaml())) == cfg


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"n_env": 4}, r"unknown key 'n_env'"),
        ({"n_envs": "64"}, r"n_envs: expected an integer, got '64'"),
        ({"n_envs": 4.0}, r"n_envs: expected an integer"),
        ({"anneal_lr": 1}, r"anneal_lr: expected true or false"),
        ({"hidden": 64}, r"hidden: expected a list"),
        ({"hidden": [64, 0]}, r"hidden\[1\]: 0, expected >= 1"),
        ({"gamma": 1.5}, r"gamma: 1.5, expected in \(0, 1\]"),
        ({"lr": -0.1}, r"lr: -0.1, expected > 0"),
        ({"penetrations": [0.5, 1.2]}, r"penetrations\[1\]: 1.2"),
        ({"penetrations": []}, r"penetrations: empty"),
        ({"activation": "gelu"}, r"activation: 'gelu'"),
        ({"observer": "eyes"}, r"observer: 'eyes'"),
        ({"minibatches": 3}, r"minibatches: 3 does not divide"),
        ({"total_env_steps": 10}, r"less than one update"),
        ({"ent_coef": float("nan")}, r"ent_coef: expected a finite number"),
    ],
)
def test_config_errors_name_the_field(changes: dict, message: str) -> None:
    d = {**PPOConfig(**TINY).to_dict(), **changes}
    with pytest.raises(ConfigError, match=message):
        ppo_config_from_dict(d)


def test_config_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no PPO config file of that name"):
        load_ppo_config("atlantis")
    with pytest.raises(ConfigError, match="does not exist"):
        load_ppo_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("- a list\n")
    with pytest.raises(ConfigError, match="expected a mapping"):
        load_ppo_config(bad)


# --------------------------------------------------------------------------- training


@pytest.fixture(scope="module")
def trainer() -> Trainer:
    return Trainer(tiny_config())


CHUNKS = """
import json, sys
import jax, numpy as np
from agents.ppo import Trainer
from tests.conftest import tree_equal
from tests.unit.test_ppo import tiny_config

trainer = Trainer(tiny_config())
cfg = trainer.config
key = jax.random.PRNGKey(cfg.seed)
runner, metrics = jax.jit(trainer.train)(key)
chunk = trainer.update_chunk(1)
stepped = jax.jit(trainer.init)(key)
parts = []
for _ in range(cfg.num_updates):
    stepped, m = chunk(stepped)
    parts.append(m)
chunked = {k: np.concatenate([np.asarray(p[k]) for p in parts]) for k in metrics}
differ = [
    jax.tree_util.keystr(path)
    for (path, a), (_, b) in zip(
        jax.tree_util.tree_flatten_with_path(runner)[0],
        jax.tree_util.tree_flatten_with_path(stepped)[0],
    )
    if not tree_equal(a, b)
]
print(json.dumps({
    "num_updates": cfg.num_updates,
    "lr": cfg.lr,
    "update": int(runner.update),
    "metrics": {k: np.asarray(v).tolist() for k, v in metrics.items()},
    "metrics_equal": tree_equal(chunked, metrics),
    "state_leaves_differ": differ,
}))
"""


def run_script(script: str, env: dict[str, str]) -> dict[str, Any]:
    """Run ``python -c script`` from the repository root with ``env``; the
    JSON object its last line of output prints."""
    done = subprocess.run(
        [sys.executable, "-c", script],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_chunks_equal_the_whole_run() -> None:
    """`train(key)` in one program and `init` + `update_chunk(1)` call by call
    (as the CLI runs) give bit-identical parameters, states and metrics.

    Checked at XLA's full optimisation, as a user runs both: with most
    optimisations off (the tests' quick mode) XLA may round one layer's
    gradient differently in the two programs (last-bit differences)."""
    out = run_script(CHUNKS, {**os.environ, QUICK_ENV: "0"})
    n = out["num_updates"]
    metrics = out["metrics"]
    assert out["update"] == n
    assert all(np.shape(v) == (n,) for v in metrics.values())
    assert np.all(np.asarray(metrics["agent_steps"]) > 0)
    for k in ("policy_loss", "value_loss", "entropy", "approx_kl"):
        assert np.all(np.isfinite(np.asarray(metrics[k]))), k
    assert metrics["learning_rate"][0] == pytest.approx(out["lr"])
    assert out["metrics_equal"]
    assert out["state_leaves_differ"] == []


def test_trip_noise_is_held_while_a_vehicle_keeps_its_slot(trainer: Trainer) -> None:
    runner = jax.jit(trainer.init)(jax.random.PRNGKey(1))
    runner, traj = jax.jit(trainer.rollout)(runner)
    out = trainer.apply(runner.params, traj.obs, traj.active)
    noise = np.asarray((traj.accel - out.accel_mean) * jnp.exp(-out.log_std))
    active = np.asarray(traj.active)
    # a slot holds the same vehicle while its position keeps growing
    pos = np.asarray(traj.obs[..., 0])
    same = active[1:] & active[:-1] & (pos[1:] > pos[:-1])
    assert same.sum() > 20
    np.testing.assert_allclose(noise[1:][same], noise[:-1][same], atol=1e-4)
    assert np.std(noise[active]) > 0.3  # but it does vary between vehicles


TWO_DEVICES = """
import json, sys
import jax, numpy as np
from agents.ppo import Trainer
from jaxround.scenario.config import ConfigError
from tests.conftest import tree_equal
from tests.unit.test_ppo import tiny_config

assert jax.device_count() == 2, jax.devices()
try:
    Trainer(tiny_config(n_envs=3, minibatches=1, total_env_steps=24))
    sys.exit("n_envs=3 on 2 devices was accepted")
except ConfigError as err:
    refused = str(err)
trainer = Trainer(tiny_config(total_env_steps=4 * 8 * 2))
keys = jax.random.split(jax.random.PRNGKey(0), 2)
runner, metrics = jax.jit(jax.vmap(trainer.train))(keys)
print(json.dumps({
    "refused": refused,
    "obs_shape": list(runner.obs.shape),
    "obs_devices": len(runner.obs.sharding.device_set),
    "pos_devices": len(runner.env_state.pos.sharding.device_set),
    "metrics": {k: np.asarray(v).tolist() for k, v in metrics.items()},
}))
"""


def test_two_seeds_sharded_over_two_devices() -> None:
    """Two seeds in one vmap with the roundabouts split over two (host) devices."""
    env = {
        **os.environ,
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", "")
        + " --xla_force_host_platform_device_count=2",
    }
    out = run_script(TWO_DEVICES, env)
    assert "cannot be split evenly over 2 devices" in out["refused"]
    m = tiny_config().max_vehicles
    assert out["obs_shape"][:3] == [2, 4, m]
    assert out["obs_devices"] == 2 and out["pos_devices"] == 2
    metrics = out["metrics"]
    assert np.shape(metrics["value_loss"]) == (2, 2)
    assert np.all(np.isfinite(metrics["value_loss"]))
    assert metrics["agent_steps"][0] != metrics["agent_steps"][1]  # seeds differ
