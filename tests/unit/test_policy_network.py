"""The policy network (`agents.common.networks`) and its export
(`agents.common.export`): shapes, the sampled distribution, the lane
choices, the NumPy policy against the JAX one, and the files refused.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.common import networks
from agents.common.export import (
    PolicyLayout,
    export_policy,
    load_policy,
    load_policy_numpy,
    policy_action,
)

# --------------------------------------------------------------------------- network


def test_network_shapes_and_distribution() -> None:
    m, d = 6, 5
    network = networks.ActorCritic(hidden=(8,), activation="relu", centralised=True)
    params = networks.init_params(network, jax.random.PRNGKey(0), d, m)
    assert params["params"]["actor_0"]["kernel"].shape == (2 * d, 8)
    obs = jnp.ones((3, m, d))
    out = jax.jit(network.apply)(params, obs, jnp.ones((3, m), bool))
    assert out.accel_mean.shape == (3, m) and out.value.shape == (3, m)
    assert out.lane_logits.shape == (3, m, 2) and out.log_std.shape == ()
    accel, change, logp = jax.jit(networks.sample)(out, jax.random.PRNGKey(1))
    assert accel.shape == change.shape == logp.shape == (3, m)
    gauss = jax.scipy.stats.norm.logpdf(accel, out.accel_mean, jnp.exp(out.log_std))
    lane = jnp.take_along_axis(
        jax.nn.log_softmax(out.lane_logits), change[..., None], -1
    )[..., 0]
    np.testing.assert_allclose(np.asarray(logp), np.asarray(gauss + lane), atol=1e-5)
    action = networks.env_action(accel, change)
    assert action.shape == (3, m, 2)


def test_centralised_input_is_the_mean_of_the_others() -> None:
    obs = np.array([[1.0], [2.0], [4.0], [8.0]], np.float32)
    mask = np.array([True, True, True, False])
    x = networks.policy_inputs(obs, mask, True, np)
    np.testing.assert_allclose(x[:, 1], [3.0, 2.5, 1.5, 7.0 / 3.0])
    np.testing.assert_allclose(x[:, 0], obs[:, 0])
    lone = networks.policy_inputs(obs[:1], mask[:1], True, np)
    assert lone[0, 1] == 0.0


def test_lane_choices_and_their_column() -> None:
    """Two choices (one-lane roads): keep (no request) or change (the lane
    to the left), as a bool or 0/1; three (two-lane roads): no request,
    left, right. The policy's mode is the likeliest choice, the lowest
    index among equals."""
    assert networks.lane_choices_for(False) == 2
    assert networks.lane_choices_for(True) == 3
    for xp in (np, jnp):
        column = np.asarray(networks.lane_column(xp.asarray([0, 1, 2]), xp))
        assert np.isnan(column[0]) and column[1] == 1.0 and column[2] == -1.0
        as_bool = np.asarray(networks.lane_column(xp.asarray([False, True]), xp))
        assert np.isnan(as_bool[0]) and as_bool[1] == 1.0
    logits = np.array([[0.0, 1.0, 2.0], [3.0, 1.0, 2.0], [1.0, 1.0, 0.0]])
    _, change = networks.deterministic_action(np.zeros(3), logits, (-1.0, 1.0), np)
    np.testing.assert_array_equal(change, [2, 0, 0])
    network = networks.ActorCritic(hidden=(8,), lane_choices=3)
    params = networks.init_params(network, jax.random.PRNGKey(0), 5, 4)
    out = network.apply(params, jnp.ones((4, 5)), jnp.ones(4, bool))
    assert out.lane_logits.shape == (4, 3)
    _, change, _ = networks.sample(out, jax.random.PRNGKey(1))
    assert set(np.asarray(change).tolist()) <= {0, 1, 2}


def test_three_lane_choices_round_trip(tmp_path: Path) -> None:
    """A two-lane policy's three lane logits are exported, read back and
    acted on: the NumPy policy asks for the lane its likeliest choice names;
    a policy file of before the field reads as two choices; another count
    is refused, naming it."""
    m, d = 5, 24
    network = networks.ActorCritic(hidden=(8,), lane_choices=3)
    params = networks.init_params(network, jax.random.PRNGKey(2), d, m)
    params = jax.tree.map(lambda x: x * 20.0, params)
    layout = PolicyLayout("lanes", d, (8,), "tanh", False, (-4.5, 2.6), lane_choices=3)
    _, js = export_policy(params, layout, tmp_path / "three")
    assert json.loads(js.read_text())["arrays"]["lane_logits/kernel"] == [8, 3]
    arrays, loaded = load_policy(js)
    assert loaded == layout
    obs = np.random.default_rng(0).normal(size=(m, d)).astype(np.float32)
    mask = np.ones(m, bool)
    out = network.apply(params, jnp.asarray(obs), jnp.asarray(mask))
    choice = np.argmax(np.asarray(out.lane_logits), axis=-1)
    _, lane = load_policy_numpy(js)(obs, mask)
    expected = np.where(choice == 1, 1.0, np.where(choice == 2, -1.0, np.nan))
    np.testing.assert_array_equal(lane, expected)
    two = networks.ActorCritic(hidden=(8,))
    old = PolicyLayout("rich", 3, (8,), "tanh", False, (-4.0, 2.0))
    _, old_js = export_policy(
        networks.init_params(two, jax.random.PRNGKey(0), 3, 2), old, tmp_path / "old"
    )
    meta = json.loads(old_js.read_text())
    del meta["lane_choices"]
    old_js.write_text(json.dumps(meta))
    assert load_policy(old_js)[1].lane_choices == 2
    meta["lane_choices"] = 4
    old_js.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="lane_choices 4, expected one of"):
        load_policy(old_js)


# --------------------------------------------------------------------------- export


@pytest.mark.parametrize(
    ("activation", "centralised"), [("tanh", False), ("relu", True)]
)
def test_export_round_trip(tmp_path: Path, activation: str, centralised: bool) -> None:
    m, d = 9, 10
    network = networks.ActorCritic(
        hidden=(32, 16), activation=activation, centralised=centralised
    )
    params = networks.init_params(network, jax.random.PRNGKey(3), d, m)
    # larger weights than at init, so the heads say something
    params = jax.tree.map(lambda x: x * 5.0, params)
    layout = PolicyLayout(
        observer="paper", obs_size=d, hidden=(32, 16), activation=activation,
        centralised=centralised, accel_bounds=(-4.5, 2.6), scenario="milan",
    )  # fmt: skip
    npz, js = export_policy(params, layout, tmp_path / "policy")
    assert json.loads(js.read_text())["hidden"] == [32, 16]
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(4, m, d)).astype(np.float32)
    mask = rng.uniform(size=(4, m)) < 0.7
    out = jax.jit(network.apply)(params, jnp.asarray(obs), jnp.asarray(mask))
    accel_jax, change_jax = networks.deterministic_action(
        out.accel_mean, out.lane_logits, layout.accel_bounds
    )
    act = load_policy_numpy(tmp_path)  # the folder finds policy.npz
    for i in range(4):
        accel, lane = act(obs[i], mask[i])  # lane: 1.0 (left) or NaN (none)
        assert accel.dtype == np.float32
        np.testing.assert_allclose(accel, np.asarray(accel_jax[i]), atol=1e-5)
        np.testing.assert_array_equal(lane == 1.0, np.asarray(change_jax[i]) == 1)
        assert np.isnan(lane[np.asarray(change_jax[i]) == 0]).all()
    assert np.any(np.asarray(accel_jax) == 2.6) or np.any(np.asarray(accel_jax) < 0)
    arrays, loaded = load_policy(npz)
    assert loaded == layout
    weights = {k: jnp.asarray(v) for k, v in arrays.items()}
    accel_j, _ = jax.jit(lambda w, o, k: policy_action(w, loaded, o, k, jnp))(
        weights, obs, mask
    )
    np.testing.assert_allclose(np.asarray(accel_j), np.asarray(accel_jax), atol=1e-5)
    with pytest.raises(ValueError, match="numbers"):
        act(obs[0, :, :4], mask[0])


def test_export_refuses_mismatched_files(tmp_path: Path) -> None:
    network = networks.ActorCritic(hidden=(4,))
    params = networks.init_params(network, jax.random.PRNGKey(0), 3, 2)
    layout = PolicyLayout("rich", 3, (4,), "tanh", False, (-4.0, 2.0))
    _, js = export_policy(params, layout, tmp_path / "p.npz")
    meta = json.loads(js.read_text())
    meta["hidden"] = [5]
    js.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="actor_0/kernel has shape"):
        load_policy(tmp_path / "p")
    with pytest.raises(FileNotFoundError):
        load_policy(tmp_path / "missing")


def test_non_finite_weights_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A NaN weight is refused when exported and when loaded (evaluate, export,
    the SUMO controller and the study all load through `load_policy`)."""
    network = networks.ActorCritic(hidden=(4,))
    params = networks.init_params(network, jax.random.PRNGKey(0), 3, 2)
    layout = PolicyLayout("rich", 3, (4,), "tanh", False, (-4.0, 2.0))
    npz, _ = export_policy(params, layout, tmp_path / "p.npz")
    with np.load(npz) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["accel_mean/bias"] = np.array([np.nan], np.float32)
    np.savez(npz, **arrays)
    with pytest.raises(ValueError, match="'accel_mean/bias' holds 1 non-finite"):
        load_policy(tmp_path / "p")
    with pytest.raises(ValueError, match="non-finite"):
        load_policy_numpy(tmp_path / "p")
    from jaxround.apps.cli.main import main

    assert main(["evaluate", "--policy", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert "accel_mean/bias" in err and "non-finite" in err
    assert "Traceback" not in err
    bad = jax.tree.map(lambda x: x, params)
    kernel = bad["params"]["actor_0"]["kernel"]
    bad["params"]["actor_0"]["kernel"] = kernel.at[0, 0].set(jnp.inf)
    with pytest.raises(ValueError, match="'actor_0/kernel' holds 1 non-finite"):
        export_policy(bad, layout, tmp_path / "q")
    assert not (tmp_path / "q.npz").exists()
