"""Pictures of the roundabout (`jaxround.analysis.render`).

The states are written by hand (no step is compiled): vehicles on every kind
of lane of Milan's network, AVs and human drivers, some halting, some due but
not yet inserted. `rollout_states` is checked on a stand-in environment whose
step only counts; the notebook test runs it on the real one. The two-lane
roundabout's vehicles are placed on its lane paths directly.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import matplotlib
import numpy as np
import pytest

from jaxround.analysis import episode_movie, render
from jaxround.core import geometry
from jaxround.core.params import EnvParams
from jaxround.core.state import (
    EnvState,
    EpisodeStats,
    Registrations,
    Schedule,
    leg_order,
)
from jaxround.envs.roundabout import RoundaboutEnv, make

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

#: Vehicle slots of the hand-written states.
SLOTS = 8
#: Time of the hand-written state: `STEP` steps of 0.5 s.
STEP = 25
#: Slot -> (route, route lane index k, fraction of that lane, AV, speed m/s);
#: two slots stay empty. k = 0 approach, odd k internal lanes, even k > 0 ring
#: lanes and the exit.
VEHICLES = {
    0: (0, 0, 0.9, False, 0.0),
    1: (1, 1, 0.5, True, 6.0),
    2: (2, 2, 0.3, False, 7.5),
    3: (5, 3, 0.6, True, 0.05),
    4: (7, 5, 0.5, False, 8.0),
    6: (11, 4, 0.99, True, 12.0),
}
#: The schedule: origin leg and departure (s); due at STEP * dt = 12.5 s and
#: not inserted: vehicles 2 and 3 (leg 1) and 4 (leg 3).
SCHEDULE = [(0, 0.0), (1, 1.0), (1, 10.0), (1, 12.5), (3, 12.0), (2, 20.0)]
INSERTED = [True, True, False, False, False, False]


@pytest.fixture(scope="module")
def env() -> RoundaboutEnv:
    return make("milan", max_vehicles=SLOTS)[0]


def hand_state(env: RoundaboutEnv, shift: float = 0.0, step: int = STEP) -> EnvState:
    """The state of `VEHICLES` and `SCHEDULE`, every vehicle `shift` m further."""
    net = env.network
    m, n = SLOTS, len(SCHEDULE)
    active, route, pos = np.zeros(m, bool), np.zeros(m, np.int32), np.zeros(m)
    is_av, speed = np.zeros(m, bool), np.zeros(m)
    for slot, (r, k, frac, av, v) in VEHICLES.items():
        lane = net.route_lanes[r, k]
        active[slot], route[slot], is_av[slot], speed[slot] = True, r, av, v
        pos[slot] = net.route_lane_start[r, k] + frac * net.lane_length[lane] + shift
        pos[slot] = min(max(pos[slot], 5.1), net.route_length[r])
    origin = np.array([o for o, _ in SCHEDULE], np.int32)
    f32 = np.float32
    schedule = Schedule(
        depart_s=jnp.asarray([t for _, t in SCHEDULE], f32),
        route=jnp.asarray(net.route_index[origin, (origin + 1) % net.n_legs]),
        origin=jnp.asarray(origin),
        speed_factor=jnp.ones(n, f32),
        is_av=jnp.zeros(n, bool),
    )
    zeros_m, zeros_n = jnp.zeros(m, f32), jnp.zeros(n, f32)
    return EnvState(
        step=jnp.int32(step),
        active=jnp.asarray(active),
        vid=jnp.where(jnp.asarray(active), jnp.arange(m), -1),
        route=jnp.asarray(route),
        pos=jnp.asarray(pos, f32),
        speed=jnp.asarray(speed, f32),
        accel=zeros_m,
        is_av=jnp.asarray(is_av),
        speed_factor=jnp.ones(m, f32),
        waiting_s=zeros_m,
        co2_mg=zeros_m,
        fuel_mg=zeros_m,
        schedule=schedule,
        inserted=jnp.asarray(INSERTED),
        leg_vehicles=leg_order(schedule.origin, net.n_legs),
        leg_inserted=jnp.asarray(
            np.bincount(origin[INSERTED], minlength=net.n_legs), jnp.int32
        ),
        insert_s=zeros_n,
        arrival_s=jnp.full(n, jnp.nan, f32),
        registrations=Registrations.empty(m, net.n_legs),
        stats=EpisodeStats.zeros(n, net.n_legs, m),
    )


def distance_to_polyline(shape: np.ndarray, point: np.ndarray) -> float:
    """Distance (m) from a point (2,) to a polyline (n, 2)."""
    a, b = shape[:-1], shape[1:]
    v = b - a
    t = np.clip(((point - a) * v).sum(1) / (v * v).sum(1), 0.0, 1.0)
    return float(np.linalg.norm(a + t[:, None] * v - point, axis=1).min())


def tangent_at(shape: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Unit direction (2,) of the polyline's segment nearest to the point."""
    a, b = shape[:-1], shape[1:]
    v = b - a
    t = np.clip(((point - a) * v).sum(1) / (v * v).sum(1), 0.0, 1.0)
    i = int(np.argmin(np.linalg.norm(a + t[:, None] * v - point, axis=1)))
    return v[i] / np.linalg.norm(v[i])


def stack(states: list[EnvState]) -> EnvState:
    return jax.tree.map(lambda *xs: jnp.stack(xs), *states)


def vehicle_collection(ax: Any) -> Any:
    (coll,) = [c for c in ax.collections if c.get_gid() == render.VEHICLES_GID]
    return coll


@pytest.fixture
def drawn(env: RoundaboutEnv) -> Any:
    state = hand_state(env)
    ax = render.render_state(env, state)
    yield state, ax
    plt.close(ax.figure)


def test_one_polygon_per_active_slot_and_a_legend(drawn: Any) -> None:
    state, ax = drawn
    coll = vehicle_collection(ax)
    assert len(coll.get_paths()) == int(state.active.sum()) == len(VEHICLES)
    assert ax.get_legend() is not None


def test_colours_follow_the_vehicle_class(drawn: Any) -> None:
    state, ax = drawn
    face = vehicle_collection(ax).get_facecolor()[:, :3]
    av = np.all(np.isclose(face, render.AV_COLOR), axis=1)
    hv = np.all(np.isclose(face, render.HV_COLOR), axis=1)
    is_av = np.asarray(state.is_av)[np.asarray(state.active)]
    assert av.sum() == is_av.sum() == 3
    assert hv.sum() == (~is_av).sum() == 3
    np.testing.assert_array_equal(av, is_av)


def test_halting_vehicles_are_outlined(drawn: Any) -> None:
    state, ax = drawn
    edge = vehicle_collection(ax).get_edgecolor()[:, :3]
    red = np.all(np.isclose(edge, matplotlib.colors.to_rgb(render.HALTING_EDGE)), 1)
    speed = np.asarray(state.speed)[np.asarray(state.active)]
    np.testing.assert_array_equal(red, speed < 0.1)
    assert red.sum() == 2


def test_time_and_waiting_vehicles_are_written(env: RoundaboutEnv, drawn: Any) -> None:
    state, ax = drawn
    np.testing.assert_array_equal(render.waiting_to_enter(env, state), [0, 2, 0, 1])
    texts = [t.get_text() for t in ax.texts]
    assert any(t.startswith("t = 12.5 s") for t in texts), texts
    assert "+2" in texts and "+1" in texts


def test_vehicles_lie_on_their_lane_shapes(env: RoundaboutEnv, drawn: Any) -> None:
    """The centre of each rectangle is on the shape of the lane where the
    middle of the vehicle is (`geometry.locate`), and the rectangle points
    along that lane."""
    state, ax = drawn
    length = env.cfg.drivers.hv.length
    on = np.asarray(state.active)
    route = state.route[on]
    _, lane, _ = geometry.locate(env.net, route, state.pos[on] - length / 2)
    internal = [env.network.lane_ids[ln].startswith(":") for ln in np.asarray(lane)]
    assert sum(internal) >= 3  # the test covers the junctions' internal lanes
    for poly, ln in zip(vehicle_collection(ax).get_paths(), np.asarray(lane)):
        corners = poly.vertices[:4]
        centre = corners.mean(0)
        shape = env.network.lane_shapes[ln]
        assert distance_to_polyline(shape, centre) < 0.05
        heading = corners[0] - corners[3]  # back to front, along one side
        heading /= np.linalg.norm(heading)
        assert np.dot(heading, tangent_at(shape, centre)) > 0.95
        np.testing.assert_allclose(np.linalg.norm(corners[0] - corners[1]), 1.8)


def test_numpy_locate_agrees_with_the_environment(env: RoundaboutEnv) -> None:
    net = env.network
    route = np.repeat(np.arange(net.n_routes), 50)
    pos = np.concatenate([np.linspace(0, x, 50) for x in net.route_length])
    lane, on_lane = render.LaneGeometry.from_network(net).locate(route, pos)
    _, lane_j, on_lane_j = geometry.locate(env.net, jnp.asarray(route), pos)
    np.testing.assert_array_equal(lane, lane_j)
    np.testing.assert_allclose(on_lane, on_lane_j, atol=1e-3)


def test_a_batch_is_refused(env: RoundaboutEnv) -> None:
    with pytest.raises(ValueError, match="one roundabout"):
        render.render_state(env, stack([hand_state(env)] * 2))


def test_animate_writes_a_multi_frame_gif(env: RoundaboutEnv, tmp_path: Path) -> None:
    from PIL import Image

    frames = 4
    states = stack([hand_state(env, 2.0 * i, STEP + i) for i in range(frames)])
    path = episode_movie.animate(env, states, tmp_path / "sub" / "a.gif", fps=5, dpi=30)
    with Image.open(path) as gif:
        assert gif.format == "GIF"
        assert gif.n_frames == frames
    with pytest.raises(ValueError, match=r"\.gif or an \.mp4"):
        episode_movie.animate(env, states, tmp_path / "a.avi")


def test_movie_formats(tmp_path: Path) -> None:
    from matplotlib import animation

    assert isinstance(episode_movie.movie_writer("a.GIF"), animation.PillowWriter)
    if animation.writers.is_available("ffmpeg"):
        assert isinstance(episode_movie.movie_writer("a.mp4"), animation.FFMpegWriter)
    else:
        with pytest.raises(ValueError, match="ffmpeg"):
            episode_movie.movie_writer("a.mp4")
    with pytest.raises(ValueError, match=r"\.gif or an \.mp4"):  # before any run
        episode_movie.render_rollout(tmp_path / "a.webm")


def test_vehicle_counts_plot(env: RoundaboutEnv) -> None:
    states = stack([hand_state(env, 0.0, STEP + i) for i in range(3)])
    ax = render.plot_vehicle_counts(env, states)
    lines = {line.get_label(): line for line in ax.get_lines()}
    np.testing.assert_allclose(lines["in the network"].get_xdata(), [12.5, 13, 13.5])
    np.testing.assert_array_equal(lines["in the network"].get_ydata(), [6, 6, 6])
    np.testing.assert_array_equal(lines["AVs"].get_ydata(), [3, 3, 3])
    np.testing.assert_array_equal(lines["waiting to enter"].get_ydata(), [3, 3, 3])
    plt.close(ax.figure)


class CountingEnv:
    """Stands in for `RoundaboutEnv` in `rollout_states`: a step moves every
    vehicle 1 m and counts; `reset` starts at pos 0, `reset_to_schedule` at 100."""

    def __init__(self, state: EnvState) -> None:
        self.state = state
        self.max_vehicles = SLOTS

    def reset(self, key: jax.Array, params: EnvParams) -> tuple[jax.Array, EnvState]:
        return jnp.zeros(SLOTS), self.state.replace(
            step=jnp.int32(0), pos=self.state.pos * 0
        )

    def reset_to_schedule(
        self, schedule: Schedule, params: EnvParams
    ) -> tuple[jax.Array, EnvState]:
        return jnp.zeros(SLOTS), self.state.replace(
            step=0, pos=self.state.pos * 0 + 100
        )

    def step_env(
        self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams
    ) -> tuple[Any, ...]:
        state = state.replace(step=state.step + 1, pos=state.pos + 1.0)
        return jnp.zeros(SLOTS), state, jnp.zeros(SLOTS), jnp.bool_(False), {}


def test_rollout_states_keeps_every_kth_state(env: RoundaboutEnv) -> None:
    fake = CountingEnv(hand_state(env))
    params = env.default_params
    key = jax.random.PRNGKey(0)
    states = episode_movie.rollout_states(fake, params, key, n_steps=11, every=3)
    assert render.n_frames(states) == 4  # after 0, 3, 6, 9 steps
    np.testing.assert_array_equal(states.step, [0, 3, 6, 9])
    np.testing.assert_allclose(states.pos[:, 0], [0, 3, 6, 9])
    assert states.schedule.depart_s.shape == (4, len(SCHEDULE))
    again = episode_movie.rollout_states(
        fake, params, key, n_steps=2, every=1, schedule=fake.state.schedule
    )
    np.testing.assert_allclose(again.pos[:, 0], [100, 101, 102])
    with pytest.raises(ValueError, match="n_steps"):
        episode_movie.rollout_states(fake, params, key, n_steps=2, every=3)


def test_two_lane_roads_are_drawn_lane_by_lane() -> None:
    """On the two-lane roundabout a vehicle's lane path is its route, so a
    vehicle on the inner ring lane is drawn on that lane's shape, a lane
    width (3.2 m) nearer the centre than one beside it on the outer lane,
    and every lane of the network is drawn."""
    env = make("two_lane", max_vehicles=SLOTS)[0]
    net = env.network
    ids = list(net.lane_ids)
    outer = ids.index("ring_1_0")
    routes, pos = [], []
    for lane in (outer, ids.index("ring_1_1")):
        r, k = np.argwhere(net.route_lanes == lane)[0]
        routes.append(r)
        pos.append(net.route_lane_start[r, k] + 0.5 * net.lane_length[lane] + 2.5)
    centre, _, _ = render.vehicle_boxes(env, np.array(routes), np.array(pos))
    middle = np.concatenate(net.lane_shapes).mean(0)
    radius = np.linalg.norm(centre - middle, axis=1)
    assert 2.9 < radius[0] - radius[1] < 3.5, radius
    for point, name in zip(centre, ("ring_1_0", "ring_1_1"), strict=True):
        assert distance_to_polyline(net.lane_shapes[ids.index(name)], point) < 0.05
    figure, ax = plt.subplots()
    render.draw_network(env, ax)
    drawn_roads = ax.collections[0].get_paths()
    assert len(drawn_roads) == len(ids) and any(i.endswith("_1") for i in ids)
    plt.close(figure)
