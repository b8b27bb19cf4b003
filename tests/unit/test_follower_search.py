"""How far upstream a lane change looks for the target lane's follower
(`ring_neighbours.follower_on`, SUMO's ``MSLane::getFollowersOnConsecutive``),
against figures measured on SUMO 1.28 with libsumo's ``getRightFollowers``.

two_lane.yaml's hour at 50% AVs, 38 s: an AV on the inner ring lane
``ring_1_1`` (front 3.3247 m in, its back 1.675 m behind the lane's start)
wants the outer lane ``ring_1_0``. Upstream of ``ring_1_0`` lie the
entry's internal lane ``:c1_0_0`` (then ``in_1_0``, an AV at 77.388 m) and
the ring's ``:c1_3_0`` (then ``ring_0_0``, an AV at 15.234 m that turns off
at the exit, the more critical of the two). SUMO goes on upstream of
``:c1_3_0`` (17.04 m) only while the target lane's braking distance at the
fastest speed factor departed so far, less the back's position, plus a
minGap, exceeds it: with the hour's 1.2308 it returns the entry's AV;
with a vehicle of speed factor 1.2625 departed first it returns the ring's,
with 1.2605 still the entry's (the step's ``search``: 16.95 and 17.05 m).
With the ego 0.5 s later (front 6.0995 m in) and shortened by ``setLength``,
the search stops before ``in_1_0`` (9.47 m up) for a length of 0.75 m and
reaches it for 0.9 m.
"""

from __future__ import annotations

import jax.numpy as jnp
import pytest

from jaxround.envs.lane_changes import changer_arrays, changer_tables, driver_numbers
from jaxround.lanes import ring_neighbours
from jaxround.scenario.config import load_config
from jaxround.sumo_files.netconvert import network_file


@pytest.fixture(scope="module")
def ring() -> tuple[ring_neighbours.RingArrays, list[str]]:
    cfg = load_config("two_lane")
    tables = changer_tables(cfg, network_file(cfg))
    return changer_arrays(cfg, tables), list(tables.paths.lane_ids)


def follower(
    ring: tuple[ring_neighbours.RingArrays, list[str]],
    vehicles: list[tuple[str, float, float]],
    fastest: float,
    ego_length: float = 5.0,
) -> tuple[int, bool, float]:
    """Vehicle 0's follower on ``ring_1_0``; ``vehicles``: (lane, front
    position on it, speed), all AVs of two_lane.yaml."""
    net, ids = ring
    av = driver_numbers(load_config("two_lane").drivers.av)
    n = len(vehicles)
    driver = av._replace(**{f: jnp.full(n, getattr(av, f)) for f in av._fields})
    driver = driver._replace(length=driver.length.at[0].set(ego_length))
    scene = ring_neighbours.Scene(
        lane=jnp.asarray([ids.index(lane) for lane, _, _ in vehicles]),
        on_lane=jnp.asarray([pos for _, pos, _ in vehicles]),
        speed=jnp.asarray([v for _, _, v in vehicles]),
        driver=driver,
        others=jnp.arange(n) != 0,
        done=jnp.zeros(n, bool),
        fastest_departed=jnp.asarray(fastest),
    )
    slot, exists, gap = ring_neighbours.follower_on(
        net, scene, jnp.asarray(0), jnp.asarray(ids.index("ring_1_0"))
    )
    return int(slot), bool(exists), float(gap)


AT_38 = [
    ("ring_1_1", 3.324673, 6.7456),
    ("ring_0_0", 15.233741, 8.3099),
    ("in_1_0", 77.388, 7.8477),
]


@pytest.mark.parametrize(
    ("fastest", "slot", "gap"),
    [(1.2308, 2, 17.896318), (1.2605, 2, 17.896318), (1.2625, 1, 14.820923)],
)
def test_the_search_goes_upstream_as_far_as_the_fastest_departed_reaches(
    ring: tuple[ring_neighbours.RingArrays, list[str]],
    fastest: float,
    slot: int,
    gap: float,
) -> None:
    got_slot, exists, got_gap = follower(ring, AT_38, fastest)
    assert exists and got_slot == slot
    assert got_gap == pytest.approx(gap, abs=1e-3)  # libsumo's getRightFollowers


@pytest.mark.parametrize(("length", "found"), [(0.75, False), (0.9, True)])
def test_the_search_shrinks_as_the_back_moves_into_the_lane(
    ring: tuple[ring_neighbours.RingArrays, list[str]], length: float, found: bool
) -> None:
    at_38_5 = [("ring_1_1", 6.099503, 5.5497), ("in_1_0", 80.658863, 6.541)]
    slot, exists, gap = follower(ring, at_38_5, 1.2308, ego_length=length)
    assert exists is found
    if found:  # libsumo's getRightFollowers: 21.5006 m
        assert slot == 1
        assert gap == pytest.approx(21.5006, abs=1e-3)
