"""What slow leavers still owe (`jaxround.analysis.exit_debt`), and the
state-dependent controller's inputs and parts (`analysis.state_controller`)."""

from __future__ import annotations

from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np

from jaxround.analysis.exit_debt import debt_table, exit_debt
from jaxround.analysis.state_controller import (
    BRAKING_SCALE_MPS2,
    CLOSING_SCALE_MPS,
    FEATURES,
    OBSERVED,
    TUNED,
    ablations,
    features_of,
)


def test_leaving_at_the_limit_owes_nothing_and_slower_owes_more() -> None:
    table = debt_table(13.89)
    speeds, co2_g, time_s = table
    assert co2_g[-1] < 0.1 and time_s[-1] < 0.01
    assert np.all(np.diff(co2_g) <= 1e-6) and np.all(np.diff(time_s) <= 1e-6)
    # from standstill: 150 m take about 3 s more than at the limit
    assert 2.0 < time_s[0] < 4.0 and co2_g[0] > co2_g[100] > 0
    co2, t = exit_debt(np.array([13.89, 20.0, 10.0]), table)
    assert float(co2[0]) < 0.1 and float(co2[1]) < 0.1
    np.testing.assert_allclose(float(t[2]), time_s[100], rtol=1e-5)


def test_ablations_keep_one_number_state_dependent() -> None:
    theta = np.arange(len(TUNED) * (1 + len(FEATURES)), dtype=np.float32) + 1
    parts = ablations(theta)
    assert list(parts) == ["full", "bias_only"] + [f"{n}_only" for n in TUNED]
    bias = parts["bias_only"].reshape(len(TUNED), -1)
    assert np.all(bias[:, 1:] == 0) and np.all(bias[:, 0] == theta.reshape(3, -1)[:, 0])
    one = parts["cruise_mps_only"].reshape(len(TUNED), -1)
    assert np.all(one[:2, 1:] == 0) and np.all(one[2] == theta.reshape(3, -1)[2])


def test_features_read_the_observation_and_mark_a_human_leader() -> None:
    """The controller reads columns 10, 11 and 13-16 of the rich observation;
    then 1 only behind a human driver, the closing speed and the leader's
    braking, each on its scale."""
    obs = jnp.tile(jnp.arange(17, dtype=jnp.float32), (4, 1))
    leader = jnp.array([-1, 0, 2, 1])
    is_av = jnp.array([False, True, True, True])  # slot 0 is the one human
    speed = jnp.array([5.0, 10.0, 4.0, 12.0])
    accel = jnp.array([-2.15, 0.0, 1.0, -4.3])
    state = SimpleNamespace(is_av=is_av, speed=speed, accel=accel)
    feats = np.asarray(features_of(obs, leader, state))
    assert feats.shape == (4, len(FEATURES))
    assert feats[0, : len(OBSERVED)].tolist() == [10, 11, 13, 14, 15, 16]
    # no leader, a human leader, an AV leader, an AV leader
    assert feats[:, len(OBSERVED)].tolist() == [0.0, 1.0, 0.0, 0.0]
    # closing in: 10 on 5, 4 on 4 (0), 12 on 10 m/s; braking: 2.15, 0, 0 m/s^2
    np.testing.assert_allclose(
        feats[:, -2], [0.0, 5.0 / CLOSING_SCALE_MPS, 0.0, 2.0 / CLOSING_SCALE_MPS]
    )
    np.testing.assert_allclose(feats[:, -1], [0.0, 2.15 / BRAKING_SCALE_MPS2, 0.0, 0.0])
