"""Drive SUMO's AVs with a policy, seeing what the JAX environment's AVs see.

    controller = PolicyController.from_policy("runs/ppo/policy", cfg, schedule)
    run = run_schedule(cfg, schedule, controller=controller)
    controller.report()  # per-step timing, slot overflow, commands

After every SUMO step the controller

1. reads every vehicle in the network into slots and computes their
   observation rows with the JAX environment's own jitted observer, the one
   the policy was trained with (`sumo_export.traffic.SumoObserver`);
2. runs the policy in NumPy on the occupied slots;
3. commands each AV ``setSpeed(v + a * dt)``, with ``a`` clipped to the AV's
   [-decel, accel] and the speed kept at or above ``max(v - decel * dt, 0)``;
   a NaN ``a`` releases the AV to its vType (``setSpeed(-1)``). SUMO's
   default speed mode 31 stays on: SUMO applies the command while the AV
   plans and clamps it by its safe speed, as `jaxround.core.command` does in JAX.
   (``setAcceleration(a, dt)`` gave the same speeds to the last digit;
   ``setSpeed`` says what `commanded_speed` computes. A command holds until
   released with ``setSpeed(-1)``.)

4. sends the action's lane column as ``changeLane(id, index + d, dt / 2)``
   (> 0.5: the lane to the left, d = 1; < -0.5: to the right, d = -1;
   between: hold the lane, d = 0; NaN: nothing), only where the AV's edge
   has two lanes and the one asked for, so on one-lane roads never, and
   only where the step's move keeps the AV off the junction ahead, under
   the default lane-change mode 1621: SUMO weighs the request against
   LC2013's own wishes in its next lane-change phase and changes only
   where its safety checks allow (`jaxround.envs.lane_view`, which JAX
   applies the same way).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jaxround.envs.assertiveness import TAU_RANGE
from jaxround.envs.observe import OBSERVATION_SIZES
from jaxround.lanes.traci import REQUEST_STEPS
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import Schedule
from sumo_export.traffic import (
    DEFAULT_SLOTS,
    SumoObserver,
    SumoTraffic,
    synchronous_cpu_dispatch,
)

#: ``act(obs (n, D), mask (n,) bool) -> (accel (n,), change (n,))``.
PolicyFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
#: Phases of a controller step whose time is recorded.
PHASES = ("read", "observe", "policy", "command")


class PolicyController:
    """The ``controller(libsumo, time_s)`` of `sumo_export.runner.run_schedule`.

    Args:
        cfg: the scenario.
        schedule: the schedule SUMO runs (routes and classes of its vehicles).
        act: the policy, ``act(obs (n, D), mask (n,)) -> (accel (n,), change (n,))``.
        observer: the observer the policy reads (`jaxround.envs.observe`).
        max_slots: vehicle slots M (default: the road's);
            vehicles beyond them drive uncontrolled (their IDM) and are
            counted in ``report()["overflow_vehicle_steps"]``.
        strict: raise OverflowError instead of counting when the slots overflow.

    Attributes:
        sumo: reads SUMO's vehicles and computes their observation rows.
        record_observations: compute the observation at every step, AVs in
            the network or not (for checks; otherwise only when there are).
        last_obs: float32 (S, D) the last step's observation rows (None when
            not computed).
        last_traffic: the last step's `SumoTraffic`.
    """

    def __init__(
        self,
        cfg: ScenarioConfig,
        schedule: Schedule,
        act: PolicyFn,
        observer: str,
        max_slots: int | str | None = DEFAULT_SLOTS,
        strict: bool = False,
        action: str = "accel",
    ) -> None:
        self.sumo = SumoObserver(cfg, schedule, observer, max_slots, strict)
        self.act = act
        self.action = action
        self.dt = cfg.simulation.dt_s
        av = cfg.drivers.av
        self.av_accel, self.av_decel = av.accel, av.decel
        self.av_tau, self.av_impatience = av.tau, av.impatience
        # the time-gap floor of the actions, as `assertive_tau` applies it
        self.min_tau = min(cfg.safety.min_av_tau_s, av.tau)
        self._lanes_of_edge: dict[str, int] = {}
        self._lane_length: dict[str, float] = {}
        self.record_observations = False
        self.start_episode(schedule)

    def start_episode(self, schedule: Schedule) -> None:
        """Forget the last run's commands and counts, and read `schedule`'s
        vehicles from now on (the compiled observers stay)."""
        self.sumo.use_schedule(schedule)
        self.sumo.overflow_vehicle_steps = 0
        self.sumo.off_path_vehicle_steps = 0
        self._retuned: dict[str, tuple[float, float]] = {}
        self._commanded: set[str] = set()
        self._times: dict[str, list[int]] = {k: [] for k in PHASES}
        self.commands = 0
        self.lane_requests = 0
        self.lane_requests_withheld = 0
        self.last_obs: np.ndarray | None = None
        self.last_traffic: SumoTraffic | None = None

    @classmethod
    def from_policy(
        cls,
        policy_path: str | Path,
        cfg: ScenarioConfig,
        schedule: Schedule,
        max_slots: int | str | None = DEFAULT_SLOTS,
        strict: bool = False,
    ) -> PolicyController:
        """A controller for an exported policy (`agents.common.export`); raises as
        `policy_observer`."""
        from agents.common.export import load_policy, load_policy_numpy

        observer = policy_observer(policy_path)
        act = load_policy_numpy(policy_path)
        action = load_policy(policy_path)[1].action
        return cls(cfg, schedule, act, observer, max_slots, strict, action)

    # ------------------------------------------------------------------ a step

    def __call__(self, libsumo: Any, time_s: float) -> None:
        """Observe, decide and command every AV after SUMO's step to `time_s`."""
        del time_s
        t0 = time.perf_counter_ns()
        traffic = self.sumo.read(libsumo)
        t1 = time.perf_counter_ns()
        obs = None
        if traffic.n_av or self.record_observations:
            obs = self.sumo.observe(traffic)
        t2 = time.perf_counter_ns()
        if traffic.n_av:
            accel, change = self.decide(obs, traffic)
            t3 = time.perf_counter_ns()
            self.command(libsumo, traffic, accel, change)
        else:  # nothing to decide; release AVs that lost their slot
            t3 = time.perf_counter_ns()
            self.command(libsumo, traffic, np.zeros(0), np.zeros(0))
        t4 = time.perf_counter_ns()
        for name, dt_ns in zip(PHASES, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
            self._times[name].append(dt_ns)
        self.last_obs, self.last_traffic = obs, traffic

    def decide(
        self, obs: np.ndarray, traffic: SumoTraffic
    ) -> tuple[np.ndarray, np.ndarray]:
        """The policy on the occupied slots: (accel float (n,), change (n,))."""
        n = traffic.n
        accel, change = self.act(obs[:n], np.ones(n, bool))
        return np.asarray(accel), np.asarray(change)

    def command(
        self,
        libsumo: Any,
        traffic: SumoTraffic,
        accel: np.ndarray,
        change: np.ndarray,
    ) -> None:
        """Command the AVs: speeds (or tau and impatience), and lanes.

        Args:
            libsumo: the running simulation.
            traffic: the vehicles as `SumoObserver.read` gave them.
            accel: float (n,) the action's first column per occupied slot
                (empty: no commands, only releases).
            change: float (n,) the lane column (> 0.5 left, < -0.5 right,
                between: hold, NaN: none).
        """
        if self.action == "assertiveness":
            self.retune(libsumo, traffic, accel)
        else:
            self.command_speeds(libsumo, traffic, accel)
        self.request_lanes(libsumo, traffic, change)

    def command_speeds(
        self, libsumo: Any, traffic: SumoTraffic, accel: np.ndarray
    ) -> None:
        """``setSpeed(v + a dt)`` for each AV (``setSpeed(-1)`` to release one
        whose ``a`` is NaN or that lost its slot).

        Args:
            libsumo: the running simulation.
            traffic: the vehicles as `SumoObserver.read` gave them.
            accel: float (n,) acceleration per occupied slot, m/s^2.
        """
        veh = libsumo.vehicle
        n = len(accel)
        v_cmd = commanded_speed(
            traffic.speed[:n], np.asarray(accel, np.float64), self.av_accel,
            self.av_decel, self.dt,
        ).tolist()  # fmt: skip
        is_av = (traffic.column("is_av")[:n] > 0.5).tolist()
        commanded = set()
        for vid, av, v in zip(traffic.ids, is_av, v_cmd):
            if not av:
                continue
            if v != v:  # NaN: no command, the AV drives its vType
                if vid in self._commanded:
                    veh.setSpeed(vid, -1.0)
                continue
            veh.setSpeed(vid, v)
            commanded.add(vid)
        # a command holds until released: an AV that lost its slot drives its IDM
        for vid in traffic.unslotted:
            if vid in self._commanded:
                veh.setSpeed(vid, -1.0)
        self._commanded = commanded
        self.commands += len(commanded)

    def request_lanes(
        self, libsumo: Any, traffic: SumoTraffic, change: np.ndarray
    ) -> None:
        """``changeLane(id, index + d, dt / 2)`` for each AV whose lane column
        asks for the lane to its left (> 0.5, d = 1), right (< -0.5, d = -1)
        or to hold its lane (between, d = 0), where its edge has the lane
        asked for (a hold: where it has two), and only off junctions: not
        on an internal lane, nor where ``(v + accel * dt) * dt`` could carry
        the AV past its lane's end before the lane-change phase; NaN asks
        nothing (`jaxround.envs.lane_view`). Lane-change mode 1621 stays:
        SUMO changes only where LC2013's safety checks allow.

        Args:
            libsumo: the running simulation.
            traffic: the vehicles as `SumoObserver.read` gave them.
            change: float (n,) the lane column per occupied slot.
        """
        change = np.asarray(change, np.float64)
        way = np.where(change > 0.5, 1, np.where(change < -0.5, -1, 0))
        is_av = traffic.column("is_av")[: len(way)] > 0.5
        asked = np.nonzero(is_av & ~np.isnan(change))[0].tolist()
        for slot in asked:
            # the lane the observer read: "<edge>_<index>"
            lane_id = traffic.lane_ids[slot]
            edge, index = lane_id.rsplit("_", 1)
            if lane_id not in self._lane_length:
                self._lane_length[lane_id] = libsumo.lane.getLength(lane_id)
            reach = (traffic.speed[slot] + self.av_accel * self.dt) * self.dt
            # on a junction, or a move that could take it onto one
            if edge.startswith(":") or (
                traffic.lane_pos[slot] + reach >= self._lane_length[lane_id]
            ):
                self.lane_requests_withheld += 1
                continue
            if edge not in self._lanes_of_edge:
                self._lanes_of_edge[edge] = libsumo.edge.getLaneNumber(edge)
            n_lanes = self._lanes_of_edge[edge]
            target = int(index) + int(way[slot])
            if n_lanes > 1 and 0 <= target < n_lanes:
                libsumo.vehicle.changeLane(
                    traffic.ids[slot], target, REQUEST_STEPS * self.dt
                )
                self.lane_requests += 1

    def retune(self, libsumo: Any, traffic: SumoTraffic, raw: np.ndarray) -> None:
        """Set each AV's tau and impatience for the next step from its raw
        action (`jaxround.envs.assertiveness`; `set_tau_and_impatience`, only
        where they change).

        Args:
            libsumo: the running simulation.
            traffic: the vehicles as `SumoObserver.read` gave them.
            raw: float (n,) raw action per occupied slot (empty: none).
        """
        n = len(raw)
        u = np.tanh(np.nan_to_num(np.asarray(raw, np.float64)))
        tau = np.maximum(self.av_tau * TAU_RANGE ** (-u), self.min_tau)
        imp = np.clip(self.av_impatience + np.maximum(u, 0.0), 0.0, 1.0)
        is_av = (traffic.column("is_av")[:n] > 0.5).tolist()
        retuned = {}
        for vid, av, t, i in zip(traffic.ids, is_av, tau.tolist(), imp.tolist()):
            if not av:
                continue
            if self._retuned.get(vid, (self.av_tau, self.av_impatience)) != (t, i):
                set_tau_and_impatience(libsumo, vid, t, i)
                self.commands += 1
            retuned[vid] = (t, i)
        # an AV that lost its slot drives its vType again
        for vid in traffic.unslotted:
            if vid in self._retuned:
                set_tau_and_impatience(libsumo, vid, self.av_tau, self.av_impatience)
        self._retuned = retuned

    # ------------------------------------------------------------------ report

    def step_times_ms(self) -> dict[str, np.ndarray]:
        """Per controller step, ms: float (T,) per phase of `PHASES` and "total"."""
        out = {k: np.asarray(v, np.float64) / 1e6 for k, v in self._times.items()}
        out["total"] = sum((out[k] for k in PHASES), np.zeros(len(self._times["read"])))
        return out

    def report(self) -> dict[str, Any]:
        """Plain data for `SumoRun.controller_report`: per-step times (lists,
        ms), slots, slot overflow, AV commands, lane requests sent and those
        withheld on or before a junction."""
        return {
            "step_ms": {k: v.tolist() for k, v in self.step_times_ms().items()},
            "max_slots": self.sumo.max_slots,
            "overflow_vehicle_steps": self.sumo.overflow_vehicle_steps,
            "off_path_vehicle_steps": self.sumo.off_path_vehicle_steps,
            "commands": self.commands,
            "lane_requests": self.lane_requests,
            "lane_requests_withheld": self.lane_requests_withheld,
        }


def policy_observer(policy_path: str | Path) -> str:
    """The observer an exported policy reads, checked against its input size.

    Raises:
        FileNotFoundError: a file of the policy is missing.
        ValueError: the files are damaged, or the observer gives another
            number of values than the policy reads.
    """
    from agents.common.export import load_policy

    _, layout = load_policy(policy_path)
    if OBSERVATION_SIZES.get(layout.observer) != layout.obs_size:
        raise ValueError(
            f"{policy_path}: the policy reads {layout.obs_size} numbers of the "
            f"{layout.observer!r} observer, which gives "
            f"{OBSERVATION_SIZES.get(layout.observer)}"
        )
    return layout.observer


def set_tau_and_impatience(
    libsumo: Any, vid: str, tau: float, impatience: float
) -> None:
    """Give one vehicle its own tau and impatience from the next step on.

    ``vehicle.setTau`` gives the vehicle a type of its own (``av@<id>``), a
    copy of its vType; the impatience is set on that type. (Measured with
    SUMO 1.28: ``vehicle.setImpatience`` leaves ``getImpatience`` and the
    junction decisions unchanged.)
    """
    libsumo.vehicle.setTau(vid, tau)
    libsumo.vehicletype.setImpatience(libsumo.vehicle.getTypeID(vid), impatience)


def commanded_speed(
    speed: np.ndarray, accel: np.ndarray, max_accel: float, decel: float, dt: float
) -> np.ndarray:
    """The speed an AV is commanded for the next step, float (n,).

    ``v + clip(a, -decel, max_accel) * dt``, at least ``max(v - decel * dt, 0)``
    (`jaxround.core.command.commanded_speed`, which the JAX environment applies as
    SUMO does); NaN where ``a`` is NaN: no command.
    """
    a = np.clip(accel, -decel, max_accel)
    return np.maximum(speed + a * dt, np.maximum(speed - decel * dt, 0.0))


@dataclass(frozen=True)
class PolicyControllerFactory:
    """Builds a `PolicyController` inside a SUMO worker process (picklable);
    a `sumo_export.runner.ControllerFactory`. It switches the worker's JAX to
    `synchronous_cpu_dispatch` first.

    Attributes:
        policy_path: the exported policy (``.npz``, ``.json``, stem or folder).
        max_slots: vehicle slots M (default: what the road holds).
    """

    policy_path: str
    max_slots: int | str | None = DEFAULT_SLOTS

    def __call__(self, cfg: ScenarioConfig, schedule: Schedule) -> PolicyController:
        synchronous_cpu_dispatch()
        return PolicyController.from_policy(
            self.policy_path, cfg, schedule, self.max_slots
        )
