"""The neighbour tables against the all-pairs searches they replace.

Every comparison is exact (bit for bit, nan equal to nan) on random states
of the Milan and six-leg networks: slots empty, partly and fully occupied;
vehicles at lane starts, straddling two lanes, on internal junction lanes at
their divergence points, and slots sharing one position (ties).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.core import neighbours, planning
from jaxround.core.geometry import back_projection, leaders, locate, project
from jaxround.core.link_leaders import link_leader
from jaxround.envs import observe
from jaxround.envs.roundabout import make
from tests.unit import allpairs

M = 24
STATES = 48  # per network, vmapped


def _assert_same(new: Any, old: Any, what: str) -> None:
    for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(old), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape, what
        same = np.array_equal(a, b, equal_nan=True)
        assert same, f"{what}: {np.argwhere(a != b)[:5].tolist()} differ"


def random_states(env: Any, seed: int, n: int = STATES) -> dict[str, jax.Array]:
    """n states of M slots: routes, positions, speeds, accelerations, active.

    A third of the slots sit on an edge: a lane's start, a vehicle length
    beyond it (the back at the start), a divergence point of a sibling lane,
    an internal lane, or the position of another slot (a tie). Occupancy
    cycles through empty, partial and full.
    """
    rng = np.random.default_rng(seed)
    net = env.net
    starts = np.asarray(net.route_lane_start)  # float32 (R, K), inf padded
    lanes = np.asarray(net.route_lanes)
    lengths = np.asarray(net.lane_length)
    diverge = np.asarray(net.lane_diverge)
    internal = np.asarray(net.lane_internal)
    route_len = np.asarray(net.route_length)
    length = np.float32(env.default_params.vehicle.length)
    r_n = route_len.shape[0]
    route = rng.integers(0, r_n, (n, M))
    pos = (rng.random((n, M)) * route_len[route]).astype(np.float32)
    for s in range(n):
        for i in np.nonzero(rng.random(M) < 0.35)[0]:
            r = route[s, i]
            ks = np.nonzero(lanes[r] >= 0)[0]
            k = rng.choice(ks)
            lane, start = lanes[r, k], starts[r, k]
            edge = rng.integers(0, 7)
            if edge == 0:
                x = start
            elif edge == 1:
                x = start + length
            elif edge == 2:
                x = np.nextafter(start, np.float32(-np.inf))
            elif edge == 3:
                x = start + diverge[lane] * rng.choice([1.0, 0.999, 1.001])
            elif edge == 4:  # somewhere on an internal lane
                ki = rng.choice(ks[internal[lanes[r, ks]]])
                x = starts[r, ki] + rng.random() * lengths[lanes[r, ki]]
            elif edge == 5:  # a tie with another slot
                j = rng.integers(0, M)
                route[s, i], x = route[s, j], pos[s, j]
            else:
                x = start + length + np.float32(1e-3)
            pos[s, i] = np.clip(np.float32(x), 0.0, route_len[route[s, i]])
    occupancy = np.array([0.0, 0.3, 0.7, 1.0])[np.arange(n) % 4]
    active = rng.random((n, M)) < occupancy[:, None]
    return {
        "route": jnp.asarray(route, jnp.int32),
        "pos": jnp.asarray(pos, jnp.float32),
        "speed": jnp.asarray(rng.random((n, M)) * 14, jnp.float32),
        "accel": jnp.asarray(rng.normal(size=(n, M)), jnp.float32),
        "waiting_s": jnp.asarray(rng.random((n, M)) * 30, jnp.float32),
        "active": jnp.asarray(active),
    }


@pytest.fixture(scope="module", params=["milan", "six_leg"])
def case(request: pytest.FixtureRequest) -> tuple[Any, Any, dict[str, jax.Array]]:
    env, params = make(request.param, max_vehicles=M)
    return env, params, random_states(env, seed=len(request.param))


def _old_front_back(net, route, pos, length):
    _, lane, pos_on_lane = locate(net, route, pos)
    front = project(net, route, lane, pos_on_lane)
    back = back_projection(net, route, pos, length)
    return front, jnp.where(jnp.isnan(back), front - length, back)


def test_route_projections_are_the_pairwise_projections(case) -> None:
    env, params, states = case
    net, length = env.net, params.vehicle.length

    @jax.vmap
    def both(s):
        front, back = neighbours.route_projections(net, s["route"], s["pos"], length)
        return (front[s["route"]], back[s["route"]]), _old_front_back(
            net, s["route"], s["pos"], length
        )

    new, old = jax.jit(both)(states)
    _assert_same(new, old, "front and back projections")


def _segments(net, seed: int) -> dict[str, tuple[jax.Array, jax.Array]]:
    """The planning step's three kinds of segment, and random ones."""
    starts = net.route_lane_start
    rng = np.random.default_rng(seed)
    r_n, k_n = starts.shape
    a = rng.random((r_n, 5)) * np.asarray(net.route_length)[:, None]
    b = a + rng.random((r_n, 5)) * 30
    a[rng.random(a.shape) < 0.2] = np.nan
    b[rng.random(b.shape) < 0.1] = np.inf
    entry = net.yield_offset[:, None]
    return {
        "lanes": (starts, starts + net.lane_length[jnp.maximum(net.route_lanes, 0)]),
        "entry": (entry, entry + net.entry_internal_length[net.route_origin][:, None]),
        "through": (
            net.conflict_offset,
            net.conflict_offset + net.through_length[None, :],
        ),
        "random": (jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)),
    }


def test_rearmost_on_matches_all_pairs(case) -> None:
    env, params, states = case
    net, length = env.net, params.vehicle.length
    segments = _segments(net, seed=3)

    @jax.vmap
    def both(s):
        route, pos, active = s["route"], s["pos"], s["active"]
        tables = neighbours.build_tables(net, route, pos, active, length)
        front, back = _old_front_back(net, route, pos, length)
        out = {}
        for name, (a, b) in segments.items():
            new = neighbours.rearmost_on(tables, route, pos, active, a, b)
            old = allpairs.rearmost_on(front, back, pos, active, a[route], b[route])
            out[name] = (new, old)
        # the entry and the through lanes read from the table of the lanes
        lanes = neighbours.rearmost_on_lanes(net, tables, route, pos, active)
        out["lanes, read"] = (lanes, out["lanes"][1])
        out["entry, read"] = (neighbours.on_entry_lane(net, lanes), out["entry"][1])
        through = neighbours.on_through_lanes(net, lanes, route)
        out["through, read"] = (through, out["through"][1])
        return out

    for name, (new, old) in jax.jit(both)(states).items():
        assert bool(jnp.any(new[0])), f"{name}: no segment occupied, a weak test"
        _assert_same(new, old, f"rearmost on {name}")


def test_leaders_match_all_pairs(case) -> None:
    env, params, states = case
    net, length = env.net, params.vehicle.length

    @jax.vmap
    def both(s):
        route, pos, active = s["route"], s["pos"], s["active"]
        front, back = _old_front_back(net, route, pos, length)
        return [
            (leaders(x, pos, active, length), allpairs.leaders(x, pos, active, length))
            for x in (front, back + length)
        ]

    for new, old in jax.jit(both)(states):
        _assert_same(new, old, "leaders")
        assert bool(jnp.any(new[0] >= 0))


def phased_link_leader_speed(
    net, car, route, pos, speed, v_lane, active, may_drive_to_line, v_wait, dt,
    n_substeps, action_step, km_fixed, *, tables,
) -> tuple[jax.Array, jax.Array]:  # fmt: skip
    """`planning.link_leader_speed` with the all-pairs version's arguments."""
    ones = jnp.ones_like(pos)
    veh = planning.Vehicles(route, pos, speed, ones, active, 0.0 * ones)
    return planning.link_leader_speed(
        net, car, veh, v_lane, may_drive_to_line, v_wait,
        step=planning.Stepping(dt, n_substeps, action_step), tables=tables,
        km_fixed=km_fixed,
    )  # fmt: skip


def test_link_leaders_match_all_pairs(case) -> None:
    env, params, states = case
    net = env.net
    p = params.for_vehicles(jnp.zeros(M, bool))
    merges = (None, *net.merge_positions)

    @jax.vmap
    def both(s):
        route, pos, active, speed = s["route"], s["pos"], s["active"], s["speed"]
        tables = neighbours.build_tables(net, route, pos, active, p.length)
        out = []
        for km in merges:
            lead = link_leader(net, tables, route, pos, active, p.min_gap, km_fixed=km)
            is_link, gap, front_on, to_link = allpairs.link_leaders(
                net, route, pos, active, p.length, p.min_gap, km_fixed=km
            )
            gap = jnp.where(is_link, gap, jnp.inf)
            nearest = jnp.argmin(gap, axis=1)
            has = jnp.isfinite(jnp.min(gap, axis=1))
            old = (
                has,
                jnp.where(has, nearest, 0),
                jnp.where(has, jnp.min(gap, axis=1), 0.0),
                has & jnp.take_along_axis(front_on, nearest[:, None], 1)[:, 0],
                to_link,
            )
            new = (
                lead.has,
                lead.slot,
                jnp.where(lead.has, lead.gap, 0.0),
                lead.has & lead.front_on,
                lead.to_link,
            )
            v_lane = jnp.full(M, 13.0)
            speeds = [
                f(
                    net, p, route, pos, speed, v_lane, active, pos < 40.0,
                    v_lane / 2, env.dt, env.n_substeps, env.action_step, km,
                    **kw,
                )
                for f, kw in (
                    (phased_link_leader_speed, {"tables": tables}),
                    (allpairs.link_leader_speed, {}),
                )
            ]  # fmt: skip
            out.append((new, old, *speeds))
        return out

    found = 0
    for new, old, v_new, v_old in jax.jit(both)(states):
        _assert_same(new, old, "link leader")
        _assert_same(v_new, v_old, "link leader speed")
        found += int(jnp.sum(new[0]))
    assert found > 0


def test_observations_match_all_pairs(case) -> None:
    env, params, states = case
    net = env.net
    _, template = jax.jit(env.reset)(jax.random.PRNGKey(0), params)

    @jax.vmap
    def both(s):
        state = template.replace(**s, is_av=s["active"])
        dest = env.route_destination
        return (
            observe.paper_observation(net, state, params),
            observe.rich_observation(net, state, params, dest),
        ), (
            allpairs.paper_observation(net, state, params),
            allpairs.rich_observation(net, state, params, dest),
        )

    new, old = jax.jit(both)(states)
    _assert_same(new, old, "observations")
