"""A lane change's leader on a lane that another internal lane leaves from
the same lane: SUMO's changer meets a vehicle on that other lane as a
same-source link leader (``MSLane::getLeaderOnConsecutive`` ->
``MSLink::getLeaderInfo``) while its back has not passed where the two
lanes part, measured from that point (`ring_neighbours.leader_on`).

On two_lane.yaml's roads the ring's internal lane ``:c3_3_0`` and the
exit's ``:c3_2_0`` both leave the outer ring lane; they part 5.85 m into
the first and 5.922 m into the second (`compile.internal_geometry`). At
50% AVs with ``--controller gap:10`` an AV on ``:c3_3_1`` changed onto
``:c3_3_0`` beside a vehicle on ``:c3_2_0`` in the step and not in SUMO,
and the two overlapped (docs/two_lane.md).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.envs.lane_changes import changer_arrays, changer_tables, driver_numbers
from jaxround.lanes import ring_neighbours
from jaxround.scenario.config import load_config
from jaxround.sumo_files.netconvert import network_file

TARGET, SIBLING, OWN = ":c3_3_0", ":c3_2_0", ":c3_3_1"

Ring = tuple[ring_neighbours.RingArrays, list[str]]


@pytest.fixture(scope="module")
def ring() -> Ring:
    cfg = load_config("two_lane")
    tables = changer_tables(cfg, network_file(cfg))
    return changer_arrays(cfg, tables), list(tables.paths.lane_ids)


def test_the_two_internal_lanes_part_where_sumo_has_it(ring: Ring) -> None:
    net, ids = ring
    target, sibling = ids.index(TARGET), ids.index(SIBLING)
    assert int(net.lane_sibling[target]) == sibling
    assert int(net.lane_sibling[sibling]) == target
    assert float(net.lane_diverge[target]) == pytest.approx(5.85, abs=1e-3)
    assert float(net.lane_diverge[sibling]) == pytest.approx(5.922, abs=1e-3)
    # a lane with no other internal lane leaving its lane has none
    assert int(net.lane_sibling[ids.index(OWN)]) == -1


def leader(
    ring: Ring, ego_pos: float, other: tuple[str, float, float]
) -> tuple[bool, float]:
    """Vehicle 0 on ``:c3_3_1`` at ``ego_pos`` looks at ``:c3_3_0``; vehicle
    1 at (lane, front position, length). Both AVs of two_lane.yaml."""
    net, ids = ring
    target = ids.index(TARGET)
    path = int(np.nonzero(np.any(np.asarray(net.path_lanes) == target, axis=1))[0][0])
    av = driver_numbers(load_config("two_lane").drivers.av)
    driver = av._replace(**{f: jnp.full(2, getattr(av, f)) for f in av._fields})
    driver = driver._replace(length=jnp.asarray([5.0, other[2]]))
    scene = ring_neighbours.Scene(
        lane=jnp.asarray([ids.index(OWN), ids.index(other[0])]),
        on_lane=jnp.asarray([ego_pos, other[1]]),
        speed=jnp.asarray([5.0, 5.0]),
        driver=driver,
        others=jnp.asarray([False, True]),
        done=jnp.zeros(2, bool),
    )
    slot, exists, gap = ring_neighbours.leader_on(
        net, scene, jnp.asarray(0), jnp.asarray(path), jnp.asarray(target),
        jnp.asarray(ids.index(OWN)), 0.5,
    )  # fmt: skip
    assert not bool(exists) or int(slot) == 1
    return bool(exists), float(gap)


@pytest.mark.parametrize(
    ("ego_pos", "front", "length"),
    [(3.0, 4.0, 5.0), (3.0, 8.5, 5.0), (8.0, 8.5, 5.0), (10.8, 8.5, 5.0)],
)
def test_a_vehicle_on_the_exit_leads_until_its_back_passes_the_parting(
    ring: Ring, ego_pos: float, front: float, length: float
) -> None:
    """Its gap is ``distToCrossing - minGap - leaderBackDist``: its back as far
    before the target's parting point as before its own, the back still on
    the ring lane both leave (4.0 m in) included; behind the ego too (a
    negative gap blocks the change) until the ego is its length past it."""
    net, ids = ring
    parting = float(net.lane_diverge[ids.index(TARGET)])  # 5.85 m
    sibling_parting = float(net.lane_diverge[ids.index(SIBLING)])  # 5.922 m
    exists, gap = leader(ring, ego_pos, (SIBLING, front, length))
    assert exists
    want = parting + (front - length - sibling_parting) - ego_pos - 2.5
    assert gap == pytest.approx(want, abs=1e-4)


@pytest.mark.parametrize(
    ("ego_pos", "front", "length"),
    [(3.0, 8.5, 2.0), (10.9, 8.5, 5.0)],
)
def test_it_leads_no_more_once_past_the_parting_or_the_ego_is(
    ring: Ring, ego_pos: float, front: float, length: float
) -> None:
    """A back 6.5 m into the exit's lane is past its parting point (5.922);
    an ego more than its length (5 m) past the target's (5.85) sees none."""
    exists, _ = leader(ring, ego_pos, (SIBLING, front, length))
    assert not exists


def follower(ring: Ring, ego_pos: float, front: float) -> tuple[bool, float]:
    """Vehicle 0 on ``:c3_3_1`` at ``ego_pos`` looks back on ``:c3_3_0``;
    vehicle 1 (5 m) on ``:c3_2_0`` at ``front``."""
    net, ids = ring
    av = driver_numbers(load_config("two_lane").drivers.av)
    driver = av._replace(**{f: jnp.full(2, getattr(av, f)) for f in av._fields})
    scene = ring_neighbours.Scene(
        lane=jnp.asarray([ids.index(OWN), ids.index(SIBLING)]),
        on_lane=jnp.asarray([ego_pos, front]),
        speed=jnp.asarray([5.0, 5.0]),
        driver=driver,
        others=jnp.asarray([False, True]),
        done=jnp.zeros(2, bool),
    )
    slot, exists, gap = ring_neighbours.follower_on(
        net, scene, jnp.asarray(0), jnp.asarray(ids.index(TARGET))
    )
    assert not bool(exists) or int(slot) == 1
    return bool(exists), float(gap)


def test_a_vehicle_turning_off_follows_while_its_back_is_on_the_ring_lane(
    ring: Ring,
) -> None:
    """1.11 m into the exit's internal lane, its back still on the outer ring
    lane both internal lanes leave, it is a partial occupant of that lane,
    met by the followers' search upstream of the target (two_lane.yaml at
    50% AVs with gap:10, schedule 1, 2377.5 s: an AV changed onto
    ``:c3_3_0`` at 1.31 m beside it in the step, and they overlapped); its
    back off that lane, it follows no more."""
    exists, gap = follower(ring, 1.31, 1.11)
    assert exists
    assert gap == pytest.approx((1.31 - 5.0) - 1.11 - 2.5, abs=1e-4)
    assert not follower(ring, 1.31, 5.5)[0]


def test_a_same_source_leader_leads_no_more_once_the_follower_passed_the_parting():
    """The step's car-following (`geometry.past_the_parting`): a vehicle on
    the exit's internal lane, its back 3 m in (before its parting point,
    5.922 m), leads one on the ring's through lane until that one's front
    passes 5.85 m (two_lane.yaml at 50% AVs with gap:10, schedule 1,
    3033 s: an AV 9.64 m into ``:c0_3_0`` stopped behind a vehicle already
    on the exit, as SUMO does not)."""
    from jaxround.core.geometry import NetArrays, past_the_parting
    from jaxround.envs.lane_changes import compiled_network

    cfg = load_config("two_lane")
    network, _ = compiled_network(cfg, network_file(cfg))
    net = NetArrays.from_network(network)
    ids = list(network.lane_ids)
    lanes = np.asarray(network.route_lanes)
    through = int(np.nonzero(np.any(lanes == ids.index(TARGET), axis=1))[0][0])
    exiting = int(np.nonzero(np.any(lanes == ids.index(SIBLING), axis=1))[0][0])
    offset = np.asarray(network.lane_offset)

    def parted(ego_front: float) -> bool:
        route = jnp.asarray([through, exiting])
        pos = jnp.asarray(
            [
                offset[through, ids.index(TARGET)] + ego_front,
                offset[exiting, ids.index(SIBLING)] + 8.0,
            ]
        )
        return bool(past_the_parting(net, route, pos, jnp.float32(5.0))[0, 1])

    assert not parted(5.8)
    assert parted(5.9)


def test_a_lane_with_lanes_on_both_sides_is_refused() -> None:
    """The changer takes one look per turn, to the side that has a lane: a
    road of three lanes is named and refused before anything runs."""
    cfg = load_config("two_lane")
    tables = changer_tables(cfg, network_file(cfg))
    paths = tables.paths
    lane = int(np.argmax(paths.lane_right >= 0))  # a left lane with a right
    left = paths.lane_left.copy()
    left[lane] = paths.lane_right[lane]  # and now a lane on its left too
    wider = dataclasses.replace(
        tables, paths=dataclasses.replace(paths, lane_left=left)
    )
    with pytest.raises(
        ValueError, match=f"lane {paths.lane_ids[lane]} has lanes on both"
    ):
        ring_neighbours.RingArrays.from_tables(wider, 4.5)
