"""Link leaders on the internal lanes that cross at a left entry
(`jaxround.core.crossing_tables`, `jaxround.core.crossing_leaders`), on
two_lane.yaml's network as netconvert builds it."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np
import pytest

from jaxround.envs.rollout import run_until_left
from jaxround.envs.roundabout import make
from jaxround.lanes.ring_network import compile_lane_network
from jaxround.scenario.config import load_config
from jaxround.scenario.schedule import make_schedule
from jaxround.sumo_files.netconvert import network_file

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


def test_the_option_is_off_by_default_and_runs_when_on() -> None:
    cfg = load_config("two_lane")
    assert make(cfg)[0].net.crossing is None
    env, params = make(cfg, crossing_leaders=True)
    assert env.net.crossing is not None
    schedule = env.schedule_from_numpy(make_schedule(cfg, seed=0))
    steps = int(900 / env.dt)  # a quarter of the hour keeps CI within its time
    state = jax.jit(lambda s, k: run_until_left(env, params, s, k, None, steps))(
        schedule, jax.random.PRNGKey(0)
    )
    assert int(state.stats.collisions) == 0
    assert int(state.stats.overflow) == 0
    depart = np.asarray(schedule.depart_s)
    left = np.isfinite(np.asarray(state.arrival_s))
    assert left[depart < 600].all()  # every vehicle of the first 10 minutes left
