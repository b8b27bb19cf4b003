"""Lane changes in the roundabout step: LC2013 after every move.

SUMO's ``MSNet::simulationStep`` moves every vehicle
(``MSEdgeControl::executeMovements``, arrivals leave), then changes lanes
(``MSEdgeControl::changeLanes``), then inserts. `LaneChanger` is that middle
phase for a roundabout with two-lane roads: every vehicle's LC2013 memory
is reset for the step (``MSLCM_LC2013::prepareStep``, at the end of
``executeMove``), then `jaxround.lanes.ring_batches` (one vehicle after
another: the default, cheaper on a CPU and on a GPU from a few thousand
roundabouts a batch) or `jaxround.lanes.ring_rounds` (all at once in
rounds, the same changes: cheaper on a GPU up to about 1,000 roundabouts
a batch; docs/benchmarks.md) moves vehicles between lane
paths, which are the step's routes (`jaxround.lanes.ring_network`). A
change onto the other entry lane is held back as SUMO 1.28 holds it, while
that lane's entry link would be closed to the vehicle's own approach
(`jaxround.lanes.entry_hold`); a vehicle about to merge ahead on the
target lane leads as SUMO's changer finds it (`jaxround.lanes.merge_leaders`).

Shapes: M vehicle slots, N scheduled vehicles.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
from flax import struct

from jaxround.core.crossing_leaders import conflict_clock
from jaxround.core.dynamics import SpeedPatch
from jaxround.core.geometry import NetArrays
from jaxround.core.junction import Approach
from jaxround.core.network import CompiledNetwork
from jaxround.core.params import CarFollowing
from jaxround.core.state import EnvState
from jaxround.envs.lane_view import lane_request
from jaxround.lanes import active_lanes, ring_batches, ring_changer, ring_rounds
from jaxround.lanes.active_lanes import TurnOrder
from jaxround.lanes.best_lanes import LookAheadDriver
from jaxround.lanes.blockers import blocker_stop_speed
from jaxround.lanes.entry_hold import (
    held_by_approaching,
    held_by_occupied,
    held_by_parallel_link,
)
from jaxround.lanes.follow import Driver
from jaxround.lanes.memory import patch_speed, prepare_step
from jaxround.lanes.merge_leaders import merge_leaders
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.ring_network import compile_lane_network
from jaxround.lanes.ring_tables import RingLanes, ring_lanes
from jaxround.lanes.views import Memory
from jaxround.scenario.config import DriverConfig, ScenarioConfig
from jaxround.sumo_files.compile import compile_network

#: `LaneChanger`'s choices for the hold at entries.
HOLD_MODES = ("parallel", "off", "occupied", "approaching")


@struct.dataclass
class LaneState:
    """What lane changing keeps from step to step.

    Attributes:
        memory: LC2013's `Memory` of each slot (M, ...).
        changes: int (N,) lane changes each scheduled vehicle made.
        lane_seconds: float (L,) vehicle-seconds on each lane (a vehicle
            counts on the lane of its front after the step's changes), as
            SUMO's lane data (``--lanedata-output``) sums ``sampledSeconds``.
        conflict_clock: float (M,) when each front entered the internal lane
            that leaves its junction (+inf elsewhere), kept only where
            internal lanes cross (`jaxround.core.crossing_leaders`).
        lane_stamp: int32 (L,) each lane's place in SUMO's list of active
            lanes, which orders the edges' turns (`jaxround.lanes.active_lanes`;
            0: not in it).
    """

    memory: Memory
    changes: jax.Array
    lane_seconds: jax.Array
    conflict_clock: jax.Array
    lane_stamp: jax.Array

    @classmethod
    def zeros(cls, m: int, n: int, n_lanes: int) -> LaneState:
        return cls(
            Memory.zeros(m), jnp.zeros(n, jnp.int32),
            jnp.zeros(n_lanes, jnp.float32), jnp.full(m, jnp.inf, jnp.float32),
            jnp.zeros(n_lanes, jnp.int32),
        )  # fmt: skip


def driver_numbers(d: DriverConfig) -> Driver:
    """A vType's car-following numbers as the lane changer reads them."""
    return Driver(d.accel, d.decel, d.emergency_decel, d.tau, d.min_gap, d.length,
                  d.delta, d.max_speed)  # fmt: skip


def car_driver(car: CarFollowing, shape: tuple[int, ...]) -> Driver:
    """The changer's `Driver` of the step's car-following numbers, each
    field broadcast to ``shape`` (the slots, (M,))."""

    def full(x: jax.Array) -> jax.Array:
        return jnp.broadcast_to(jnp.asarray(x, jnp.float32), shape)

    return Driver(
        accel=full(car.accel), decel=full(car.decel),
        emergency_decel=full(car.emergency_decel), tau=full(car.tau),
        min_gap=full(car.min_gap), length=full(car.length), delta=full(car.delta),
        max_speed=full(car.max_speed),
    )  # fmt: skip


def changer_tables(cfg: ScenarioConfig, net_file: str | Path) -> RingLanes:
    """The changer's tables of a scenario's network (`ring_tables`), with
    the human drivers' look-ahead."""
    driver = LookAheadDriver.from_config(cfg.drivers.hv, cfg.simulation.dt_s)
    return ring_lanes(net_file, driver)


def changer_arrays(cfg: ScenarioConfig, tables: RingLanes) -> ring_changer.RingArrays:
    """The changer's arrays for a scenario's vTypes (SUMO's followers'
    search: the smallest of the decelerations and SUMO's default, 4.5)."""
    min_decel = min(cfg.drivers.hv.decel, cfg.drivers.av.decel, 4.5)
    return ring_changer.RingArrays.from_tables(tables, min_decel)


def compiled_network(
    cfg: ScenarioConfig, net_file: str | Path, crossing_leaders: bool = True
) -> tuple[CompiledNetwork, LaneChanger | None]:
    """The step's network of a scenario, and its lane changer where a road has
    two lanes (routes are then lane paths: `jaxround.lanes.ring_network`);
    the crossings' link leaders unless `crossing_leaders` is False."""
    if cfg.network.single_lane:
        return compile_network(net_file, cfg.n_legs), None
    network, _ = compile_lane_network(net_file, cfg.n_legs)
    if not crossing_leaders:
        network = dataclasses.replace(network, crossings=None)
    return network, LaneChanger(cfg, net_file)


class LaneChanger:
    """The lane-change phase of a two-lane roundabout's step (static).

    Args:
        cfg: the scenario.
        net_file: its `.net.xml` (the paths' numbering is `lane_paths`').
        in_rounds: `ring_rounds` instead of the turns one by one (the same
            changes; on an H200 twice as fast at batch 1,024, three times
            slower at 65,536: docs/benchmarks.md). May be set on the
            instance before the step is traced.
        hold_entries: how a change onto the other entry lane is held back
            (`jaxround.lanes.entry_hold`): ``"parallel"`` (the default) as
            SUMO 1.28 does, while that lane's entry link would be closed to
            the vehicle's own approach; ``"off"``: never; ``"occupied"``
            and ``"approaching"``: two earlier readings, kept for
            comparison (figures in that module).
        merge_leaders: the vehicles about to merge ahead on the target
            lane lead a change as SUMO's changer finds them
            (`jaxround.lanes.merge_leaders`); False leaves them out.
    """

    def __init__(
        self,
        cfg: ScenarioConfig,
        net_file: str | Path,
        in_rounds: bool = False,
        hold_entries: str = "parallel",
        merge_leaders: bool = True,
    ) -> None:
        if hold_entries not in HOLD_MODES:
            raise ValueError(
                f"hold_entries={hold_entries!r}: expected one of {HOLD_MODES}"
            )
        tables = changer_tables(cfg, net_file)
        self.paths = tables.paths
        self.arrays = changer_arrays(cfg, tables)
        self.hv = driver_numbers(cfg.drivers.hv)
        self.av = driver_numbers(cfg.drivers.av)
        self.dt = cfg.simulation.dt_s
        self.in_rounds = in_rounds
        self.hold_entries = hold_entries
        self.merge_leaders = merge_leaders
        self.turn_order = TurnOrder.of(net_file, self.paths.lane_ids, self.arrays)

    def request(
        self,
        state: EnvState,
        lane_action: jax.Array,
        agent: jax.Array,
        car: CarFollowing,
    ) -> jax.Array:
        """int (M,) the lane index each AV's action asks for in this step's
        changes (-1: none), from ``state`` before the move, where the move
        (at most ``car.accel`` more speed) keeps the AV off a junction
        (`jaxround.envs.lane_view.lane_request`)."""
        reach = (state.speed + car.accel * self.dt) * self.dt
        return lane_request(self.arrays, state, lane_action, agent, reach)

    def patch(
        self, state: EnvState, lc: LaneChangeParams, car: CarFollowing | None = None
    ) -> SpeedPatch:
        """``MSLCM_LC2013::patchSpeed`` for the next move: the room kept for
        a blocker, the speed advices and the wishes the last lane changes
        left in the memory (``car`` as in `vehicles`)."""
        memory = state.lanes.memory
        driver = self._driver(state, car)
        v = state.speed
        _, lane, _ = ring_changer.locate(self.arrays, state.route, state.pos)
        v_desired = jnp.minimum(
            driver.max_speed, self.arrays.lane_speed[lane] * state.speed_factor
        )
        blocker = blocker_stop_speed(memory, driver, v, v_desired, self.dt)

        def patched(v_min: jax.Array, v_max: jax.Array) -> jax.Array:
            return patch_speed(
                memory, v_min, v_max, v_max, lc.cooperative, blocker=blocker
            )

        return patched

    def _driver(self, state: EnvState, car: CarFollowing | None) -> Driver:
        """Each slot's `Driver`: the step's numbers ``car``, or its class's."""
        if car is None:
            return jax.tree.map(
                lambda h, a: jnp.where(state.is_av, a, h), self.hv, self.av
            )
        return car_driver(car, state.active.shape)

    def vehicles(
        self,
        state: EnvState,
        request: jax.Array | None = None,
        hold: jax.Array | None = None,
        merge: ring_changer.MergeLeaders | None = None,
        car: CarFollowing | None = None,
    ) -> tuple[ring_changer.RingVehicles, Memory]:
        """The changer's view of ``state`` after the move, and the memory
        reset for the step (``prepareStep``; an empty slot's cleared);
        ``hold`` and ``merge`` as `RingVehicles.entry_hold` and
        `RingVehicles.merge`. Each vehicle's car-following numbers are the
        step's, ``car`` (`EnvParams.for_vehicles`, with any retuning of the
        step), as SUMO's LC2013 reads the vehicle's own (a TraCI ``setTau``
        included); without it, its class's vType in the scenario."""
        active = state.active
        memory = jax.tree.map(
            lambda x, z: jnp.where(active.reshape(-1, *([1] * (x.ndim - 1))), x, z),
            prepare_step(state.lanes.memory), Memory.zeros(active.shape[0]),
        )  # fmt: skip
        driver = self._driver(state, car)
        departed = jnp.where(state.inserted, state.schedule.speed_factor, 1.0)
        veh = ring_changer.RingVehicles(
            path=state.route, pos=state.pos, speed=state.speed, accel=state.accel,
            active=active, driver=driver, speed_factor=state.speed_factor,
            lane_request=request, entry_hold=hold, merge=merge,
            fastest_departed=jnp.maximum(jnp.max(departed), 1.0),
        )  # fmt: skip
        return veh, memory

    def holds(
        self,
        state: EnvState,
        net: NetArrays,
        car: CarFollowing,
        own_entry: Approach | None = None,
    ) -> jax.Array:
        """bool (M, 2): where a change right / left would be held back at the
        target lane's entry (`jaxround.lanes.entry_hold`), from ``state``
        after the move: SUMO 1.28's test of the target lane's entry link
        against each vehicle's own approach (``own_entry``) under
        ``hold_entries="parallel"``; otherwise the occupied foe lanes, and
        the registered foes too under ``"approaching"`` (whatever the mode,
        the step uses this only when the mode is not ``"off"``)."""
        if self.hold_entries == "parallel":
            if own_entry is None:
                raise ValueError('hold_entries="parallel" needs own_entry')
            t = (state.step - 1).astype(jnp.float32) * self.dt  # the step's start
            return held_by_parallel_link(
                net, self.arrays, car, state.route, state.pos, state.active,
                state.waiting_s, state.registrations, own_entry, t, self.dt,
            )  # fmt: skip
        held = held_by_occupied(
            net, self.arrays, state.route, state.pos, car.length, state.active
        )
        if self.hold_entries == "approaching":
            t = state.step.astype(jnp.float32) * self.dt
            held = held | held_by_approaching(
                net, self.arrays, car, state.route, state.pos, state.speed,
                state.speed_factor, state.active, state.registrations, t, self.dt,
            )  # fmt: skip
        return held

    def __call__(
        self,
        state: EnvState,
        lc: LaneChangeParams,
        request: jax.Array | None = None,
        net: NetArrays | None = None,
        car: CarFollowing | None = None,
        own_entry: Approach | None = None,
    ) -> tuple[EnvState, jax.Array]:
        """Change lanes after the move (arrivals gone, insertions not yet).

        Args:
            state: after the move; ``state.lanes`` a `LaneState`,
                ``state.registrations`` the step's.
            lc: the lane-change parameters (scalars or (M,)).
            request: int (M,) a lane index TraCI asks for (-1: none), or None.
            net, car: the step's network and each vehicle's car-following
                numbers, for the hold at entries and the merges' link
                leaders (None: neither).
            own_entry: each vehicle's approach to its own entry link, as the
                step registered it (`jaxround.core.dynamics.Planned`), for
                the hold of ``hold_entries="parallel"``.

        Returns:
            (state, direction): the state on its new paths, and int (M,)
            -1 / 0 / +1 each slot changed right, not, left.
        """
        lanes: LaneState = state.lanes
        active = state.active
        hold = None
        if self.hold_entries != "off" and net is not None and car is not None:
            hold = self.holds(state, net, car, own_entry)
        merge = None
        if self.merge_leaders and net is not None and car is not None:
            merge = merge_leaders(
                net, self.arrays, car, state.route, state.pos, state.speed,
                active, self.dt,
            )  # fmt: skip
        veh, memory = self.vehicles(state, request, hold, merge, car)
        stamp, arrays = self.turn_order.before_changes(
            lanes.lane_stamp, path=state.route, pos=state.pos, speed=state.speed,
            active=active, dt=self.dt,
        )  # fmt: skip
        if self.in_rounds:
            result, memory, _ = ring_rounds.change_lanes(
                arrays, veh, memory, lc, self.dt
            )
        else:
            result, memory = ring_batches.change_lanes(arrays, veh, memory, lc, self.dt)
        changed = active & (result.direction != 0)
        n = lanes.changes.shape[0]
        vid = jnp.where(changed, state.vid, n)  # out of range: dropped
        seconds = lanes.lane_seconds.at[result.lane].add(
            jnp.where(active, self.dt, 0.0)
        )
        route = jnp.where(active, result.path, state.route)
        pos = jnp.where(active, result.pos, state.pos)
        clock = lanes.conflict_clock
        if net is not None and net.crossing is not None:
            t = (state.step - 1).astype(jnp.float32) * self.dt  # the step's start
            clock = conflict_clock(net, route, pos, active, clock, t)
        changes = lanes.changes.at[vid].add(1, mode="drop")
        stamp = active_lanes.after_changes(
            self.arrays, stamp, arrays.lane_order, result.lane, active
        )
        return state.replace(
            route=route, pos=pos,
            lanes=LaneState(memory, changes, seconds, clock, stamp),
        ), jnp.where(active, result.direction, 0)  # fmt: skip

    @staticmethod
    def junction_order(
        state: EnvState, net: NetArrays
    ) -> tuple[jax.Array, jax.Array] | None:
        """`dynamics.planned_speed`'s ``junction_order``: (clock, vid) where
        internal lanes cross, None elsewhere."""
        return None if net.crossing is None else (state.lanes.conflict_clock, state.vid)
