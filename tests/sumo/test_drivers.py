"""The AVs' drivers in both simulators: scripted controllers and assertiveness
policies give the same vehicles the same crossing times in JAX and in real
SUMO; a zero assertiveness is the vType itself; bad specs fail first."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.common.export import PolicyLayout, export_policy
from jaxround.apps.drivers import parse_driver
from jaxround.apps.parity import parity_report
from jaxround.envs.rollout import run_until_left, uncontrolled_policy
from jaxround.envs.roundabout import make
from jaxround.scenario.config import ScenarioConfig, config_from_dict
from jaxround.scenario.schedule import make_schedule
from tests.conftest import small_config, tree_equal


def constant_policy(path: Path, raw: float) -> Path:
    """An exported assertiveness policy whose raw action is `raw` everywhere."""
    layout = PolicyLayout(
        observer="rich", obs_size=17, hidden=(8,), activation="tanh",
        centralised=False, accel_bounds=(-3.0, 3.0), action="assertiveness",
        scenario="milan",
    )  # fmt: skip
    tree = {"log_std": np.float32(0.0)}
    for name, shape in layout.array_shapes().items():
        if "/" in name:
            layer, leaf = name.split("/")
            tree.setdefault(layer, {})[leaf] = np.zeros(shape, np.float32)
    tree["accel_mean"]["bias"][:] = raw
    npz, _ = export_policy({"params": tree}, layout, path / f"constant_{raw}")
    return npz


def test_zero_assertiveness_is_the_vtype() -> None:
    cfg = small_config("milan", n_vehicles=40, duration_s=120.0)
    d = cfg.to_dict()
    d["agent"]["action"] = "assertiveness"
    env, params = make(config_from_dict(d), episode_s=400.0)
    sched = env.schedule_from_numpy(make_schedule(env.cfg, seed=5, penetration=1.0))

    def zero(obs, state, key):
        return jnp.zeros((env.max_vehicles, 2))

    key = jax.random.PRNGKey(0)
    a = jax.jit(lambda s: run_until_left(env, params, s, key, zero))(sched)
    b = jax.jit(
        lambda s: run_until_left(env, params, s, key, uncontrolled_policy(env))
    )(sched)
    assert tree_equal(a, b)
    assert np.all(np.isfinite(np.asarray(a.arrival_s)))


def driven_config() -> ScenarioConfig:
    return small_config("milan", n_vehicles=60, duration_s=150.0)


@pytest.fixture(scope="module")
def uncontrolled_report() -> dict[str, Any]:
    """Parity of the uncontrolled vType on the drivers' scenario (seed 3)."""
    return parity_report(
        driven_config(), [3], workers=1, show_progress=False, penetration=1.0
    )


@pytest.mark.sumo
@pytest.mark.parametrize("controller", ["cruise:6", "assertive"])
def test_same_crossing_times_in_both_simulators(
    controller: str, tmp_path: Path, uncontrolled_report: dict[str, Any]
) -> None:
    cfg = driven_config()
    if controller == "assertive":
        controller = str(constant_policy(tmp_path, 1.0))
    report = parity_report(
        cfg, [3], workers=1, show_progress=False, penetration=1.0,
        controller=controller,
    )  # fmt: skip
    assert report["jax_not_arrived"] == report["sumo_not_arrived"] == 0
    assert report["per_vehicle_median_abs_err_s"] == 0.0
    assert report["per_vehicle_exact_share"] > 0.9
    assert report["rel_err"]["mean_crossing_time_s"] < 0.01
    assert report["sumo_collisions"] == 0
    # the driver did something: not the uncontrolled vType's crossing times
    plain = uncontrolled_report
    assert (
        abs(report["sumo"]["all"]["mean_crossing_time_s"]
            - plain["sumo"]["all"]["mean_crossing_time_s"]) > 0.2
    )  # fmt: skip


def test_bad_driver_specs_fail_before_anything_runs(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no exported policy"):
        parse_driver(str(tmp_path / "missing.npz"))
    with pytest.raises(ValueError, match="cruise"):
        parse_driver("cruise")
    assert parse_driver(None).kind == "uncontrolled"
    assert parse_driver(str(constant_policy(tmp_path, 0.5))).action == "assertiveness"
