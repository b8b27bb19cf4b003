"""The vehicles about to merge ahead on a change's target lane
(`jaxround.lanes.merge_leaders`), on two_lane.yaml's junction c2: a ring
vehicle near the end of the outer through lane (:c2_1_0) looking at the
inner one (:c2_1_1), which merges with the entry's left lane (:c2_3_1)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxround.envs.roundabout import make
from jaxround.lanes.merge_leaders import merge_leaders
from tests.conftest import TWO_LANE_SLOTS

LEFT = 1


@pytest.fixture(scope="module")
def scene():  # noqa: ANN201 - (env, params, state, paths)
    env, params = make("two_lane", max_vehicles=TWO_LANE_SLOTS)
    _, state = env.reset(jax.random.PRNGKey(0), params)
    ids = list(env.network.lane_ids)
    lanes = np.asarray(env.net.route_lanes)
    change = np.asarray(env.lane_changer.arrays.change_path)

    def path_through(lane_id: str, can_go_left: bool = False) -> tuple[int, int]:
        lane = ids.index(lane_id)
        for p in range(lanes.shape[0]):
            hits = np.nonzero(lanes[p] == lane)[0]
            if hits.size and (not can_go_left or change[p, hits[0], LEFT] >= 0):
                return p, int(hits[0])
        raise AssertionError(f"no path through {lane_id}")

    return env, params, state, path_through, ids


def place(env, state, rows):  # noqa: ANN001, ANN202
    """Only the vehicles of ``rows`` (slot, path, k, position on lane k,
    speed) active."""
    starts = np.asarray(env.net.route_lane_start)
    route = np.zeros_like(np.asarray(state.route))
    pos = np.zeros_like(np.asarray(state.pos))
    speed = np.zeros_like(np.asarray(state.speed))
    active = np.zeros_like(np.asarray(state.active))
    for slot, path, k, on_lane, v in rows:
        route[slot], pos[slot], speed[slot] = path, starts[path, k] + on_lane, v
        active[slot] = True
    return state.replace(route=route, pos=pos, speed=speed, active=active)


def leaders(env, params, state):  # noqa: ANN001, ANN202
    car = params.for_vehicles(state.is_av)
    return merge_leaders(
        env.net, env.lane_changer.arrays, car, state.route, state.pos,
        state.speed, state.active, env.dt,
    )  # fmt: skip


def test_an_entering_vehicle_past_the_crossing_point_leads_a_change(scene) -> None:  # noqa: ANN001
    env, params, state, path_through, ids = scene
    ego_path, ego_k = path_through(":c2_1_0", can_go_left=True)
    foe_path, foe_k = path_through(":c2_3_1")
    length = float(np.asarray(env.net.lane_length)[ids.index(":c2_1_0")])
    # ego 0.5 m before the end; the foe's front 3.3 m before the end of its
    # lane, past the crossing point: it is in the way whoever came first
    state = place(env, state, [(0, ego_path, ego_k, length - 0.5, 0.4),
                               (1, foe_path, foe_k, 10.99, 3.9)])  # fmt: skip
    found = leaders(env, params, state)
    assert int(found.slot[0, LEFT]) == 1
    assert float(found.gap[0, LEFT]) < 0.0  # an overlap: the change is blocked
    assert float(found.link_at[0, LEFT]) == pytest.approx(0.5, abs=1e-4)
    assert bool(found.critical[0, LEFT])
    assert int(found.slot[0, 1 - LEFT]) == -1  # no lane to the right
    assert int(found.slot[1, LEFT]) == -1  # entries' lanes: no change there


def test_far_from_the_lane_end_the_changer_does_not_look(scene) -> None:  # noqa: ANN001
    env, params, state, path_through, _ = scene
    ego_path, ego_k = path_through(":c2_1_0", can_go_left=True)
    foe_path, foe_k = path_through(":c2_3_1")
    # the ring edge before the junction, 30 m before its end at 5 m/s: beyond
    # brakeGap + minGap, and not on an internal lane
    ring_k = ego_k - 1
    ring = int(np.asarray(env.net.route_lanes)[ego_path, ring_k])
    ring_length = float(np.asarray(env.net.lane_length)[ring])
    far = [(0, ego_path, ring_k, ring_length - 30.0, 5.0),
           (1, foe_path, foe_k, 10.99, 3.9)]  # fmt: skip
    found = leaders(env, params, place(env, state, far))
    assert int(found.slot[0, LEFT]) == -1
    near = [(0, ego_path, ring_k, ring_length - 1.0, 5.0),
            (1, foe_path, foe_k, 10.99, 3.9)]  # fmt: skip
    found = leaders(env, params, place(env, state, near))
    assert int(found.slot[0, LEFT]) == 1
