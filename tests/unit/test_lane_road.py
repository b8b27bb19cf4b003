"""`jaxround.lanes` without SUMO: the road's refusals, lane-change numbers
swept with `vmap` (the same numbers twice), the advice slots, the lane
parity report."""

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
        (dict(n_lanes=3, speed_limit=13.89), "n_lanes: 3"),
        (dict(n_lanes=2, speed_limit=25.0), "60 km/h"),
        (dict(n_lanes=2, speed_limit=13.89, dt=0.0), "dt: 0.0"),
    ],
)
def test_road_refuses_what_is_not_ported(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        lane_road.Road(**kwargs)


def test_traffic_refuses_a_road_without_length() -> None:
    with pytest.raises(ValueError, match="road_length: -1.0 m"):
        lane_road.traffic(
            depart_pos=np.zeros(1), depart_speed=np.zeros(1),
            depart_lane=np.zeros(1, int), leads_on=np.ones((1, 2), bool),
            driver=lane_road.default_driver(1), road_length=-1.0,
        )  # fmt: skip


def behind_a_slow_leader() -> lane_road.Traffic:
    """A 5 m/s leader 60 m ahead of a free vehicle, both on the right lane."""
    return lane_road.traffic(
        depart_pos=np.array([60.0, 0.0]),
        depart_speed=np.array([5.0, 13.89]),
        depart_lane=np.array([0, 0]),
        leads_on=np.ones((2, 2), bool),
        driver=lane_road.default_driver(2, np.array([5.0, 55.55])),
        road_length=600.0,
    )


def test_speed_gain_swept_with_vmap() -> None:
    """LaneChangeParams are traced: one `vmap` runs lcSpeedGain 0 and 1; only
    the eager driver passes its slow leader on the left. Run twice, the
    same numbers."""
    road = lane_road.Road(n_lanes=2, speed_limit=13.89)

    def run(speed_gain: jax.Array) -> lane_road.StepRecord:
        lc = LaneChangeParams(speed_gain=speed_gain)
        return lane_road.simulate(road, behind_a_slow_leader(), lc, 20)[1]

    sweep = jax.jit(jax.vmap(run))
    record = sweep(jnp.array([0.0, 1.0]))
    follower_changes = np.asarray(record.change_direction[:, :, 1])  # (2, T)
    assert not follower_changes[0].any()
    assert follower_changes[1].max() == 1  # left, for speed
    first = int(np.argmax(follower_changes[1] == 1))
    assert record.change_state[1, first, 1] & lca.SPEEDGAIN
    again = sweep(jnp.array([0.0, 1.0]))
    for x, y in zip(jax.tree.leaves(record), jax.tree.leaves(again), strict=True):
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
