"""`jaxround.lanes` without SUMO: the road's refusals, lane-change numbers
swept with `vmap`, the advice slots, and the same numbers twice."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.lanes import actions as lca
from jaxround.lanes import road as lane_road
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.views import N_ADVICES, push_advice


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(length=500.0, n_lanes=3, speed_limit=13.89), "n_lanes: 3"),
        (dict(length=500.0, n_lanes=2, speed_limit=25.0), "60 km/h"),
        (dict(length=-1.0, n_lanes=2, speed_limit=13.89), "length -1.0"),
    ],
)
def test_road_refuses_what_is_not_ported(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        lane_road.Road(**kwargs)


def behind_a_slow_leader() -> lane_road.Traffic:
    """A 5 m/s leader 60 m ahead of a free vehicle, both on the right lane."""
    return lane_road.traffic(
        depart_pos=np.array([60.0, 0.0]),
        depart_speed=np.array([5.0, 13.89]),
        depart_lane=np.array([0, 0]),
        leads_on=np.ones((2, 2), bool),
        driver=lane_road.default_driver(2, np.array([5.0, 55.55])),
    )


def test_speed_gain_swept_with_vmap() -> None:
    """LaneChangeParams are traced: one `vmap` runs lcSpeedGain 0 and 1; only
    the eager driver passes its slow leader on the left."""
    road = lane_road.Road(length=600.0, n_lanes=2, speed_limit=13.89)

    def run(speed_gain: jax.Array) -> lane_road.StepRecord:
        lc = LaneChangeParams(speed_gain=speed_gain)
        return lane_road.simulate(road, behind_a_slow_leader(), lc, 20)[1]

    record = jax.jit(jax.vmap(run))(jnp.array([0.0, 1.0]))
    follower_changes = np.asarray(record.change_direction[:, :, 1])  # (2, T)
    assert not follower_changes[0].any()
    assert follower_changes[1].max() == 1  # left, for speed
    first = int(np.argmax(follower_changes[1] == 1))
    assert record.change_state[1, first, 1] & lca.SPEEDGAIN


def test_same_numbers_twice() -> None:
    road = lane_road.Road(length=600.0, n_lanes=2, speed_limit=13.89)
    simulate = jax.jit(lane_road.simulate, static_argnums=(0, 3))
    a = simulate(road, behind_a_slow_leader(), LaneChangeParams(), 30)[1]
    b = simulate(road, behind_a_slow_leader(), LaneChangeParams(), 30)[1]
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_advices_fill_slots_and_keep_the_smallest() -> None:
    row = jnp.full(N_ADVICES, jnp.nan)
    row = push_advice(row, jnp.nan)  # nothing to add
    assert np.isnan(np.asarray(row)).all()
    for speed in range(N_ADVICES, 0, -1):
        row = push_advice(row, jnp.asarray(float(speed)))
    assert sorted(np.asarray(row)) == list(range(1, N_ADVICES + 1))
    row = push_advice(row, jnp.asarray(0.5))  # full: the largest gives way
    assert np.nanmax(np.asarray(row)) == N_ADVICES - 1
    assert np.nanmin(np.asarray(row)) == 0.5


def test_lane_parity_refuses_bad_input(tmp_path, capsys) -> None:
    from jaxround.apps import lane_parity

    with pytest.raises(SystemExit):
        lane_parity.main(["--vehicles", "1"])
    assert "--vehicles [1]: each between 2 and 99" in capsys.readouterr().err
    kept = tmp_path / "rows.json"
    kept.write_text("[]")
    with pytest.raises(SystemExit):
        lane_parity.main(["--json", str(kept)])
    assert "exists; not overwritten" in capsys.readouterr().err
    assert kept.read_text() == "[]"
    assert lane_parity._seeds("3-5") == [3, 4, 5]
    assert lane_parity._seeds("0,7") == [0, 7]


def test_lane_parity_report_sums_the_roads() -> None:
    from jaxround.apps.lane_parity import report

    row = {
        "seed": 3, "vehicles": 30, "sumo_changes": 40, "float64_changes": 38,
        "float32_changes": 41, "sumo_time_s": 100.0, "float64_time_s": 101.0,
        "float32_time_s": 99.5, "compared": 30,
    }  # fmt: skip
    text = report([row, {**row, "seed": 4}])
    assert "| 3 | 30 | 40 | 38 | 41 | 100.00 | +1.00% | -0.50% |" in text
    assert "over 2 roads: SUMO 80, JAX float64 76, float32 82" in text
