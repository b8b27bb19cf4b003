"""The hold at entries (`jaxround.lanes.entry_hold`): the step holds as
SUMO 1.28 does by default (compared with SUMO in
tests/sumo/test_lane_hold_probe.py); with the earlier reading
``hold_entries="occupied"`` a change onto an entry lane is held back exactly
while a foe link's internal lane of that entry is occupied, as SUMO's lane
ids say, and a held change is not made."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.core import geometry
from jaxround.envs.lane_changes import LaneChanger
from jaxround.envs.roundabout import make
from jaxround.lanes.params import LaneChangeParams
from jaxround.scenario.schedule import make_schedule
from jaxround.sumo_files.netconvert import network_file
from tests.conftest import TWO_LANE_SLOTS

#: Steps run (0.5 s each): queues and a busy ring.
STEPS = 400


def foe_lanes(net_file: Path) -> dict[str, set[str]]:
    """Each entry lane's foe internal lanes, from the junctions'
    ``<request foes=...>`` (bit j from the right: link j, in ``intLanes``
    order) and the connection leaving the lane."""
    root = ET.parse(net_file).getroot()
    via = {c.get("from") + "_" + c.get("fromLane"): c.get("via")
           for c in root.iter("connection") if c.get("via")}  # fmt: skip
    foes = {}
    for junction in root.iter("junction"):
        internal = junction.get("intLanes", "").split()
        for request in junction.iter("request"):
            bits = request.get("foes")[::-1]
            mine = internal[int(request.get("index"))]
            foes[mine] = {internal[j] for j, bit in enumerate(bits) if bit == "1"}
    return {lane: foes[v] for lane, v in via.items() if lane.startswith("in_")}


def test_a_change_is_held_while_the_target_entrys_foe_lanes_are_occupied() -> None:
    env, params = make("two_lane", max_vehicles=TWO_LANE_SLOTS)
    changer = LaneChanger(env.cfg, network_file(env.cfg), hold_entries="occupied")
    net, lane_ids = env.net, env.network.lane_ids
    schedule = env.schedule_from_numpy(make_schedule(env.cfg, seed=0))
    _, state = env.reset_to_schedule(schedule, params)
    action = jnp.zeros((state.active.shape[0], 2))
    step = jax.jit(env.step)
    car_of = jax.jit(lambda s: params.for_vehicles(s.is_av))
    holds = jax.jit(lambda s: changer.holds(s, net, car_of(s)))
    change = jax.jit(lambda s: changer(s, LaneChangeParams(), None, net, car_of(s))[1])
    length = float(env.cfg.drivers.hv.length)
    foes_of = foe_lanes(network_file(env.cfg))
    assert foes_of["in_0_1"] > foes_of["in_0_0"]  # the left lane's link crosses
    checked = held = 0
    for _ in range(STEPS):
        _, state, *_ = step(jax.random.PRNGKey(0), state, action, params)
        # the changer once more on the state as it is (as after a move)
        hold, direction = np.asarray(holds(state)), np.asarray(change(state))
        active = np.asarray(state.active)
        _, front, _ = geometry.locate(net, state.route, state.pos)
        _, back, _ = geometry.locate(net, state.route, state.pos - length)
        on = {lane_ids[int(x)] for x in np.concatenate(
            [np.asarray(front)[active], np.asarray(back)[active]]
        )}  # fmt: skip
        yield_offset = np.asarray(net.yield_offset)[np.asarray(state.route)]
        before = active & (yield_offset - np.asarray(state.pos) > 0)
        for i in np.nonzero(before)[0]:
            lane = lane_ids[int(front[i])]
            side = 1 if lane.endswith("_0") else 0  # the other entry lane
            target = lane[:-1] + str(side)
            expected = bool(foes_of[target] & on)
            assert bool(hold[i, side]) == expected, (lane, sorted(on))
            assert not hold[i, 1 - side]  # no lane on that side
            checked += 1
            if expected:
                held += 1
                assert direction[i] != (1 if side else -1)
    assert checked > 1000
    assert held > 50


def test_the_step_holds_as_sumo_1_28_by_default() -> None:
    env, params = make("two_lane", max_vehicles=TWO_LANE_SLOTS)
    assert env.lane_changer.hold_entries == "parallel"
    with pytest.raises(ValueError, match="hold_entries='sometimes'"):
        LaneChanger(env.cfg, network_file(env.cfg), hold_entries="sometimes")
    # the hold reads the approach the step registered: called alone, the
    # changer says what it lacks
    _, state = env.reset(jax.random.PRNGKey(0), params)
    car = params.for_vehicles(state.is_av)
    with pytest.raises(ValueError, match="own_entry"):
        env.lane_changer(state, LaneChangeParams(), None, env.net, car)
