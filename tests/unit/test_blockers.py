"""LC2013's room for a counter-lane-change blocker (`jaxround.lanes.blockers`,
its use in `jaxround.lanes.memory.patch_speed`), and the target lane's leader
on the lane after an internal lane (`ring_neighbours.leader_on`).

SUMO 1.28 step for step: tests/sumo/test_look_ahead_sumo.py.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.envs.lane_changes import changer_arrays, changer_tables, driver_numbers
from jaxround.lanes import actions as lca
from jaxround.lanes import ring_neighbours
from jaxround.lanes.blockers import blocker_stop_speed, save_blocker_length
from jaxround.lanes.follow import Driver
from jaxround.lanes.memory import after_change, patch_speed, prepare_step
from jaxround.lanes.views import Memory, Neighbour
from jaxround.scenario.config import load_config
from jaxround.sumo_files.netconvert import network_file

DRIVER = Driver(
    accel=2.6, decel=4.2939, emergency_decel=9.0, tau=1.0, min_gap=2.5, length=5.0,
    delta=4.0, max_speed=55.56,
)  # fmt: skip


def blocker(state: int, exists: bool = True) -> Neighbour:
    return Neighbour(
        exists=jnp.asarray(exists), gap=jnp.asarray(1.0), speed=jnp.asarray(7.4),
        accel=jnp.asarray(0.0), driver=DRIVER, v_max=jnp.asarray(8.33),
        state=jnp.asarray(state, jnp.int32),
    )  # fmt: skip


@pytest.mark.parametrize(
    ("state", "kept", "room"),
    [
        (lca.LEFT | lca.COOPERATIVE, 0.0, 7.5),  # wants the other way: room
        (lca.LEFT | lca.COOPERATIVE, 9.0, 9.0),  # more room kept already
        (lca.RIGHT | lca.STRATEGIC, 0.0, 0.0),  # wants the same way
        (lca.STAY | lca.COOPERATIVE, 0.0, 0.0),  # wants nothing
    ],
)
def test_room_is_kept_for_a_blocker_that_wants_the_other_way(
    state: int, kept: float, room: float
) -> None:
    # ego wants right, so the blocker's LEFT bit is the counter direction;
    # 16.46 m left at 7.06 m/s (4.15 m to brake): the blocker fits
    def save(b: Neighbour) -> float:
        return float(save_blocker_length(
            b, counter=lca.LEFT, kept=jnp.asarray(kept), ego=DRIVER,
            v=jnp.asarray(7.063), left_space=jnp.asarray(16.457), dt=0.5,
        ))  # fmt: skip

    assert save(blocker(state)) == pytest.approx(room)
    assert save(blocker(state, exists=False)) == pytest.approx(kept)


@pytest.mark.parametrize(("length", "room"), [(3.6, 6.1), (3.7, 0.0), (5.0, 0.0)])
def test_room_is_kept_only_for_a_blocker_that_fits_in_front(
    length: float, room: float
) -> None:
    # two_lane.yaml at 50% AVs, 38.5 s: an AV with 11.0906 m left at 5.54966
    # m/s (2.3293 m to brake) beside a human driver that wants its lane.
    # SUMO 1.28 keeps no room for the 5 m driver (4.0755 m/s next, as with
    # the driver's lane-change mode 0); with libsumo's setLength it keeps the
    # room for 3.6 m (3.4027 m/s next) and not for 3.7 m: the lengthWithGap
    # and a minGap within the left space less POSITION_EPS and the braking
    # distance, 6.16 m (blockers' note)
    short = DRIVER._replace(length=length)
    b = blocker(lca.LEFT | lca.COOPERATIVE)._replace(driver=short)
    got = save_blocker_length(
        b, counter=lca.LEFT, kept=jnp.asarray(0.0), ego=DRIVER,
        v=jnp.asarray(5.54966), left_space=jnp.asarray(11.0906), dt=0.5,
    )  # fmt: skip
    assert float(got) == pytest.approx(room)


def memory_with_room(left_space: float, blocker_length: float) -> Memory:
    memory = Memory.zeros(2)
    return memory.replace(
        left_space=jnp.asarray([left_space, 0.0]),
        blocker_length=jnp.asarray([blocker_length, 0.0]),
    )


def test_the_stop_before_the_room_brakes_beyond_decel_where_it_must() -> None:
    # the two_lane case of blockers' note: 16.457 m left, 7.5 m of room, at
    # 7.063 m/s; SUMO 1.28 stops 10.1 m before the lane's end at 3.68498 m/s
    # (libsumo's getStopSpeed at 6.357 m gives 3.68494)
    memory = memory_with_room(16.4570621, 7.5)
    driver = Driver(*(jnp.full(2, x) for x in DRIVER))
    v = jnp.asarray([7.062972, 7.062972])
    stop, _ = blocker_stop_speed(memory, driver, v, jnp.full(2, 8.33), 0.5)
    assert float(stop[0]) == pytest.approx(3.68498, abs=2e-4)
    assert np.isnan(float(stop[1]))  # no room kept: no stop
    v_min = v - 4.2939 * 0.5  # minNextSpeed, 4.916 m/s
    v_max = jnp.asarray([8.33, 8.33])
    emergency = v - 9.0 * 0.5
    patched = patch_speed(memory, v_min, v_max, v_max, 1.0, blocker=(stop, emergency))
    assert float(patched[0]) == pytest.approx(float(stop[0]))  # below decel's 4.916
    assert float(patched[1]) == pytest.approx(8.33)
    # the room is gone once the step is prepared and after a change
    assert float(prepare_step(memory).blocker_length[0]) == 0.0
    changed = after_change(memory, jnp.asarray([True, False]))
    assert float(changed.blocker_length[0]) == 0.0
    assert float(changed.left_space[0]) == 0.0


def test_a_stop_beyond_emergency_braking_is_not_taken() -> None:
    # the room 2 m ahead at 7 m/s: the stop speed is below v - emergencyDecel
    # dt, so the bound stays minNextSpeed (SUMO: `safe >= vMinEmergency`)
    memory = memory_with_room(13.0, 7.5)
    driver = Driver(*(jnp.full(2, x) for x in DRIVER))
    v = jnp.asarray([7.0, 7.0])
    stop, _ = blocker_stop_speed(memory, driver, v, jnp.full(2, 8.33), 0.5)
    emergency = v - 9.0 * 0.5
    assert float(stop[0]) < float(emergency[0])
    v_min = v - 4.2939 * 0.5
    v_max = jnp.asarray([8.33, 8.33])
    patched = patch_speed(memory, v_min, v_max, v_max, 1.0, blocker=(stop, emergency))
    assert float(patched[0]) == pytest.approx(float(v_min[0]))


def test_the_right_leader_beyond_an_internal_lane_is_found_across_float32() -> None:
    # two_lane.yaml, 29.5 s at 50% AVs: an AV on the inner ring lane's
    # internal lane :c0_3_1 at 14.241 m, its right leader on ring_0_0 at
    # 6.66 m. In float32 ring_0_0's start on that lane path is 1.5e-5 m
    # before :c0_3_0's start plus its length; the search once compared the
    # two and missed the leader (SUMO: blocked by it, 0x811; the step 0x11)
    cfg = load_config("two_lane")
    tables = changer_tables(cfg, network_file(cfg))
    net = changer_arrays(cfg, tables)
    ids = list(tables.paths.lane_ids)
    own, target, ahead = (
        ids.index(":c0_3_1"),
        ids.index(":c0_3_0"),
        ids.index("ring_0_0"),
    )
    lanes = np.asarray(net.path_lanes)
    change = np.asarray(net.change_path)
    path, k = next(
        (p, int(np.flatnonzero(lanes[p] == own)[0]))
        for p in range(lanes.shape[0])
        if own in lanes[p]
        and change[p, int(np.flatnonzero(lanes[p] == own)[0]), 0] >= 0
    )
    q = int(change[path, k, 0])
    offset, length = np.asarray(net.lane_offset), np.asarray(net.lane_length)
    assert offset[q, ahead] < offset[q, target] + length[target]  # the rounding
    av = driver_numbers(cfg.drivers.av)
    driver = Driver(*(jnp.full(2, x, jnp.float32) for x in av))
    scene = ring_neighbours.Scene(
        lane=jnp.asarray([own, ahead]), on_lane=jnp.asarray([14.241, 6.660]),
        speed=jnp.asarray([7.3614, 7.7158]), driver=driver,
        others=jnp.asarray([False, True]), done=jnp.asarray([False, True]),
    )  # fmt: skip
    slot, exists, gap = ring_neighbours.leader_on(
        net, scene, jnp.asarray(0), jnp.asarray(q), jnp.asarray(target),
        jnp.asarray(own), 0.5,
    )  # fmt: skip
    assert bool(exists) and int(slot) == 1
    assert float(gap) == pytest.approx(17.04 - 14.241 + 6.660 - 7.5, abs=1e-3)
