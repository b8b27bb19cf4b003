"""The PettingZoo environment over real SUMO: PettingZoo's API test passes, and
an exported policy driven through it gives the crossing times of the policy
controller that ``jaxround evaluate --sim sumo`` runs."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("pettingzoo")

from gymnasium.utils.env_checker import check_env  # noqa: E402
from pettingzoo.test import parallel_api_test  # noqa: E402

from agents.common.export import load_policy, load_policy_numpy  # noqa: E402
from jaxround.scenario.schedule import make_schedule  # noqa: E402
from sumo_export.evaluate import policy_controller, sumo_runs  # noqa: E402
from sumo_export.gymnasium_env import SumoSharedPolicyEnv  # noqa: E402
from sumo_export.pettingzoo_env import SumoParallelEnv  # noqa: E402
from sumo_export.scenario import vehicle_id  # noqa: E402
from tests.conftest import small_config  # noqa: E402
from tests.sumo.test_controller import write_standin_policy  # noqa: E402

pytestmark = pytest.mark.sumo

SEED, PENETRATION = 0, 0.5
#: The stand-in policy's mean command, m/s^2: AVs that keep the traffic moving.
BIAS = 1.0
#: Observer slots: one compiled size (the small scenario never fills them).
SLOTS = 32


@pytest.fixture(scope="module")
def cfg() -> Any:
    return small_config("milan", n_vehicles=40, duration_s=100.0)


@pytest.fixture(scope="module")
def policy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_standin_policy(tmp_path_factory.mktemp("policy"), bias=BIAS)


@pytest.fixture(scope="module")
def env(cfg: Any) -> Iterator[SumoParallelEnv]:
    env = SumoParallelEnv(cfg, penetration=PENETRATION, max_slots=SLOTS)
    yield env
    env.close()


def test_pettingzoo_parallel_api_test_passes(env: SumoParallelEnv) -> None:
    parallel_api_test(env, num_cycles=60)
    obs, _ = env.reset(seed=1)
    assert env.agents and set(obs) == set(env.agents)
    assert set(env.agents) <= set(env.possible_agents)
    space = env.observation_space(env.agents[0])
    assert all(space.contains(row) for row in obs.values())


def test_bad_input_is_named(cfg: Any, env: SumoParallelEnv) -> None:
    with pytest.raises(ValueError, match="penetration"):
        SumoParallelEnv(cfg, penetration=1.5)
    with pytest.raises(ValueError, match="observer"):
        SumoParallelEnv(cfg, observer="eyes")
    env.close()
    env.agents = []
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="not in the network"):
        env.step({"v99999": np.zeros(2, np.float32)})


def test_the_gymnasium_view_for_one_shared_policy(env: SumoParallelEnv) -> None:
    gym_env = SumoSharedPolicyEnv(env)
    check_env(gym_env, skip_render_check=True)
    obs, info = gym_env.reset(seed=2)
    assert obs.shape == (SLOTS, env.observation_space("").shape[0] + 1)
    assert obs[:, -1].sum() == len(info["agents"]) > 0
    with pytest.raises(ValueError, match="shape"):
        gym_env.step(np.zeros((SLOTS, 3), np.float32))
    total, done, steps = 0.0, False, 0
    assert gym_env.action_space.shape == (SLOTS * 2,)
    while not done and steps < 40:
        obs, reward, terminated, truncated, info = gym_env.step(
            np.zeros((SLOTS, 2), np.float32)  # the rows, as the flat action holds them
        )
        assert reward == pytest.approx(sum(info["rewards"].values()))
        total += reward
        done, steps = terminated or truncated, steps + 1
    assert total < 0.0


def drive(env: SumoParallelEnv, policy: Path) -> dict[str, Any]:
    """One run of the exported policy through the environment: arrival times
    by vehicle id, and the rewards and agents seen."""
    act = load_policy_numpy(policy)
    obs, _ = env.reset()
    rewards, steps, seen = [], 0, set()
    while env.agents:
        agents = list(env.agents)
        seen |= set(agents)
        actions = env.policy_actions(act)
        assert set(actions) == set(agents)
        # the agents' own rows give the same actions, up to rounding
        own, _ = act(np.stack([obs[a] for a in agents]), np.ones(len(agents), bool))
        np.testing.assert_allclose(
            [actions[a][0] for a in agents], own, rtol=1e-4, atol=1e-5
        )
        obs, reward, terminated, truncated, _ = env.step(actions)
        assert set(reward) >= set(agents)
        rewards.extend(reward[a] for a in agents)
        steps += 1
    return {
        "arrival": dict(env.arrival_s),
        "rewards": rewards,
        "steps": steps,
        "seen": seen,
    }


def test_the_exported_policy_crosses_as_in_evaluate(cfg: Any, policy: Path) -> None:
    """Same vehicles, same arrival times to the last digit (tripinfo against
    the environment's own count)."""
    # `jaxround evaluate --sim sumo`: the policy controller in a worker process
    factory = policy_controller(cfg, policy)
    (controlled,) = sumo_runs(
        cfg, [PENETRATION], [SEED], workers=1, show_progress=False, controller=factory
    )[PENETRATION]
    (plain,) = sumo_runs(cfg, [PENETRATION], [SEED], workers=1, show_progress=False)[
        PENETRATION
    ]
    base = make_schedule(cfg, seed=SEED, penetration=0.0)
    schedule = base.with_penetration(PENETRATION)
    observer = load_policy(policy)[1].observer
    env = SumoParallelEnv(cfg, schedule=schedule, observer=observer, max_slots=SLOTS)
    try:
        run = drive(env, policy)
    finally:
        env.close()
    n = schedule.n_vehicles
    arrival = np.array([run["arrival"].get(vehicle_id(i), np.nan) for i in range(n)])
    assert np.isfinite(arrival).all()
    np.testing.assert_array_equal(arrival, controlled.records.arrival_s)
    # the policy changed the traffic: the uncontrolled run crosses otherwise
    assert np.any(arrival != plain.records.arrival_s)
    # every AV was an agent, and the rewards are the paper's cost per step
    assert run["seen"] == {vehicle_id(i) for i in np.nonzero(schedule.is_av)[0]}
    rewards = np.asarray(run["rewards"])
    assert np.all((rewards <= 0.0) & (rewards >= -1.0)) and rewards.min() < 0.0
