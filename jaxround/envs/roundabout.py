"""The roundabout as a gymnax-style JAX environment.

    env, params = jaxround.make("milan")
    obs, state = env.reset(key, params)
    obs, state, reward, done, info = env.step(key, state, action, params)

`reset` and `step` are pure and jit-able; batch them with
``jax.vmap(env.step, in_axes=(0, 0, 0, None))``. `step` resets by itself when
an episode ends. `reset_to_schedule` starts from a given departure schedule
(the one SUMO runs), for parity checks and evaluation.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from jaxround.core import dynamics, emissions, geometry, idm
from jaxround.core.network import CompiledNetwork
from jaxround.core.params import EnvParams
from jaxround.core.state import (
    EnvState,
    EpisodeStats,
    Registrations,
    Schedule,
    leg_order,
)
from jaxround.envs import conflicts, departures, observe, queues, schedules
from jaxround.envs.actions import command_from_action
from jaxround.envs.assertiveness import retuned_params
from jaxround.envs.lane_changes import LaneChanger, LaneState, compiled_network
from jaxround.envs.lane_view import observation_by_name
from jaxround.envs.reward import av_reward, system_reward
from jaxround.envs.slots import resolve_slots
from jaxround.envs.supported import check_driver_classes, check_jax_lanes
from jaxround.envs.wrappers import auto_reset
from jaxround.lanes.params import LaneChangeParams
from jaxround.scenario.config import ScenarioConfig, load_config
from jaxround.scenario.schedule import Schedule as NumpySchedule
from jaxround.sumo_files.netconvert import network_file

#: Extra seconds after the demand horizon for the last vehicles to leave.
DEFAULT_DRAIN_S = 300.0


class RoundaboutEnv:
    """A roundabout with M vehicle slots and N scheduled vehicles. On two-lane
    roads (`jaxround.lanes.ring_network`'s network, `lane_changer` given)
    the vehicles change lanes after every move (`jaxround.envs.lane_changes`).

    M: given, else the config's ``simulation.max_vehicles``, else what its
    traffic needs (`jaxround.envs.slots`); ``"road"``: what the road holds.
    Static settings live here; traced numbers in `EnvParams`; state `EnvState`.
    """

    def __init__(
        self,
        cfg: ScenarioConfig,
        network: CompiledNetwork,
        max_vehicles: int | str | None = None,
        episode_s: float | None = None,
        lane_changer: LaneChanger | None = None,
    ) -> None:
        check_jax_lanes(cfg)
        check_driver_classes(cfg)
        if lane_changer is None and not cfg.network.single_lane:
            raise ValueError(
                f"{cfg.name!r} has two-lane roads: build its environment with "
                "`jaxround.make` (a lane-path network and a lane changer)"
            )
        if network.n_legs != cfg.n_legs:
            raise ValueError(
                f"network has {network.n_legs} legs, config {cfg.name!r} "
                f"has {cfg.n_legs}"
            )
        self.cfg = cfg
        self.network = network
        self.lane_changer = lane_changer
        self.net = geometry.NetArrays.from_network(network)
        self.max_vehicles = resolve_slots(
            max_vehicles, cfg, network,
            build_env=lambda m, s: RoundaboutEnv(cfg, network, m, s, lane_changer),
        )  # fmt: skip
        self.n_schedule = cfg.demand.n_vehicles
        self.dt = cfg.simulation.dt_s
        self.n_substeps = idm.idm_substeps(self.dt)
        hv = cfg.drivers.hv
        self.action_step = (
            max(1, math.floor(hv.action_step_length / self.dt + 1e-9)) * self.dt
        )
        self.episode_s = (
            cfg.demand.duration_s + DEFAULT_DRAIN_S if episode_s is None else episode_s
        )
        self.episode_steps = int(math.ceil(self.episode_s / self.dt))
        self.observer = cfg.agent.observer
        self.route_destination = jnp.asarray(network.route_od[:, 1])
        # jitted once per environment, as gymnax jits its `reset`: a call
        # outside any trace compiles one program instead of each of its
        # several hundred operations (inside a trace it is inlined)
        self._reset_to_schedule = jax.jit(self._start_episode)
        self._reset = jax.jit(
            lambda key, params: self._start_episode(
                self.draw_schedule(key, params), params
            )
        )

    # ------------------------------------------------------------------ params

    @property
    def default_params(self) -> EnvParams:
        return EnvParams.from_config(self.cfg)

    @property
    def n_legs(self) -> int:
        return self.network.n_legs

    @property
    def obs_size(self) -> int:
        """Numbers per slot of the configured observer."""
        return observe.OBSERVATION_SIZES[self.observer]

    @property
    def action_size(self) -> int:
        """Per slot: acceleration (m/s^2) and lane (> 0.5 left, < -0.5 right)."""
        return 2

    # ------------------------------------------------------------------ schedules

    def schedule_from_numpy(self, schedule: NumpySchedule) -> Schedule:
        """The JAX form of a schedule drawn by `schedule.make_schedule`."""
        return schedules.from_numpy(self.network, self.cfg, self.n_schedule, schedule)

    def draw_schedule(self, key: jax.Array, params: EnvParams) -> Schedule:
        """A random schedule in JAX with the distribution of `make_schedule`
        (`schedules.draw`)."""
        return schedules.draw(self.network, self.n_schedule, self.dt, key, params)

    # ------------------------------------------------------------------ API

    def reset(self, key: jax.Array, params: EnvParams) -> tuple[jax.Array, EnvState]:
        """Start an episode with a freshly drawn schedule.

        Jitted, drawing included, as `reset_to_schedule`.
        """
        return self._reset(key, params)

    def reset_to_schedule(
        self, schedule: Schedule, params: EnvParams
    ) -> tuple[jax.Array, EnvState]:
        """Start an episode that inserts the vehicles of `schedule`.

        Jitted: outside a trace the first call per shape compiles it.

        Returns:
            (observation (M, obs_size), state).
        """
        return self._reset_to_schedule(schedule, params)

    def _start_episode(
        self, schedule: Schedule, params: EnvParams
    ) -> tuple[jax.Array, EnvState]:
        """`reset_to_schedule`'s body: empty slots, then the first insertions."""
        m, n, g = self.max_vehicles, self.n_schedule, self.network.n_entries
        zf = jnp.zeros(m, jnp.float32)
        state = EnvState(
            step=jnp.int32(0),
            active=jnp.zeros(m, bool),
            vid=-jnp.ones(m, jnp.int32),
            route=jnp.zeros(m, jnp.int32),
            pos=zf,
            speed=zf,
            accel=zf,
            is_av=jnp.zeros(m, bool),
            speed_factor=jnp.ones(m, jnp.float32),
            waiting_s=zf,
            co2_mg=zf,
            fuel_mg=zf,
            schedule=schedule,
            inserted=jnp.zeros(n, bool),
            leg_vehicles=leg_order(schedule.origin, g),
            leg_inserted=jnp.zeros(g, jnp.int32),
            insert_s=jnp.full(n, jnp.nan, jnp.float32),
            arrival_s=jnp.full(n, jnp.nan, jnp.float32),
            registrations=Registrations.empty(m, g),
            stats=EpisodeStats.zeros(n, self.network.n_legs, m),
            lanes=None
            if self.lane_changer is None
            else LaneState.zeros(m, n, self.network.n_lanes),
        )
        state = self._insert(state, params, jnp.float32(0.0))
        return self.observation(state, params), state

    def step(
        self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams
    ) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, dict[str, Any]]:
        """One step of dt seconds; a finished episode restarts with a new schedule.

        Args:
            key: PRNG key (used by the reset).
            state: the current state.
            action: float (M, 2) per slot: acceleration (or assertiveness) and
                lane (> 0.5 left, < -0.5 right); ignored for human drivers.
            params: traced parameters.

        Returns:
            (obs, state, reward, done, info); reward is float (M,) per slot.
        """
        obs, new_state, reward, done, info = self.step_env(key, state, action, params)
        # the reset runs only when the episode ended (under `vmap` in every
        # step: `jaxround.envs.wrappers.auto_reset` on a whole batch avoids that)
        obs, state = auto_reset(done, (obs, new_state), lambda: self.reset(key, params))
        return obs, state, reward, done, info

    def step_env(
        self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams
    ) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, dict[str, Any]]:
        """One step without the automatic reset (see `step`).

        Every vehicle plans its speed as SUMO's IDM does with its class's
        parameters. With ``agent.action: assertiveness`` an AV's
        ``action[:, 0]`` retunes its tau and impatience for the step
        (`jaxround.envs.assertiveness`; 0 is its vType). Otherwise (``accel``) an
        AV's ``action[:, 0]`` (m/s^2) becomes the speed command
        ``speed + action * dt`` (`command_from_action`), which SUMO applies
        while it plans (`jaxround.core.command`): under speed mode 31 it can slow
        an AV below its IDM speed, never raise it above its safe speed; a NaN
        action leaves the AV to its vType. On two-lane roads every vehicle
        changes lanes as LC2013 decides (`jaxround.envs.lane_changes`), an
        AV's ``action[:, 1]`` asking for the lane to the left (> 0.5) or
        right (< -0.5) as a TraCI request (`jaxround.envs.lane_view`).

        Returns:
            (obs, state, reward, done, info): reward float (M,) for the AV
            slots (0 elsewhere); info["agent"] bool (M,) the slot held an AV
            at the start of the step, info["terminated"] bool (M,) that AV
            left the network, info["truncated"] bool (M,) the episode ended
            with the vehicle still in it.
        """
        del key
        p, net = params, self.net
        pv = p.for_vehicles(state.is_av)  # (M,) accel, tau, gap acceptance
        t = state.step.astype(jnp.float32) * self.dt  # time at the start of the step

        # 1. the AVs' commands, applied as SUMO applies a TraCI speed command
        #    while every vehicle plans (IDM, junctions); then all move
        agent = state.active & state.is_av
        with jax.named_scope("actions"):
            if self.cfg.agent.action == "assertiveness":
                pv = retuned_params(
                    pv, action[:, 0], agent, self.cfg.safety.min_av_tau_s
                )
                command = jnp.full_like(state.speed, jnp.nan)
            else:
                command = command_from_action(state, action, pv, self.dt)
            changer = self.lane_changer  # the lane action: a TraCI request
            request = changer and changer.request(state, action[:, 1], agent, pv)
        lc = LaneChangeParams() if p.lane_change is None else p.lane_change
        patch = changer and changer.patch(state, lc, pv)
        v_next, regs, _, leader, gap, own_entry = dynamics.planned_speed(
            net, pv, state.route, state.pos, state.speed, state.speed_factor,
            state.active, state.waiting_s, state.registrations, t, self.dt,
            self.n_substeps, self.action_step, command=command, patch=patch,
            junction_order=changer and changer.junction_order(state, net),
        )  # fmt: skip
        with jax.named_scope("move"):
            pos_next = state.pos + v_next * self.dt
            route_len = net.route_length[state.route]
            arrived = state.active & (pos_next > route_len - dynamics.ARRIVAL_EPS)
            if not net.all_arrive:  # a lane path ending on the ring: no exit
                arrived = arrived & net.route_arrives[state.route]
            # a vehicle whose bumper passed the back of the one it followed
            lead = jnp.maximum(leader, 0)
            gap_next = gap + (v_next[lead] - v_next) * self.dt
            crashed = state.active & (leader >= 0) & ~arrived[lead] & (gap_next < -1e-3)
            waiting = jnp.where(
                v_next < dynamics.HALTING_SPEED, state.waiting_s + self.dt, 0.0
            )
        with jax.named_scope("surrogate_safety"):
            safety, conflicts_step = conflicts.step_conflicts(
                state, arrived, leader, gap_next, v_next, self.cfg.safety
            )
        with jax.named_scope("emissions"):
            # SUMO counts the arrival step in full (measured against tripinfo)
            co2_step, fuel_step = emissions.step_emissions_mg(
                state.speed, v_next, self.dt
            )
            co2 = state.co2_mg + jnp.where(state.active, co2_step, 0.0)
            fuel = state.fuel_mg + jnp.where(state.active, fuel_step, 0.0)
        with jax.named_scope("reward"):
            if self.cfg.agent.reward == "system":
                pending = queues.due(state, t) - jnp.sum(state.leg_inserted)
                n_in_system = jnp.sum(state.active) + pending
                reward = system_reward(
                    n_in_system, co2_step, state.active, agent, p, self.dt,
                    share=self.cfg.agent.share, conflicts_step=conflicts_step,
                )  # fmt: skip
            else:
                _, lane, _ = geometry.locate(net, state.route, state.pos)
                v_desired = jnp.minimum(
                    net.lane_speed[lane] * state.speed_factor, p.vehicle.max_speed
                )
                reward = av_reward(v_next, v_desired, co2_step / self.dt, p)
                reward = jnp.where(agent, reward, 0.0)

        # 2. arrivals leave their slots
        vid = jnp.where(arrived, state.vid, self.n_schedule)  # out of range: dropped
        arrival_s = state.arrival_s.at[vid].set(t + self.dt, mode="drop")
        stats = conflicts.add_conflicts(state.stats, state.vid, safety, conflicts_step)
        stats = stats.replace(
            trip_co2_mg=stats.trip_co2_mg.at[vid].set(co2, mode="drop"),
            trip_fuel_mg=stats.trip_fuel_mg.at[vid].set(fuel, mode="drop"),
            collisions=stats.collisions + jnp.sum(crashed),
        )
        active = state.active & ~arrived
        state = state.replace(
            step=state.step + 1,
            active=active,
            vid=jnp.where(active, state.vid, -1),
            pos=jnp.where(active, pos_next, 0.0),
            speed=jnp.where(active, v_next, 0.0),
            accel=jnp.where(active, (v_next - state.speed) / self.dt, 0.0),
            is_av=state.is_av & active,
            waiting_s=jnp.where(active, waiting, 0.0),
            co2_mg=jnp.where(active, co2, 0.0),
            fuel_mg=jnp.where(active, fuel, 0.0),
            arrival_s=arrival_s,
            registrations=regs._replace(ok=regs.ok & active[:, None]),
            stats=stats,
        )

        # 3. lane changes (two-lane roads), insertions, the queues of the new time
        if self.lane_changer is not None:
            with jax.named_scope("lane_changes"):
                state, _ = self.lane_changer(state, lc, request, net, pv, own_entry)
        with jax.named_scope("insertion"):
            state = self._insert(state, p, t + self.dt)
        with jax.named_scope("queues"):
            state = queues.count_queues(self.net, state, p, t + self.dt)
        done = state.step >= self.episode_steps
        info = {
            "agent": agent,
            "terminated": agent & arrived,
            "truncated": agent & ~arrived & done,
            "arrived": jnp.sum(arrived),
            "conflicts": jnp.sum(conflicts_step),  # each vehicle of a pair counts
            "collisions": jnp.sum(crashed),
            "overflow": state.stats.overflow,
            "n_active": jnp.sum(state.active),
        }
        with jax.named_scope("observation"):
            obs = self.observation(state, p)
        return obs, state, reward, done, info

    # ------------------------------------------------------------------ pieces

    def _insert(self, state: EnvState, params: EnvParams, t: jax.Array) -> EnvState:
        return departures.insert_departures(
            self.net, state, params, t, dt=self.dt, n_substeps=self.n_substeps
        )

    def observation(self, state: EnvState, params: EnvParams) -> jax.Array:
        """The configured observer's rows, float (M, obs_size) (`envs.observe`)."""
        changer = None if self.lane_changer is None else self.lane_changer.arrays
        return observation_by_name(
            self.observer, self.net, changer, state, params, self.route_destination
        )


def make(
    scenario: str | Path | ScenarioConfig = "milan",
    max_vehicles: int | str | None = None,
    episode_s: float | None = None,
    workdir: str | Path | None = None,
    *,
    crossing_leaders: bool = True,
) -> tuple[RoundaboutEnv, EnvParams]:
    """Build the environment of a scenario: its network is compiled by netconvert.

    Args:
        scenario: a built-in name, a YAML path, or a `ScenarioConfig`.
        max_vehicles: vehicle slots M; None: the config's, else what the
            scenario's traffic needs (`jaxround.envs.slots`); "road": what the
            road holds.
        episode_s: episode length; default demand horizon + 300 s.
        workdir: where to write the SUMO network; a cache folder if None.
        crossing_leaders: SUMO's link leaders where internal lanes cross (False: none).

    Returns:
        (env, default params).
    """
    cfg = scenario if isinstance(scenario, ScenarioConfig) else load_config(scenario)
    check_jax_lanes(cfg)  # before netconvert runs
    net_path = network_file(cfg, workdir)
    network, changer = compiled_network(cfg, net_path, crossing_leaders)
    env = RoundaboutEnv(cfg, network, max_vehicles, episode_s, changer)
    return env, env.default_params
