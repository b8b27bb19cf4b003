"""SUMO's vehicles as the JAX environment's vehicle slots, and what they see.

`SumoObserver.read` takes every vehicle in the network from libsumo (lane,
position on the lane, speed, acceleration, waiting time) into slots: a
vehicle's position along its route is where its lane starts on the route
(`CompiledNetwork.lane_offset`) plus its position on the lane, as the JAX
environment counts it. On two-lane roads a route is a lane path, which
`jaxround.lanes.tracking.PathTracker` follows from SUMO's lanes step by
step. `SumoObserver.observe` computes the rows with the
environment's own jitted observer (`RoundaboutEnv.observation`).

The observers' rows do not depend on how many empty slots follow the
occupied ones, so the observer is compiled for a few slot counts (32, 64,
... up to ``max_slots``) and each step uses the smallest that holds the
traffic: its cost grows with the slots.

Time alignment: after the SUMO step that ends at time t, SUMO holds the
state the JAX environment holds at time t - dt (SUMO inserts the vehicles
departing at t - dt at the end of that step, JAX at the end of its step to
t - dt).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs.observe import OBSERVATION_SIZES
from jaxround.envs.roundabout import RoundaboutEnv, make
from jaxround.envs.slots import ROAD
from jaxround.lanes.tracking import PathTracker
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import Schedule
from sumo_export.scenario import vehicle_id

#: Columns of the packed state handed to the jitted observer.
COLUMNS = ("active", "route", "pos", "speed", "accel", "waiting_s", "is_av")
#: Vehicle slots by default: what the road holds (`jaxround.core.capacity`),
#: so every vehicle in SUMO has one whatever the traffic (each step still
#: uses the smallest of `slot_sizes` that holds its vehicles).
DEFAULT_SLOTS: int | str | None = ROAD
#: Smallest slot count the observer is compiled for.
MIN_SLOTS = 32
#: A vehicle's path once it was found off the lane paths: it stays unslotted.
OFF_PATH = -1


@dataclass
class SumoTraffic:
    """The vehicles in SUMO after a step, in slots (SUMO's id order).

    Attributes:
        ids: SUMO ids of the n occupied slots (the first n).
        packed: float32 (S, 7), S >= n slots; columns `COLUMNS`, zero rows
            for empty slots.
        speed: float64 (n,) speeds as SUMO holds them.
        unslotted: ids of the vehicles in the network that found no slot.
        lane_ids: SUMO lane ids of the n occupied slots' vehicles.
        lane_pos: float64 (n,) their positions on those lanes (m).
    """

    ids: list[str]
    packed: np.ndarray
    speed: np.ndarray
    unslotted: list[str]
    lane_ids: list[str] = dataclasses.field(default_factory=list)
    lane_pos: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    @property
    def n(self) -> int:
        return len(self.ids)

    @property
    def n_av(self) -> int:
        return int(np.count_nonzero(self.column("is_av")))

    def column(self, name: str) -> np.ndarray:
        """One column of `packed`, float32 (S,)."""
        return self.packed[:, COLUMNS.index(name)]


class SumoObserver:
    """Reads SUMO's vehicles into slots and computes their observation rows.

    Args:
        cfg: the scenario.
        schedule: the schedule SUMO runs (routes and classes of its vehicles).
        observer: the observer's name (`jaxround.envs.observe`).
        max_slots: vehicle slots M (`DEFAULT_SLOTS`: the road's; None: the
            config's, else what the traffic needs); vehicles beyond
            them get no slot and are counted in `overflow_vehicle_steps`.
        strict: raise OverflowError instead of counting when the slots overflow.

    Attributes:
        overflow_vehicle_steps: vehicle-steps without a slot.
        off_path_vehicle_steps: vehicle-steps of vehicles found off the lane
            paths (two-lane roads; after a teleport, say), which get no slot
            from then on and drive uncontrolled.
    """

    def __init__(
        self,
        cfg: ScenarioConfig,
        schedule: Schedule,
        observer: str,
        max_slots: int | str | None = DEFAULT_SLOTS,
        strict: bool = False,
    ) -> None:
        if observer not in OBSERVATION_SIZES:
            raise ValueError(
                f"observer {observer!r}, expected one of {sorted(OBSERVATION_SIZES)}"
            )
        cfg = dataclasses.replace(
            cfg, agent=dataclasses.replace(cfg.agent, observer=observer)
        )
        self.env, self.params = make(cfg, max_vehicles=max_slots)
        self.strict = strict
        net, changer = self.env.network, self.env.lane_changer
        self._lane_index = {lane: k for k, lane in enumerate(net.lane_ids)}
        self._lane_offset = net.lane_offset
        # two-lane roads: routes are lane paths, which a tracker follows
        self._paths = None if changer is None else changer.paths
        self.use_schedule(schedule)
        self.slot_sizes = slot_sizes(self.env.max_vehicles)
        self._observers = {
            size: observation_function(
                RoundaboutEnv(cfg, net, size, self.env.episode_s, changer),
                self.params,
            )
            for size in self.slot_sizes
        }
        for size, fn in self._observers.items():  # compile now, not in a step
            fn(np.zeros((size, len(COLUMNS)), np.float32)).block_until_ready()
        self.overflow_vehicle_steps = 0
        self.off_path_vehicle_steps = 0

    @property
    def max_slots(self) -> int:
        return self.env.max_vehicles

    def use_schedule(self, schedule: Schedule) -> None:
        """Read the vehicles of `schedule` from now on (routes and classes by
        SUMO id); the compiled observers stay.

        Raises:
            ValueError: the schedule has another number of vehicles than the
                scenario.
        """
        n = self.env.n_schedule
        if schedule.n_vehicles != n:
            raise ValueError(
                f"schedule has {schedule.n_vehicles} vehicles, the scenario {n}"
            )
        net = self.env.network
        route = net.route_index[schedule.origin, schedule.destination]
        # per SUMO id: (route, is_av)
        self._vehicles = {
            vehicle_id(i): (int(r), bool(a))
            for i, (r, a) in enumerate(zip(route, schedule.is_av, strict=True))
        }
        self._tracker = None
        if self._paths is not None:  # route: the (origin, exit) route's index
            self._tracker = PathTracker(self._paths)
            od = self._paths.route_index[schedule.origin, schedule.destination]
            self._od_route = {vehicle_id(i): int(r) for i, r in enumerate(od)}

    def read(self, libsumo: Any) -> SumoTraffic:
        """The vehicles in the network after a step, in slots (SUMO's id order).

        Raises:
            OverflowError: more vehicles than slots, with `strict`.
        """
        veh = libsumo.vehicle
        m = self.max_slots
        ids, unslotted, off_path, lane_ids = [], [], [], []
        lanes, routes, avs = [], [], []
        lane_pos, speed, accel, waiting = [], [], [], []
        tracker = self._tracker
        all_ids = veh.getIDList()
        for vid in all_ids:
            lane_id = veh.getLaneID(vid)
            lane = self._lane_index.get(lane_id)
            if lane is None:  # teleporting: not on a lane
                continue
            route, is_av = self._vehicles[vid]
            if tracker is not None:
                try:  # off the lane paths (after a teleport, say): uncontrolled
                    if tracker.state.get(vid) == OFF_PATH:
                        raise ValueError(vid)
                    route = tracker.step(vid, lane_id, self._od_route[vid])[1]
                except ValueError:
                    tracker.state[vid] = OFF_PATH
                    off_path.append(vid)
                    continue
            if len(ids) == m:
                unslotted.append(vid)
                continue
            ids.append(vid)
            lane_ids.append(lane_id)
            lanes.append(lane)
            routes.append(route)
            avs.append(is_av)
            lane_pos.append(veh.getLanePosition(vid))
            speed.append(veh.getSpeed(vid))
            accel.append(veh.getAcceleration(vid))
            waiting.append(veh.getWaitingTime(vid))
        if unslotted:
            if self.strict:
                raise OverflowError(
                    f"{len(ids) + len(unslotted)} vehicles in SUMO, {m} slots; "
                    "raise max_slots"
                )
            self.overflow_vehicle_steps += len(unslotted)
        if tracker is not None:
            tracker.forget(set(all_ids))
            self.off_path_vehicle_steps += len(off_path)
            unslotted += off_path
        n = len(ids)
        size = next(s for s in self.slot_sizes if s >= n)
        table = np.zeros((len(COLUMNS), size), np.float64)
        table[:, :n] = (
            np.ones(n),
            routes,
            self._lane_offset[routes, lanes] + np.asarray(lane_pos),
            speed,
            accel,
            waiting,
            avs,
        )
        return SumoTraffic(
            ids=ids,
            packed=table.T.astype(np.float32),
            speed=np.asarray(speed, np.float64),
            unslotted=unslotted,
            lane_ids=lane_ids,
            lane_pos=np.asarray(lane_pos, np.float64),
        )

    def observe(self, traffic: SumoTraffic) -> np.ndarray:
        """The observer's rows, float32 (S, D) for the S slots of `traffic`."""
        packed = traffic.packed
        return np.asarray(self._observers[packed.shape[0]](packed))


def slot_sizes(max_slots: int) -> tuple[int, ...]:
    """Slot counts the observer is compiled for: 32, 64, ... below `max_slots`,
    and `max_slots` itself."""
    if max_slots < 1:
        raise ValueError(f"max_slots: {max_slots}, expected >= 1")
    sizes = []
    size = MIN_SLOTS
    while size < max_slots:
        sizes.append(size)
        size *= 2
    return (*sizes, max_slots)


def observation_function(
    env: RoundaboutEnv, params: EnvParams
) -> Callable[[np.ndarray], jax.Array]:
    """The environment's jitted observer on a packed float32 (M, 7) state.

    Only the fields the observers read are filled (`COLUMNS`); the rest of
    the `EnvState` is zeros of the right shapes, which the compiled function
    never reads. Returns float (M, D).
    """
    template = zero_state(env, params)

    def observe(packed: jax.Array) -> jax.Array:
        col = {name: packed[:, k] for k, name in enumerate(COLUMNS)}
        state = template.replace(
            active=col["active"] > 0.5,
            route=col["route"].astype(jnp.int32),
            pos=col["pos"],
            speed=col["speed"],
            accel=col["accel"],
            waiting_s=col["waiting_s"],
            is_av=col["is_av"] > 0.5,
        )
        return env.observation(state, params)

    return jax.jit(observe)


def zero_state(env: RoundaboutEnv, params: EnvParams) -> EnvState:
    """An `EnvState` of zeros with the environment's shapes."""
    _, shapes = jax.eval_shape(env.reset, jax.random.PRNGKey(0), params)
    return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)


def synchronous_cpu_dispatch() -> None:
    """Run JAX's CPU computations in the calling thread, in a process that has
    not computed anything with JAX yet (later the setting has no effect).

    For a SUMO worker whose only JAX work is the controller's small observer:
    handing each call to another thread and back cost about as much as the
    computation (measured at 32 slots on a busy 2-core machine: median 95 us
    per observation instead of 190 us).
    """
    if "jax_cpu_enable_async_dispatch" in jax.config.values:
        jax.config.update("jax_cpu_enable_async_dispatch", False)
