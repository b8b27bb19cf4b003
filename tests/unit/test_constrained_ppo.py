"""Constrained PPO (`agents.ppo.constraint`): the multiplier step by hand, the
per-penetration prices in the environment, the vType's measured limit, and
the config's refusals."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from agents.common.config import ppo_config_from_dict
from agents.common.constraint_config import ConflictConstraintConfig
from agents.ppo import Trainer, constraint
from jaxround.scenario.config import ConfigError, load_config
from tests.unit.test_ppo import tiny_config

SETTINGS = ConflictConstraintConfig(
    limit=(2.0, 6.0), price_lr=0.1, price_min=1.0, price_max=300.0
)


def ledger(price: list[float], conflicts: list[float], arrivals: list[float]):
    return constraint.ConflictLedger(
        price=jnp.asarray(price, jnp.float32),
        limit=jnp.asarray(SETTINGS.limit, jnp.float32),
        conflicts=jnp.asarray(conflicts, jnp.float32),
        arrivals=jnp.asarray(arrivals, jnp.float32),
    )


def test_multiplier_step_by_hand() -> None:
    """rate = 1000 C / A of the decayed counts; log price += lr * relative
    excess, clipped to [-1, 1]."""
    before = ledger([50.0, 50.0], conflicts=[1.0, 10.0], arrivals=[1000.0, 1000.0])
    after = constraint.update_ledger(
        before, SETTINGS, jnp.asarray([30.0, 0.0]), jnp.asarray([500.0, 500.0])
    )
    # group 0: C = 0.9 + 30 = 30.9, A = 900 + 500 = 1400: 22.1 per 1,000,
    #   10 times its limit of 2: the excess is clipped to 1
    # group 1: C = 9, A = 1400: 6.43 per 1,000, 7% over its limit of 6
    rate = np.array([30.9 / 1400, 9.0 / 1400]) * 1000
    np.testing.assert_allclose(after.rate(), rate, rtol=1e-5)
    excess = np.array([1.0, (rate[1] - 6.0) / 6.0])
    np.testing.assert_allclose(after.price, 50 * np.exp(0.1 * excess), rtol=1e-5)
    # under the limit the price falls, by the same rule
    under = constraint.update_ledger(
        before, SETTINGS, jnp.zeros(2), jnp.asarray([500.0, 500.0])
    )
    excess = np.array([0.9 / 1.4 - 2.0, 9.0 / 1.4 - 6.0]) / np.array([2.0, 6.0])
    np.testing.assert_allclose(under.price, 50 * np.exp(0.1 * excess), rtol=1e-5)
    assert under.price[0] < 50 < after.price[1]


def test_price_is_clipped_and_kept_without_arrivals() -> None:
    low = ledger([1.02, 1.02], conflicts=[0.0, 0.0], arrivals=[1000.0, 1000.0])
    low = constraint.update_ledger(low, SETTINGS, jnp.zeros(2), jnp.ones(2) * 100)
    np.testing.assert_array_equal(low.price, [1.0, 1.0])
    high = ledger([290.0, 290.0], conflicts=[50.0, 50.0], arrivals=[100.0, 100.0])
    high = constraint.update_ledger(high, SETTINGS, jnp.ones(2), jnp.ones(2))
    np.testing.assert_array_equal(high.price, [300.0, 300.0])
    # no vehicle arrived yet: no rate, the price stays
    none = ledger([42.0, 7.0], conflicts=[0.0, 0.0], arrivals=[0.0, 0.0])
    none = constraint.update_ledger(none, SETTINGS, jnp.zeros(2), jnp.zeros(2))
    assert np.all(np.isnan(none.rate()))
    np.testing.assert_array_equal(none.price, [42.0, 7.0])


def test_groups_and_prices_per_roundabout() -> None:
    group = constraint.groups(6, 2)
    np.testing.assert_array_equal(group, [0, 1, 0, 1, 0, 1])
    totals = constraint.group_totals(jnp.arange(12.0).reshape(2, 6), group, 2)
    # per roundabout 6, 8, 10, 12, 14, 16: even ones 6 + 10 + 14, odd 8 + 12 + 16
    np.testing.assert_array_equal(totals, [30.0, 36.0])
    trainer = Trainer(tiny_config(penetrations=(0.5, 1.0)))
    priced = constraint.with_prices(
        trainer.env_params, jnp.asarray([11.0, 99.0]), constraint.groups(4, 2)
    )
    np.testing.assert_array_equal(priced.reward.conflict_weight, [11, 99, 11, 99])
    np.testing.assert_array_equal(priced.demand.penetration, [0.5, 1, 0.5, 1])


def test_limit_of_uncontrolled_avs_is_measured_and_prices_follow(
    tmp_path: Path,
) -> None:
    """Milan with AVs of tau 0.5 s (about 270 conflicts per 1,000 vehicles
    uncontrolled, docs/safety.md) in 60 s episodes, so that vehicles arrive
    and conflicts happen: the measured limit is positive in both groups;
    with a limit of 0 the price can only rise, and rises; with one of 1e6 it
    only falls."""
    scenario = load_config("milan").to_dict()
    scenario["drivers"]["av"]["tau"] = 0.5
    path = tmp_path / "close_avs.yaml"
    path.write_text(yaml.safe_dump(scenario))
    changes = dict(
        scenario=str(path), demand_window_s=60.0, episode_s=60.0, max_vehicles=24,
        penetrations=(0.5, 1.0), n_steps=30, total_env_steps=4 * 30 * 3,
        conflict_weight=50.0,
    )  # fmt: skip
    trainer = Trainer(tiny_config(**changes, conflict_constraint={}))
    runner = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    limit = np.asarray(runner.ledger.limit)
    assert limit.shape == (2,) and np.all(limit > 0), limit
    np.testing.assert_array_equal(runner.ledger.price, [50.0, 50.0])

    run = jax.jit(lambda r: trainer.run_updates(r, trainer.config.num_updates))

    def prices_with_limit(limit: float) -> np.ndarray:
        ledger = runner.ledger._replace(limit=jnp.full(2, limit, jnp.float32))
        _, metrics = run(runner._replace(ledger=ledger))
        assert np.nansum(np.asarray(metrics["conflicts_per_1000"])) > 0
        return np.concatenate([[50.0], np.asarray(metrics["conflict_price"])])

    strict = prices_with_limit(0.0)
    assert np.all(np.diff(strict) >= 0) and strict[-1] > 50.0
    lax = prices_with_limit(1e6)
    assert np.all(np.diff(lax) <= 0) and lax[-1] < 50.0


@pytest.mark.parametrize(
    ("constraint_settings", "message"),
    [
        ({"limit": [1.0, 2.0, 3.0]}, r"conflict_constraint.limit: 3 numbers"),
        ({"limit": [-1.0]}, r"conflict_constraint.limit\[0\]: -1.0, expected >= 0"),
        ({"price_lr": 0.0}, r"price_lr: 0.0, expected > 0"),
        ({"price_min": 0.0}, r"expected 0 < price_min <= price_max"),
        ({"smoothing": 1.0}, r"smoothing: 1.0, expected in \[0, 1\)"),
        ({"measure_episodes": 0}, r"measure_episodes: 0"),
        ({"limt": [1.0]}, r"unknown key 'limt'"),
    ],
)
def test_config_refusals(constraint_settings: dict, message: str) -> None:
    data = {**tiny_config().to_dict(), "penetrations": [0.5, 1.0]}
    with pytest.raises(ConfigError, match=message):
        ppo_config_from_dict({**data, "conflict_constraint": constraint_settings})


def test_config_round_trip() -> None:
    cfg = tiny_config(
        penetrations=[0.5, 1.0],
        conflict_constraint={"limit": [2.0, 6.5], "price_lr": 3.0},
    )
    assert cfg.conflict_constraint == ConflictConstraintConfig(
        limit=(2.0, 6.5), price_lr=3.0
    )
    assert ppo_config_from_dict(yaml.safe_load(cfg.to_yaml())) == cfg
