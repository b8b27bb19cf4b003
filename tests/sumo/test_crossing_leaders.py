"""Link leaders on the internal lanes that cross at a left entry
(`jaxround.core.crossing_tables`, `jaxround.core.crossing_leaders`), on
two_lane.yaml's network as netconvert builds it."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.core.crossing_leaders import conflict_clock, crossing_leader_speed
from jaxround.core.geometry import locate
from jaxround.envs.rollout import run_until_left
from jaxround.envs.roundabout import make
from jaxround.lanes.ring_network import compile_lane_network
from jaxround.scenario.config import load_config
from jaxround.scenario.schedule import make_schedule
from jaxround.sumo_files.netconvert import network_file
from tests.conftest import TWO_LANE_SLOTS

pytestmark = pytest.mark.sumo


def test_each_left_entry_crosses_the_outer_ring_lane_going_on(tmp_path: Path) -> None:
    cfg = load_config("two_lane")
    net, _ = compile_lane_network(network_file(cfg, tmp_path), cfg.n_legs)
    c = net.crossings
    minor = [(net.lane_ids[a], net.lane_ids[b]) for a, b in zip(c.lane, c.foe) if a in
             set(c.lane[c.minor])]  # fmt: skip
    assert len(minor) == cfg.n_legs  # one left entry lane per leg
    for lane, foe in minor:
        g = int(np.nonzero(net.entry_internal == net.lane_ids.index(lane))[0][0])
        crossed = net.entry_crossing[g]
        assert crossed >= 0 and net.lane_ids[net.ring_through[crossed]] == foe
    # both sides of each crossing, each the mirror of the other
    for x in np.nonzero(c.minor)[0]:
        y = int(np.nonzero((c.lane == c.foe[x]) & (c.foe == c.lane[x]))[0][0])
        assert not c.minor[y]
        assert c.behind[x] == pytest.approx(c.foe_behind[y])
        assert c.size[x] == pytest.approx(c.foe_size[y])
    # the conflict area lies inside both lanes, 52 degrees apart: about 4.9 m
    lengths = net.lane_length[c.lane]
    assert np.all((c.behind > c.size / 2) & (c.behind < lengths))
    np.testing.assert_allclose(
        c.size, 3.2 * (2 / np.sin(np.radians(52)) - 1), rtol=0.05
    )


@pytest.fixture(scope="module")
def crossing_env():
    cfg = load_config("two_lane")
    return make(cfg, max_vehicles=TWO_LANE_SLOTS)


def test_the_crossing_is_on_by_default_and_runs(crossing_env) -> None:
    cfg = load_config("two_lane")
    off = make(cfg, max_vehicles=TWO_LANE_SLOTS, crossing_leaders=False)[0]
    assert off.net.crossing is None
    env, params = crossing_env
    assert env.net.crossing is not None
    schedule = env.schedule_from_numpy(make_schedule(cfg, seed=0))
    steps = int(600 / env.dt)  # ten minutes of the hour keep CI within its time
    state = jax.jit(lambda s, k: run_until_left(env, params, s, k, None, steps))(
        schedule, jax.random.PRNGKey(0)
    )
    assert int(state.stats.collisions) == 0
    assert int(state.stats.overflow) == 0
    depart = np.asarray(schedule.depart_s)
    left = np.isfinite(np.asarray(state.arrival_s))
    assert left[depart < 360].all()  # every vehicle of the first 6 minutes left


def _two_on_the_crossing(env, params, clock: tuple[float, float], speeds=(5.0, 5.0)):
    """The crossing's speed for a vehicle 1 m onto the left entry's internal
    lane (slot 0) and one 1 m onto the outer ring lane it crosses (slot 1)."""
    net = env.net
    cx = net.crossing
    x = int(np.nonzero(np.asarray(cx.minor))[0][0])
    lane, foe = int(cx.lane[x]), int(cx.foe[x])
    offsets = np.asarray(net.lane_offset)
    route_a = int(np.nonzero(~np.isnan(offsets[:, lane]))[0][0])
    route_b = int(np.nonzero(~np.isnan(offsets[:, foe]))[0][0])
    route = jnp.array([route_a, route_b])
    pos = jnp.array([offsets[route_a, lane] + 1.0, offsets[route_b, foe] + 1.0])
    k, _, _ = locate(net, route, pos)
    car = params.for_vehicles(jnp.zeros(2, bool))
    return crossing_leader_speed(
        net, car, route, k, pos, jnp.array(speeds), jnp.ones(2, bool),
        jnp.full(2, 13.89), jnp.array(clock), jnp.array([0, 1]),
        dt=env.dt, n_substeps=env.n_substeps, action_step=env.action_step,
    )  # fmt: skip


def test_on_the_junction_the_first_to_enter_leads(crossing_env) -> None:
    # MSVehicle::isLeader: both fronts on the crossing lanes, neither in the
    # other's way yet: the one that entered later yields, whichever link it took
    env, params = crossing_env
    entry_first = np.asarray(_two_on_the_crossing(env, params, (0.0, 1.0)))
    assert np.isinf(entry_first[0]) and entry_first[1] < 5.0
    ring_first = np.asarray(_two_on_the_crossing(env, params, (1.0, 0.0)))
    assert ring_first[0] < 5.0 and np.isinf(ring_first[1])
    # entered in the same step: the faster goes first
    same = np.asarray(_two_on_the_crossing(env, params, (1.0, 1.0), (4.0, 6.0)))
    assert same[0] < 4.0 and np.isinf(same[1])


def test_the_clock_runs_from_entering_the_junction_to_leaving_it(crossing_env) -> None:
    net = crossing_env[0].net
    offsets = np.asarray(net.lane_offset)
    lane = int(net.crossing.lane[0])
    route = int(np.nonzero(~np.isnan(offsets[:, lane]))[0][0])
    start, length = offsets[route, lane], float(net.lane_length[lane])
    before, on, after = start - 1.0, start + 1.0, start + length + 1.0
    pos = jnp.array([before, on, on, after])
    routes, active = jnp.full(4, route), jnp.array([True, True, False, True])
    earlier = jnp.array([3.0, jnp.inf, 2.0, 2.0])
    clock = conflict_clock(net, routes, pos, active, earlier, jnp.float32(5.0))
    # cleared before and after the junction and in an empty slot; set on entry
    assert np.asarray(clock).tolist() == [np.inf, 5.0, np.inf, np.inf]
    kept = conflict_clock(net, routes, pos, jnp.ones(4, bool), clock, jnp.float32(6.0))
    assert float(kept[1]) == 5.0
