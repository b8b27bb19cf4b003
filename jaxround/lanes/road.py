"""A straight multi-lane road driven by SUMO's IDM and LC2013: the testbed.

One edge of one or two lanes; each vehicle has a route that leads on from
some of its lanes (the others end for it) and leaves the road at its end.
A step follows `MSNet::simulationStep`: every vehicle plans its speed from
the state at the start of the step (the IDM behind its lane's leader, a
stop at the end of a lane that does not lead on, the lane-change advices
of the previous step in `patchSpeed`), all move at once (Euler), vehicles
past the end leave, LC2013's memory is reset (`prepareStep`), the lane
changer runs (`jaxround.lanes.changer`), and scheduled vehicles enter.

Limits: speeds under 60 km/h (LC2013's rules against overtaking on the right
and for highway on-ramps start there and are not ported), no junction at
the road's end, vehicles enter where they are told without SUMO's
insertion checks.

Shapes: M vehicle slots, Z lanes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.typing import ArrayLike

from jaxround.core import finalize, idm
from jaxround.lanes.changer import Changes, EdgeView, change_lanes
from jaxround.lanes.follow import Driver
from jaxround.lanes.memory import patch_speed, prepare_step
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.views import Memory

#: Below this (m/s, 60 km/h) every vehicle is "congested" for LC2013.
CONGESTED_SPEED = 60.0 / 3.6


@dataclass(frozen=True)
class Road:
    """The road's static layout (its length is traced: `Traffic.road_length`).

    Attributes:
        n_lanes: 1 or 2.
        speed_limit: m/s, below 60 km/h.
        dt: step length (s).
    """

    n_lanes: int
    speed_limit: float
    dt: float = 1.0

    def __post_init__(self) -> None:
        if self.n_lanes not in (1, 2):
            raise ValueError(f"Road.n_lanes: {self.n_lanes}, expected 1 or 2")
        if not 0 < self.speed_limit < CONGESTED_SPEED:
            raise ValueError(
                f"Road.speed_limit: {self.speed_limit} m/s; LC2013 is ported for "
                f"speeds under {CONGESTED_SPEED:.2f} m/s (60 km/h) only"
            )
        if self.dt <= 0:
            raise ValueError(f"Road.dt: {self.dt}, must be > 0")


@struct.dataclass
class Traffic:
    """The vehicles on the road, (M,) each unless said.

    Attributes:
        pos, speed, accel: front position (m), speed (m/s), last acceleration.
        lane: int lane index (0 rightmost).
        active: bool, on the road.
        depart_step: int, the step at whose end the vehicle enters.
        depart_pos, depart_speed, depart_lane: where and how it enters.
        driver: `Driver` of (M,) arrays.
        leads_on: bool (M, Z), whether each lane leads on along its route.
        beyond: metres of its route after the road (0: it ends at the road's end).
        road_length: the road's length (m), a scalar: roads of any length
            share one compilation.
        memory: its LC2013 memory.
    """

    pos: jax.Array
    speed: jax.Array
    accel: jax.Array
    lane: jax.Array
    active: jax.Array
    depart_step: jax.Array
    depart_pos: jax.Array
    depart_speed: jax.Array
    depart_lane: jax.Array
    driver: Driver
    leads_on: jax.Array
    beyond: jax.Array
    road_length: jax.Array
    memory: Memory


class StepRecord(NamedTuple):
    """One step's outcome, (M,) each: after the move and the changes
    (`change_state`: the bits a vehicle changed with; `state`: LC2013's
    state and probabilities as SUMO's libsumo reads them after the step)."""

    pos: jax.Array
    speed: jax.Array
    lane: jax.Array
    active: jax.Array
    change_direction: jax.Array
    change_state: jax.Array
    state: jax.Array
    speed_gain_probability: jax.Array
    keep_right_probability: jax.Array


def default_driver(n: int, max_speed: ArrayLike = 55.55) -> Driver:
    """SUMO's default passenger vType with the IDM (accel 2.6, decel 4.5,
    emergencyDecel 9, tau 1, minGap 2.5, length 5, delta 4), (n,) each."""
    dtype = jnp.result_type(float)
    full = lambda x: jnp.full(n, x, dtype)  # noqa: E731
    return Driver(
        accel=full(2.6), decel=full(4.5), emergency_decel=full(9.0), tau=full(1.0),
        min_gap=full(2.5), length=full(5.0), delta=full(4.0),
        max_speed=jnp.broadcast_to(jnp.asarray(max_speed, dtype), (n,)),
    )  # fmt: skip


def traffic(
    *,
    depart_pos: np.ndarray,
    depart_speed: np.ndarray,
    depart_lane: np.ndarray,
    leads_on: np.ndarray,
    driver: Driver,
    road_length: float,
    depart_step: np.ndarray | None = None,
    beyond: np.ndarray | None = None,
) -> Traffic:
    """Vehicles that enter at the end of ``depart_step`` (default 0), their
    routes ending ``beyond`` metres after the road (default 0), (M,) each,
    on a road of ``road_length`` m."""
    if not road_length > 0:
        raise ValueError(f"road_length: {road_length} m, must be > 0")
    m = len(depart_pos)
    depart_step = np.zeros(m, np.int32) if depart_step is None else depart_step
    f = lambda x: jnp.asarray(x, jnp.result_type(float))  # noqa: E731
    entered = jnp.asarray(depart_step) <= 0
    return Traffic(
        pos=jnp.where(entered, f(depart_pos), 0.0),
        speed=jnp.where(entered, f(depart_speed), 0.0),
        accel=jnp.zeros(m, jnp.result_type(float)),
        lane=jnp.asarray(depart_lane, jnp.int32),
        active=entered,
        depart_step=jnp.asarray(depart_step, jnp.int32),
        depart_pos=f(depart_pos),
        depart_speed=f(depart_speed),
        depart_lane=jnp.asarray(depart_lane, jnp.int32),
        driver=driver,
        leads_on=jnp.asarray(leads_on, bool),
        beyond=f(np.zeros(m) if beyond is None else beyond),
        road_length=f(road_length),
        memory=Memory.zeros(m),
    )


def _lane_tables(
    road: Road, length_m: jax.Array, leads_on: jax.Array, beyond: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Each vehicle's LaneQ length and best-lane offset per lane, (M, Z):
    a lane that leads on counts the road and the route beyond it (up to
    SUMO's look-ahead of 3,000 m), one that does not only the road."""
    beyond_road = jnp.minimum(length_m + beyond[:, None], 3000.0)
    length = jnp.where(leads_on, beyond_road, length_m)
    lanes = jnp.arange(road.n_lanes)
    best = length >= jnp.max(length, axis=1, keepdims=True)  # (M, Z)
    apart = jnp.abs(lanes[:, None] - lanes[None, :])  # (Z, Z)
    distance = jnp.where(best[:, None, :], apart[None], 99)  # (M, Z, Z)
    nearest_best = jnp.argmin(distance, axis=2)  # (M, Z)
    return length, (nearest_best - lanes[None, :]).astype(jnp.int32)


def step(
    road: Road, state: Traffic, lc: LaneChangeParams, step_index: jax.Array
) -> tuple[Traffic, StepRecord]:
    """One step of the road (see the module's docstring for the order)."""
    dt, m = road.dt, state.pos.shape[0]
    driver, v, pos = state.driver, state.speed, state.pos
    v_max_lane = jnp.minimum(road.speed_limit, driver.max_speed)  # (M,)
    # 1. plan: the leader on the lane, a lane that ends, the advices
    same_lane = state.lane[:, None] == state.lane[None, :]
    ahead = (pos[None, :] > pos[:, None]) & same_lane & state.active[None, :]
    gap = pos[None, :] - driver.length[None, :] - pos[:, None] - driver.min_gap[:, None]
    gap = jnp.where(ahead, gap, jnp.inf)  # (M, M)
    lead = jnp.argmin(gap, axis=1)
    has_lead = jnp.isfinite(gap[jnp.arange(m), lead])
    n_sub = idm.idm_substeps(dt)
    v_follow = idm.idm_follow_speed(
        v, v[lead], gap[jnp.arange(m), lead] + driver.min_gap, v_max_lane,
        vtype=driver.idm, dt=dt, n_substeps=n_sub,
    )  # fmt: skip
    v_free = idm.idm_free_speed(
        v, v_max_lane, vtype=driver.idm, dt=dt, n_substeps=n_sub
    )
    ends = ~jnp.take_along_axis(state.leads_on, state.lane[:, None], axis=1)[:, 0]
    v_stop = idm.idm_stop_speed(
        v,
        state.road_length - pos,
        v_max_lane,
        vtype=driver.idm,
        dt=dt,
        n_substeps=n_sub,
    )
    v_safe = jnp.minimum(jnp.where(has_lead, v_follow, jnp.inf), v_free)
    v_safe = jnp.where(ends, jnp.minimum(v_safe, v_stop), v_safe)
    # MSCFModel::finalizeSpeed's bounds, then MSLCM_LC2013::patchSpeed
    v_min, v_top = finalize.speed_bounds(
        v, v_safe, v_max_lane, accel=driver.accel, decel=driver.decel,
        emergency_decel=driver.emergency_decel, dt=dt, action_step=dt,
    )  # fmt: skip
    v_top = jnp.maximum(v_min, v_top)
    v_next = patch_speed(state.memory, v_min, v_top, v_top, lc.cooperative)
    v_next = jnp.where(state.active, finalize.snap_speed(v_next, dt), 0.0)
    # 2. move, 3. leave at the end
    pos = jnp.where(state.active, pos + v_next * dt, pos)
    accel = (v_next - v) / dt
    active = state.active & (pos <= state.road_length)
    # 4. prepareStep, 5. the lane changer
    memory = prepare_step(state.memory)
    length, offset = _lane_tables(road, state.road_length, state.leads_on, state.beyond)
    edge = EdgeView(
        pos=pos, speed=v_next, accel=accel, lane=state.lane, active=active,
        driver=driver, v_max=jnp.broadcast_to(v_max_lane[:, None], (m, road.n_lanes)),
        speed_limit=jnp.full(road.n_lanes, road.speed_limit, jnp.result_type(float)),
        lane_length=jnp.full(road.n_lanes, state.road_length),
        laneq_length=length, laneq_offset=offset,
        next_occupation=jnp.zeros((m, road.n_lanes), jnp.result_type(float)),
        ends_in_links=~state.leads_on,
    )  # fmt: skip
    changes, memory = change_lanes(edge, memory, lc, dt)
    # 6. insertion
    enters = state.depart_step == step_index
    state = state.replace(
        pos=jnp.where(enters, state.depart_pos, pos),
        speed=jnp.where(enters, state.depart_speed, v_next),
        accel=jnp.where(enters, 0.0, accel),
        lane=jnp.where(enters, state.depart_lane, changes.lane),
        active=active | enters,
        memory=memory,
    )
    record = StepRecord(
        pos=state.pos, speed=state.speed, lane=state.lane, active=state.active,
        change_direction=changes.direction, change_state=changes.state,
        state=memory.state, speed_gain_probability=memory.speed_gain_probability,
        keep_right_probability=memory.keep_right_probability,
    )  # fmt: skip
    return state, record


def simulate(
    road: Road, state: Traffic, lc: LaneChangeParams, n_steps: int
) -> tuple[Traffic, StepRecord]:
    """Steps 1..n_steps after the insertion step 0; records stacked (T, M)."""

    def body(carry: Traffic, index: jax.Array):
        return step(road, carry, lc, index)

    return jax.lax.scan(body, state, jnp.arange(1, n_steps + 1))


__all__ = [
    "Changes", "Road", "StepRecord", "Traffic", "default_driver", "simulate", "step",
    "traffic",
]  # fmt: skip
