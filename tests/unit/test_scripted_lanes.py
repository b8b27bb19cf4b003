"""The AVs' lane action and scripted lane rules: specs, choices on hand-made
rows, the ``"lanes"`` observer's numbers for vehicles placed by hand on the
two-lane roundabout, and the request an action turns into."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.common.evaluation import with_observer
from jaxround.envs.lane_view import (
    GAP_LEFT,
    GAP_OWN,
    GAP_RIGHT,
    LANE_INDEX,
    ROOM_LEFT,
    ROOM_OWN,
    ROOM_RIGHT,
    lane_direction,
)
from jaxround.envs.observe import DISTANCE_SCALE, OBSERVATION_SIZES
from jaxround.envs.roundabout import make
from jaxround.envs.scripted import (
    controller_from_spec,
    is_scripted_spec,
    rule_and_value,
)
from jaxround.lanes.paths import LEFT
from jaxround.scenario.schedule import make_schedule
from tests.conftest import small_config


def lane_row(
    lane: int = 0,
    room: tuple[float, float] = (0.0, 60.0),
    gaps: tuple[float, float, float] = (20.0, 0.0, 20.0),
    own_room: float = 80.0,
) -> np.ndarray:
    """A ``"lanes"`` row, float (24,): lane index, room own/right/left (m)
    and gaps own/right/left (m); the rich part zeros."""
    obs = np.zeros(OBSERVATION_SIZES["lanes"], np.float32)
    obs[LANE_INDEX] = lane
    obs[ROOM_OWN] = min(own_room / DISTANCE_SCALE, 1.0)
    obs[ROOM_RIGHT], obs[ROOM_LEFT] = np.minimum(np.array(room) / DISTANCE_SCALE, 1)
    scaled = np.minimum(np.array(gaps) / DISTANCE_SCALE, 1)
    obs[GAP_OWN], obs[GAP_RIGHT], obs[GAP_LEFT] = scaled
    return obs


def lanes_of(spec: str, *rows: np.ndarray) -> np.ndarray:
    action = jax.jit(controller_from_spec(spec).action)(jnp.asarray(np.stack(rows)))
    return np.asarray(action)


def test_lane_specs_read_the_lanes_observer() -> None:
    for spec in ("inner", "outer", "gap:5", "eco+gap:5", "cruise:8+outer"):
        assert is_scripted_spec(spec)
        assert controller_from_spec(spec).observer == "lanes"
    assert controller_from_spec("eco").observer == "rich"
    with pytest.raises(ValueError, match="a speed rule alone"):
        rule_and_value("eco+inner")


def lane_column(spec: str, *rows: np.ndarray) -> list[float | None]:
    """The lane column of each row, None for NaN (no request)."""
    return [None if np.isnan(x) else float(x) for x in lanes_of(spec, *rows)[:, 1]]


def test_lane_rules_choose_as_documented() -> None:
    outer_lane = lane_row(lane=0, room=(0.0, 60.0))  # the left lane counts
    short = lane_row(lane=0, room=(0.0, 30.0))  # it ends within 50 m
    inner_lane = lane_row(lane=1, room=(80.0, 0.0), gaps=(10.0, 40.0, 0.0))
    leaving = lane_row(lane=1, room=(80.0, 0.0), own_room=30.0)  # must go soon
    inner = lanes_of("inner", outer_lane, short, inner_lane, leaving)
    assert np.isnan(inner[:, 0]).all()  # a lane rule alone: no speed command
    # left where it counts, else hold, but not near the end of the own path
    assert lane_column("inner", outer_lane, short, inner_lane, leaving) == [
        1.0, 0.0, 0.0, None,
    ]  # fmt: skip
    assert lane_column("outer", outer_lane, short, inner_lane, leaving) == [
        0.0, 0.0, -1.0, -1.0,
    ]  # fmt: skip
    # gap:X: the lane beside only when its gap is more than X m longer
    wider = lane_row(lane=0, gaps=(10.0, 0.0, 25.0))
    assert lane_column("gap:10", wider, inner_lane) == [1.0, -1.0]
    assert lane_column("gap:20", wider, inner_lane) == [0.0, -1.0]
    assert lane_column("gap:40", wider, inner_lane) == [0.0, 0.0]
    # with a speed rule: its command, and the lane rule's column
    assert lanes_of("accel:-1+outer", inner_lane).tolist() == [[-1.0, -1.0]]
    # a speed rule alone asks for no lane
    assert np.isnan(lanes_of("eco", inner_lane)[:, 1]).all()


def test_lane_column_thresholds() -> None:
    column = jnp.array([1.0, 0.6, 0.5, 0.0, -0.5, -0.7, jnp.nan])
    asked, direction = lane_direction(column)
    assert direction.tolist()[:6] == [1, 1, 0, 0, 0, -1]
    assert asked.tolist() == [True] * 6 + [False]


@pytest.fixture(scope="module")
def two_lane() -> tuple:
    cfg = small_config("two_lane", n_vehicles=40, duration_s=60.0)
    cfg = with_observer(cfg, "lanes")
    env, params = make(cfg, max_vehicles=8)
    sched = env.schedule_from_numpy(make_schedule(cfg, seed=1, penetration=1.0))
    _, state = jax.jit(env.reset_to_schedule)(sched, params)
    return env, params, state


def placed(env, state, paths: list[int], pos: list[float]):
    """``state`` with vehicles on these lane paths at these positions (m)."""
    n = len(paths)
    return state.replace(
        active=jnp.zeros_like(state.active).at[:n].set(True),
        route=state.route.at[:n].set(jnp.asarray(paths, jnp.int32)),
        pos=state.pos.at[:n].set(jnp.asarray(pos, state.pos.dtype)),
        speed=state.speed.at[:n].set(5.0),
        is_av=state.is_av.at[:n].set(True),
    )


def test_lane_numbers_of_vehicles_placed_by_hand(two_lane) -> None:
    """An AV on the outer ring lane, one ahead of it on the same lanes and
    one beside-ahead on the inner lane: its own gap, the gap on the left,
    its lane index; and the request its action gives."""
    env, params, state = two_lane
    paths = env.lane_changer.paths
    # a path on the ring's outer lane (lane index 0) that may change left there
    ring = [
        (p, k)
        for p in range(paths.n_paths)
        for k in range(paths.path_lanes.shape[1])
        if paths.path_lanes[p, k] >= 0
        and paths.lane_ids[paths.path_lanes[p, k]].startswith("ring")
        and paths.lane_index[paths.path_lanes[p, k]] == 0
        and paths.change_path[p, k, LEFT] >= 0
    ]
    assert ring, "no outer ring lane with a lane to its left"
    p, k = ring[0]
    q = int(paths.change_path[p, k, LEFT])
    start_p = float(paths.path_lane_start[p, k])
    start_q = float(paths.path_lane_start[q, k])
    length = float(params.vehicle.length)
    me = start_p + 1.0
    state = placed(env, state, [p, p, q], [me, me + 12.0, start_q + 1.0 + 30.0])
    obs = np.asarray(jax.jit(env.observation)(state, params))
    assert obs[0, LANE_INDEX] == 0
    np.testing.assert_allclose(
        obs[0, GAP_OWN] * DISTANCE_SCALE, 12.0 - length, atol=1e-3
    )
    np.testing.assert_allclose(
        obs[0, GAP_LEFT] * DISTANCE_SCALE, 30.0 - length, atol=1e-3
    )
    assert obs[0, ROOM_LEFT] > 0 and obs[0, ROOM_RIGHT] == 0 and obs[0, GAP_RIGHT] == 0
    assert obs[2, LANE_INDEX] == 1
    assert obs[0, ROOM_OWN] == 1.0
    # the request: the lane index to the left, none to the right (no lane);
    # all three on the ring lanes and off their ends (no junction in reach)
    state = placed(env, state, [p, p, q], [me, me + 5.0, start_q + 1.0])
    agent = state.active & state.is_av
    car = params.for_vehicles(state.is_av)

    def asks(state, column):
        return env.lane_changer.request(state, column, agent, car)

    left, right = asks(state, jnp.ones(8)), asks(state, -jnp.ones(8))
    assert int(left[0]) == 1 and int(right[0]) == -1
    assert int(right[2]) == 0 and int(left[2]) == -1
    hold = asks(state, jnp.zeros(8))
    assert hold[:3].tolist() == [0, 0, 1] and (hold[3:] == -1).all()
    assert (asks(state, jnp.full(8, jnp.nan)) == -1).all()


def test_no_request_on_or_just_before_a_junction(two_lane) -> None:
    """An AV 1 m before the end of its ring lane asks nothing at 5 m/s (its
    move, at most (v + accel dt) dt = 3.15 m, could take it onto the
    junction), and asks at rest (0.65 m); on the junction's internal lane
    it asks nothing at rest either."""
    env, params, state = two_lane
    paths, arrays = env.lane_changer.paths, env.lane_changer.arrays
    p, k = next(
        (p, k)
        for p in range(paths.n_paths)
        for k in range(paths.path_lanes.shape[1] - 1)
        if paths.path_lanes[p, k] >= 0
        and paths.lane_ids[paths.path_lanes[p, k]].startswith("ring")
        and paths.change_path[p, k, LEFT] >= 0
        and paths.lane_ids[paths.path_lanes[p, k + 1]].startswith(":")
    )
    lane = int(paths.path_lanes[p, k])
    end = float(paths.path_lane_start[p, k]) + float(arrays.lane_length[lane])
    on_junction = float(paths.path_lane_start[p, k + 1]) + 1.0
    state = placed(env, state, [p, p], [on_junction, end - 1.0])
    agent = state.active & state.is_av
    car = params.for_vehicles(state.is_av)
    left = jnp.ones(8)
    moving = env.lane_changer.request(state, left, agent, car)
    assert moving[:2].tolist() == [-1, -1]
    at_rest = state.replace(speed=jnp.zeros_like(state.speed))
    asked = env.lane_changer.request(at_rest, left, agent, car)
    assert asked[:2].tolist() == [-1, int(paths.lane_index[lane]) + 1]


def test_on_one_lane_roads_the_lane_numbers_ask_for_nothing() -> None:
    """Milan with the ``"lanes"`` observer: the rich rows, lane 0, no room
    anywhere, the own gap the rich leader gap; so every lane rule asks
    nothing there."""
    cfg = small_config("milan", n_vehicles=40, duration_s=60.0)
    cfg = with_observer(cfg, "lanes")
    env, params = make(cfg, max_vehicles=16)
    sched = env.schedule_from_numpy(make_schedule(cfg, seed=1, penetration=1.0))
    obs, state = jax.jit(env.reset_to_schedule)(sched, params)
    step, action = jax.jit(env.step_env), jnp.full((16, 2), jnp.nan)
    for _ in range(40):
        obs, state, *_ = step(jax.random.PRNGKey(0), state, action, params)
    rows = np.asarray(obs)[np.asarray(state.active)]
    assert rows.shape[1] == OBSERVATION_SIZES["lanes"] and len(rows) > 3
    np.testing.assert_array_equal(rows[:, GAP_OWN], rows[:, 11])  # rich leader gap
    lane_part = np.delete(rows[:, 17:], GAP_OWN - 17, axis=1)
    assert (lane_part == 0).all()
    for spec in ("inner", "outer", "gap:0"):
        assert np.isnan(lanes_of(spec, *rows)[:, 1]).all()
