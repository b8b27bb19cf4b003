"""Near-conflicts as SUMO's SSM device counts them: the measures by hand,
the encounters, the AVs' time-gap floor and the settings that carry them."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.analysis.setting_search import SPACE, bounds, from_unit, to_unit
from jaxround.apps.drivers import parse_av_numbers, with_av_numbers
from jaxround.apps.search import CONFLICT_PENALTY, fitness_of
from jaxround.core.params import EnvParams
from jaxround.core.surrogate_safety import (
    NO_TTC_S,
    deceleration_to_avoid_crash,
    following_conflicts,
    time_to_collision,
)
from jaxround.envs.assertiveness import assertive_tau
from jaxround.envs.reward import system_reward
from jaxround.scenario.config import ConfigError, config_from_dict, load_config
from tests.conftest import builtin_dict


def test_ttc_and_drac_by_hand() -> None:
    gap = jnp.array([10.0, 10.0, 0.0, 4.0])
    v_follower = jnp.array([10.0, 5.0, 3.0, 8.0])
    v_leader = jnp.array([5.0, 6.0, 1.0, 0.0])
    ttc = np.asarray(time_to_collision(gap, v_follower, v_leader))
    drac = np.asarray(deceleration_to_avoid_crash(gap, v_follower, v_leader))
    # closing at 5 m/s over 10 m; opening; touching; closing at 8 over 4
    np.testing.assert_allclose(ttc, [2.0, NO_TTC_S, 0.0, 0.5])
    np.testing.assert_allclose(drac, [1.25, 0.0, 0.0, 8.0])


def _step(leader: list[int], gap: list[float], previous: tuple) -> tuple:
    found = following_conflicts(
        leader_vehicle=jnp.array(leader),
        gap=jnp.array(gap),
        v_follower=jnp.array([10.0, 10.0]),
        v_leader=jnp.array([0.0, 0.0]),
        previous_leader=previous[0],
        previous_conflict=previous[1],
        ttc_threshold_s=1.5,
        drac_threshold_mps2=3.0,
    )
    return found, (found.encounter_leader, found.encounter_conflict)


def test_an_encounter_counts_once_and_a_new_leader_starts_another() -> None:
    state = (jnp.array([-1, -1]), jnp.array([False, False]))
    # slot 0 closes in on vehicle 7 at 10 m/s: TTC 1 s (critical twice),
    # slot 1 far behind vehicle 8 (TTC 10 s, DRAC 0.5: no conflict)
    found, state = _step([7, 8], [10.0, 100.0], state)
    assert found.new_conflict.tolist() == [True, False]
    found, state = _step([7, 8], [10.0, 100.0], state)
    assert found.new_conflict.tolist() == [False, False]
    # another vehicle cuts in ahead of slot 0: a new encounter, a new conflict
    found, state = _step([9, 8], [10.0, 100.0], state)
    assert found.new_conflict.tolist() == [True, False]
    # slot 0 empties, then holds a vehicle behind the same leader again
    found, state = _step([-1, 8], [10.0, 100.0], state)
    assert state[0].tolist() == [-1, 8] and not bool(state[1][0])
    found, state = _step([9, 8], [10.0, 100.0], state)
    assert found.new_conflict.tolist() == [True, False]


def test_the_time_gap_floor_bounds_the_action_not_the_vtype() -> None:
    u = jnp.array([1.0, 0.0, -1.0])
    np.testing.assert_allclose(assertive_tau(1.0, u, 0.8), [0.8, 1.0, 2.0])
    np.testing.assert_allclose(assertive_tau(1.0, u), [0.5, 1.0, 2.0])
    # a vType already below the floor keeps its own tau, and no shorter
    np.testing.assert_allclose(assertive_tau(0.6, u, 0.8), [0.6, 0.6, 1.2])


def test_the_search_box_starts_at_the_floor() -> None:
    assert bounds(0.8)["tau"] == (0.8, SPACE["tau"][1])
    assert bounds(0.0)["tau"] == SPACE["tau"]
    corner = np.asarray(from_unit(jnp.zeros(len(SPACE)), 0.8))
    assert corner[0] == pytest.approx(0.8)
    np.testing.assert_allclose(to_unit(corner, 0.8), np.zeros(len(SPACE)), atol=1e-6)
    with pytest.raises(ValueError, match="time-gap floor"):
        bounds(2.5)


def test_safety_settings_load_with_defaults_and_refuse_nonsense() -> None:
    cfg = load_config("milan")
    assert cfg.safety.min_av_tau_s == 0.8 and cfg.safety.ttc_threshold_s == 1.5
    options = cfg.safety.sumo_options("ssm.xml")
    assert options[options.index("--device.ssm.thresholds") + 1] == "1.5 3"
    data = builtin_dict()
    data["safety"] = {"min_av_tau_s": 0.5}
    assert config_from_dict(data).safety.min_av_tau_s == 0.5
    data["safety"] = {"ttc_threshold_s": -1.0}
    with pytest.raises(ConfigError, match="safety.ttc_threshold_s"):
        config_from_dict(data)
    data["safety"] = {"ttc_treshold_s": 1.0}
    with pytest.raises(ConfigError, match="ttc_treshold_s"):
        config_from_dict(data)


def test_av_numbers_from_the_command_line() -> None:
    assert parse_av_numbers("tau=0.5, impatience=1") == {"tau": 0.5, "impatience": 1.0}
    cfg = with_av_numbers(load_config("milan"), {"tau": 0.5})
    assert cfg.drivers.av.tau == 0.5 and cfg.drivers.hv.tau != 0.5
    with pytest.raises(ValueError, match="decel"):
        parse_av_numbers("decel=3")
    with pytest.raises(ValueError, match="not a number"):
        parse_av_numbers("tau=fast")
    with pytest.raises(ConfigError, match="drivers.av.tau"):
        with_av_numbers(load_config("milan"), {"tau": -1.0})


def load_params() -> EnvParams:
    return EnvParams.from_config(load_config("milan"))


def test_the_system_reward_charges_conflicts_shared_and_own() -> None:
    params = load_params()
    params = params.replace(
        reward=params.reward.replace(conflict_weight=jnp.float32(10.0))
    )
    active = jnp.array([True, True, True])
    agent = jnp.array([True, True, False])
    co2 = jnp.zeros(3)
    plain = system_reward(jnp.int32(3), co2, active, agent, params, 0.5, share=0.5)
    charged = system_reward(
        jnp.int32(3), co2, active, agent, params, 0.5, share=0.5,
        conflicts_step=jnp.array([1, 0, 1]),
    )  # fmt: skip
    # shared: 2 conflicts over 2 AVs, half weight; own: the first AV's one
    np.testing.assert_allclose(
        np.asarray(plain - charged), [10 * (0.5 * 1 + 0.5 * 1), 10 * 0.5, 0.0]
    )


def test_the_constraint_penalises_only_the_excess() -> None:
    scores = {
        "objective": np.array([[40.0, 40.0], [38.0, 38.0]]),
        "missing": np.zeros((2, 2), int),
        "conflicts_per_1000": np.array([[2.0, 4.0], [20.0, 30.0]]),
    }
    np.testing.assert_allclose(fitness_of(scores), [40.0, 38.0])
    limited = fitness_of(scores, conflict_limit=5.0)
    np.testing.assert_allclose(limited, [40.0, 38.0 + CONFLICT_PENALTY * 20.0])
