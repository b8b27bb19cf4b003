"""The changer in rounds (`jaxround.lanes.ring_rounds`) against the one that
takes the turns one by one (`jaxround.lanes.ring_turns`), on SUMO's
traffic on the two-lane roundabout: the same changes and LC2013 states in
every step, the positions and the memory's numbers to float rounding (XLA
compiles the two programs differently; advices as a set: the rounds keep
them in another order), with steps that needed more than one round."""

from __future__ import annotations

from collections import Counter

import jax
import numpy as np
import pytest

from jaxround.apps.ring_lane_record import record_sumo
from jaxround.apps.ring_lane_replay import SlotBook, arrays, tables_for
from jaxround.lanes import ring_batches, ring_rounds
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.views import Memory
from jaxround.scenario.config import load_config
from jaxround.scenario.schedule import make_schedule

pytestmark = pytest.mark.sumo


def test_rounds_give_the_changes_of_the_turns_one_by_one() -> None:
    cfg = load_config("two_lane")
    tables = tables_for(cfg)
    # another seed than the traffic test's, past the ring's filling up
    steps, _ = record_sumo(cfg, tables.paths, 240.0, make_schedule(cfg, 1))
    net, book = arrays(cfg, tables), SlotBook.for_steps(cfg, steps)
    lc, dt = LaneChangeParams(), cfg.simulation.dt_s
    one_by_one = jax.jit(ring_batches.change_lanes, static_argnums=4)
    in_rounds = jax.jit(ring_rounds.change_lanes, static_argnums=4)
    memory = Memory.zeros(book.n_slots)
    rounds: Counter = Counter()
    changes = 0
    for rec in steps:
        veh, memory, _ = book.vehicles(rec, memory)
        expected, expected_memory = one_by_one(net, veh, memory, lc, dt)
        got, got_memory, n_rounds = in_rounds(net, veh, memory, lc, dt)
        rounds[int(n_rounds)] += 1
        changes += int(np.count_nonzero(expected.direction))
        for field in ("direction", "state", "lane", "path"):
            np.testing.assert_array_equal(
                getattr(got, field), getattr(expected, field), err_msg=f"{rec.time}"
            )
        np.testing.assert_allclose(got.pos, expected.pos, rtol=1e-6)
        # the memory of the vehicles on the network (empty slots are cleared
        # when a vehicle takes them)
        active = np.asarray(veh.active)
        np.testing.assert_array_equal(
            np.asarray(got_memory.state)[active],
            np.asarray(expected_memory.state)[active],
        )
        for field in ("speed_gain_probability", "keep_right_probability",
                      "look_ahead_speed"):  # fmt: skip
            np.testing.assert_allclose(
                np.asarray(getattr(got_memory, field))[active],
                np.asarray(getattr(expected_memory, field))[active],
                rtol=1e-6, atol=1e-9, err_msg=f"{rec.time} {field}",
            )  # fmt: skip
        np.testing.assert_allclose(
            np.sort(np.asarray(got_memory.advices)[active], axis=1),
            np.sort(np.asarray(expected_memory.advices)[active], axis=1),
            rtol=1e-6,
        )
        memory = expected_memory
    assert changes > 100
    assert sum(n for r, n in rounds.items() if r >= 2) > 50, rounds
