"""LC2013 on the two-lane roundabout in JAX (`jaxround.lanes.ring_changer`)
against SUMO 1.28, decision by decision (`jaxround.apps.ring_lane_replay`).

SUMO runs; every step, the JAX changer decides from SUMO's state before
SUMO's own changes of the step, carrying its own LC2013 memory, and its
changes are compared with SUMO's: same vehicle, step and direction.

- Every route driven alone (one vehicle every 30 s): the roundabout bonus's
  move to the left entry lane and the return to the outer lane before the
  exit, exactly as SUMO makes them, on the held-out five-leg roundabout
  (one- and two-lane entries and exits).
- Traffic: `test_ring_changer_traffic.py`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.apps.ring_lane_record import record_sumo
from jaxround.apps.ring_lane_replay import arrays, replay, tables_for
from jaxround.lanes.ring_neighbours import roundabout_bonus
from jaxround.scenario.config import ScenarioConfig, load_config
from jaxround.scenario.schedule import Schedule
from tests.sumo.two_lane_networks import five_legs

pytestmark = pytest.mark.sumo

#: Seconds between two vehicles driving alone (one crosses in 20 to 27 s).
ALONE_S = 30.0


def every_route_alone(cfg: ScenarioConfig) -> Schedule:
    n = cfg.n_legs
    od = [(o, d) for o in range(n) for d in range(n) if o != d]
    return Schedule(
        depart_s=np.arange(len(od)) * ALONE_S,
        origin=np.array([o for o, _ in od], np.int32),
        destination=np.array([d for _, d in od], np.int32),
        speed_factor=np.ones(len(od)),
        av_rank=np.arange(len(od), dtype=np.int32),
        penetration=0.0,
    )


def test_every_route_alone_changes_as_in_sumo() -> None:
    """On the held-out five-leg roundabout (two_lane.yaml's alone run, 16
    changes, is exact too: docs/lc2013-map.md section 12)."""
    cfg = five_legs()
    tables = tables_for(cfg)
    schedule = every_route_alone(cfg)
    steps, reasons = record_sumo(
        cfg, tables.paths, ALONE_S * schedule.n_vehicles, schedule
    )
    tally = replay(cfg, tables, steps, reasons)["tally"]
    # each route past two or more junctions: left on the entry, right on the
    # ring's last edge; routes to the next exit: none
    passing = sum(
        1 for o, d in zip(schedule.origin, schedule.destination, strict=True)
        if (d - o) % cfg.n_legs >= 2
    )  # fmt: skip
    assert tally["sumo"] == 2 * passing
    assert tally.get("sumo cooperative") == tally.get("sumo strategic|urgent")
    assert tally["matched"] == tally["sumo"] == tally["jax"]


def test_the_roundabout_bonus_as_sumo_1_28_computes_it() -> None:
    """docs/lc2013-map.md section 4, "As 1.28 computes it": looking right from
    a ring lane the bonus is the distance's in full, however jammed the
    inner lane; elsewhere the jam factor takes it away; an empty roundabout
    keeps its bonus."""
    cfg = load_config("two_lane")
    tables = tables_for(cfg)
    net = arrays(cfg, tables)
    looks = np.argwhere(tables.bonus_junctions >= 2)  # (n, 4): p, k, z, side
    own = tables.edge_lanes[looks[:, 0], looks[:, 1], looks[:, 2]]
    on_ring = tables.lane_roundabout[own]
    right_on_ring = (looks[:, 3] == 0) & on_ring
    assert right_on_ring.any() and (looks[:, 3] == 1).any()
    unjammed = tables.bonus_unjammed[tuple(looks.T)]
    assert np.array_equal(unjammed, right_on_ring)

    def bonus(occupied: np.ndarray) -> np.ndarray:
        one = lambda at, lane: roundabout_bonus(  # noqa: E731  (one look)
            net, jnp.asarray(occupied), tuple(at), lane, 0.0, 1.0
        )
        return np.asarray(jax.vmap(one)(jnp.asarray(looks), jnp.asarray(own)))

    full = tables.bonus_distance[tuple(looks.T)] * 9.0
    empty = bonus(np.zeros(len(tables.paths.lane_ids)))
    np.testing.assert_allclose(empty, full, rtol=1e-5)
    inner_jammed = np.where(tables.paths.lane_index == 1, 200.0, 0.0)
    jammed = bonus(inner_jammed)
    np.testing.assert_allclose(jammed[right_on_ring], full[right_on_ring], rtol=1e-5)
    assert np.all(jammed[~right_on_ring] < full[~right_on_ring])
