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
import numpy as np

from jaxround import command as traci
from jaxround import dynamics, emissions, geometry, idm, insertion, observe
from jaxround.assertiveness import retuned_params
from jaxround.capacity import resolve_max_vehicles
from jaxround.config import ConfigError, ScenarioConfig, load_config
from jaxround.geometry import NetArrays
from jaxround.network import CompiledNetwork, compile_network
from jaxround.reductions import first_min
from jaxround.relax import soft_step
from jaxround.reward import av_reward, system_reward
from jaxround.sampling import inverse_cdf, smallest_k, sorted_uniform
from jaxround.schedule import Schedule as NumpySchedule
from jaxround.state import EnvParams, EnvState, Registrations, Schedule

#: Extra seconds after the demand horizon for the last vehicles to leave.
DEFAULT_DRAIN_S = 300.0
#: Driver numbers the JAX environment shares between AVs and human drivers.
SHARED_DRIVER_FIELDS = (
    "car_follow_model", "decel", "emergency_decel", "min_gap", "delta", "length",
    "max_speed",
)  # fmt: skip


class RoundaboutEnv:
    """A single-lane roundabout with M vehicle slots and N scheduled vehicles.

    M: given, else the config's ``simulation.max_vehicles``, else what the road
    holds (`jaxround.capacity`). Static settings (shapes, dt, the network) live
    here; traced numbers in `EnvParams`; everything that changes in `EnvState`.
    """

    def __init__(
        self,
        cfg: ScenarioConfig,
        network: CompiledNetwork,
        max_vehicles: int | None = None,
        episode_s: float | None = None,
    ) -> None:
        if network.n_legs != cfg.n_legs:
            raise ValueError(
                f"network has {network.n_legs} legs, config {cfg.name!r} "
                f"has {cfg.n_legs}"
            )
        check_driver_classes(cfg)
        self.cfg = cfg
        self.network = network
        self.net = geometry.NetArrays.from_network(network)
        self.max_vehicles = resolve_max_vehicles(max_vehicles, cfg, network)
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
        dest = np.zeros(network.route_index.max() + 1, np.int32)
        for o in range(network.n_legs):
            for d in range(network.n_legs):
                if network.route_index[o, d] >= 0:
                    dest[network.route_index[o, d]] = d
        self.route_destination = jnp.asarray(dest)

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
        """Per slot: acceleration (m/s^2) and lane-change decision (> 0.5: change)."""
        return 2

    # ------------------------------------------------------------------ schedules

    def schedule_from_numpy(self, schedule: NumpySchedule) -> Schedule:
        """The JAX form of a schedule drawn by `jaxround.schedule.make_schedule`."""
        if schedule.n_vehicles != self.n_schedule:
            raise ValueError(
                f"schedule has {schedule.n_vehicles} vehicles, the environment "
                f"{self.n_schedule}"
            )
        route = self.network.route_index[schedule.origin, schedule.destination]
        drivers = self.cfg.drivers
        factor = schedule.class_speed_factors(
            drivers.hv.speed_dev, drivers.av.speed_dev
        )
        return Schedule(
            depart_s=jnp.asarray(schedule.depart_s, jnp.float32),
            route=jnp.asarray(route, jnp.int32),
            origin=jnp.asarray(schedule.origin, jnp.int32),
            speed_factor=jnp.asarray(factor, jnp.float32),
            is_av=jnp.asarray(schedule.is_av),
        )

    def draw_schedule(self, key: jax.Array, params: EnvParams) -> Schedule:
        """A random schedule in JAX with the distribution of `make_schedule`.

        Drawn without sorting (`step` draws one for every roundabout at every
        step, for its automatic reset): sorted departure times from
        exponential gaps, origins and destinations by inverse CDF, the AVs as
        the vehicles with the smallest random keys (a binary search for the
        cut).
        """
        n = self.n_schedule
        k_t, k_o, k_d, k_s, k_av = jax.random.split(key, 5)
        t = sorted_uniform(k_t, n, params.duration_s)
        depart = jnp.floor(t / self.dt) * self.dt
        origin = inverse_cdf(
            k_o, jnp.broadcast_to(params.origin_share, (n, self.n_legs))
        )
        dest = inverse_cdf(k_d, params.od[origin])
        z = jax.random.truncated_normal(
            k_s, -0.8 / jnp.maximum(params.speed_dev, 1e-6),
            1.0 / jnp.maximum(params.speed_dev, 1e-6), (n,),
        )  # fmt: skip
        speed_factor = jnp.round((1.0 + params.speed_dev * z) * 1e4) / 1e4
        # round(p * N) with halves up, as `n_av_at`; the margin absorbs float32
        n_av = jnp.floor(params.penetration * n + 0.5 + 1e-3).astype(jnp.int32)
        route = jnp.asarray(self.network.route_index)[origin, dest]
        is_av = smallest_k(k_av, n, n_av)
        # as `Schedule.class_speed_factors`: AVs scale their deviation from 1
        scale = params.av_speed_dev / jnp.maximum(params.speed_dev, 1e-6)
        av_factor = jnp.round((1.0 + (speed_factor - 1.0) * scale) * 1e4) / 1e4
        return Schedule(
            depart_s=depart.astype(jnp.float32),
            route=route.astype(jnp.int32),
            origin=origin.astype(jnp.int32),
            speed_factor=jnp.where(is_av, av_factor, speed_factor).astype(jnp.float32),
            is_av=is_av,
        )

    # ------------------------------------------------------------------ API

    def reset(self, key: jax.Array, params: EnvParams) -> tuple[jax.Array, EnvState]:
        """Start an episode with a freshly drawn schedule."""
        return self.reset_to_schedule(self.draw_schedule(key, params), params)

    def reset_to_schedule(
        self, schedule: Schedule, params: EnvParams
    ) -> tuple[jax.Array, EnvState]:
        """Start an episode that inserts the vehicles of `schedule`."""
        m, n, g = self.max_vehicles, self.n_schedule, self.n_legs
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
            insert_s=jnp.full(n, jnp.nan, jnp.float32),
            arrival_s=jnp.full(n, jnp.nan, jnp.float32),
            trip_co2_mg=jnp.zeros(n, jnp.float32),
            trip_fuel_mg=jnp.zeros(n, jnp.float32),
            queue_sum=jnp.zeros(g, jnp.float32),
            queue_max=jnp.zeros(g, jnp.float32),
            queue_samples=jnp.int32(0),
            overflow=jnp.int32(0),
            collisions=jnp.int32(0),
            registrations=Registrations.empty(m, g),
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
            action: float (M, 2) per slot: acceleration and lane-change flag
                (ignored for human drivers).
            params: traced parameters.

        Returns:
            (obs, state, reward, done, info); reward is float (M,) per slot.
        """
        obs, new_state, reward, done, info = self.step_env(key, state, action, params)
        # the reset runs only when the episode ended (under `vmap` a cond
        # computes both branches; `agents.batch.BatchTrainer.env_step` resets
        # a whole batch only in steps where some episode ended)
        obs, state = jax.lax.cond(
            done,
            lambda: self.reset(key, params),
            lambda: (obs, new_state),
        )
        return obs, state, reward, done, info

    def step_env(
        self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams
    ) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, dict[str, Any]]:
        """One step without the automatic reset (see `step`).

        Every vehicle plans its speed as SUMO's IDM does with its class's
        parameters. With ``agent.action: assertiveness`` an AV's
        ``action[:, 0]`` retunes its tau and impatience for the step
        (`jaxround.assertiveness`; 0 is its vType). Otherwise (``accel``) an
        AV's ``action[:, 0]`` (m/s^2) becomes the speed command
        ``speed + action * dt`` (`command_from_action`), which SUMO applies
        while it plans (`jaxround.command`): under speed mode 31 it can slow
        an AV below its IDM speed, never raise it above its safe speed; a NaN
        action leaves the AV to its vType. ``action[:, 1]`` (lane change) has
        nothing to act on: every lane of these roundabouts is the only one of
        its road.

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
        if self.cfg.agent.action == "assertiveness":
            pv = retuned_params(pv, action[:, 0], agent)
            command = jnp.full_like(state.speed, jnp.nan)
        else:
            command = command_from_action(state, action, pv, self.dt)
        v_next, regs, _, leader, gap = dynamics.planned_speed(
            net, pv, state.route, state.pos, state.speed, state.speed_factor,
            state.active, state.waiting_s, state.registrations, t, self.dt,
            self.n_substeps, self.action_step, command=command,
        )  # fmt: skip
        pos_next = state.pos + v_next * self.dt
        route_len = net.route_length[state.route]
        arrived = state.active & (pos_next > route_len - dynamics.ARRIVAL_EPS)
        # a vehicle whose bumper passed the back of the one it followed
        lead = jnp.maximum(leader, 0)
        gap_next = gap + (v_next[lead] - v_next) * self.dt
        crashed = state.active & (leader >= 0) & ~arrived[lead] & (gap_next < -1e-3)
        # SUMO counts the arrival step in full (measured against tripinfo)
        co2_step, fuel_step = emissions.step_emissions_mg(state.speed, v_next, self.dt)
        co2 = state.co2_mg + jnp.where(state.active, co2_step, 0.0)
        fuel = state.fuel_mg + jnp.where(state.active, fuel_step, 0.0)
        waiting = jnp.where(
            v_next < dynamics.HALTING_SPEED, state.waiting_s + self.dt, 0.0
        )
        _, lane, _ = geometry.locate(net, state.route, state.pos)
        v_desired = jnp.minimum(net.lane_speed[lane] * state.speed_factor, p.max_speed)
        if self.cfg.agent.reward == "system":
            pending = ~state.inserted & (state.schedule.depart_s <= t + 1e-4)
            n_in_system = jnp.sum(state.active) + jnp.sum(pending)
            reward = system_reward(
                n_in_system, co2_step, state.active, agent, p, self.dt,
                share=self.cfg.agent.share,
            )  # fmt: skip
        else:
            reward = av_reward(v_next, v_desired, co2_step / self.dt, p)
            reward = jnp.where(agent, reward, 0.0)

        # 2. arrivals leave their slots
        vid = jnp.where(arrived, state.vid, self.n_schedule)  # out of range: dropped
        arrival_s = state.arrival_s.at[vid].set(t + self.dt, mode="drop")
        trip_co2 = state.trip_co2_mg.at[vid].set(co2, mode="drop")
        trip_fuel = state.trip_fuel_mg.at[vid].set(fuel, mode="drop")
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
            trip_co2_mg=trip_co2,
            trip_fuel_mg=trip_fuel,
            collisions=state.collisions + jnp.sum(crashed),
            registrations=regs._replace(ok=regs.ok & active[:, None]),
        )

        # 3. insertions, then the queue statistics of the new time
        state = self._insert(state, p, t + self.dt)
        state = self._count_queues(state, p, t + self.dt)
        done = state.step >= self.episode_steps
        info = {
            "agent": agent,
            "terminated": agent & arrived,
            "truncated": agent & ~arrived & done,
            "arrived": jnp.sum(arrived),
            "collisions": jnp.sum(crashed),
            "overflow": state.overflow,
            "n_active": jnp.sum(state.active),
        }
        return self.observation(state, p), state, reward, done, info

    # ------------------------------------------------------------------ pieces

    def _insert(self, state: EnvState, params: EnvParams, t: jax.Array) -> EnvState:
        """Insert the first waiting vehicle of each leg where its approach has room.

        As SUMO with departPos="base", departSpeed="max": the vehicle's back at
        the start of its approach, at the highest speed that is safe behind
        the vehicle ahead; otherwise it waits (and blocks later vehicles of
        its leg) until the next step.

        Insertion is a hard decision and carries no gradient: its inputs are
        frozen with `stop_gradient` (the inserted speed's sensitivity is left
        out, which also keeps the backward pass small to compile).
        """
        net, s = self.net, state.schedule
        p = jax.lax.stop_gradient(params)
        pos, speed = jax.lax.stop_gradient((state.pos, state.speed))
        g, n, m = self.n_legs, self.n_schedule, self.max_vehicles
        waiting = ~state.inserted & (s.depart_s <= t + 1e-4)  # (N,)
        idx = jnp.arange(n)
        mine = waiting[None, :] & (
            s.origin[None, :] == jnp.arange(g)[:, None]
        )  # (G, N)
        cand = jnp.min(jnp.where(mine, idx[None, :], n), axis=1)  # (G,)
        has = cand < n
        c = jnp.minimum(cand, n - 1)
        route = s.route[c]  # (G,)
        front = jnp.full(g, p.length + dynamics.DEPART_OFFSET)
        # the nearest vehicle ahead of the new one's front, along its route
        back = jnp.maximum(pos - p.length, 0.0)
        _, lane, pos_on_lane = geometry.locate(net, state.route, back)
        proj = geometry.project(net, route, lane, pos_on_lane)  # (G, M) backs
        ahead = jnp.where(state.active[None, :], proj - front[:, None], jnp.nan)
        ahead = jnp.where(jnp.isnan(ahead) | (ahead < -p.length), jnp.inf, ahead)
        nearest, j = first_min(ahead, axis=1)
        gap = nearest - p.min_gap  # SUMO's gap2pred
        v_lane = jnp.minimum(
            net.lane_speed[net.route_lanes[route, 0]] * s.speed_factor[c], p.max_speed
        )
        free_lane = jnp.isinf(gap)
        # SUMO lowers the speed first for the vehicle ahead, then for the stop
        # the vehicle plans at its yield line (beyond the visibility distance)
        pi = p.for_vehicles(s.is_av[c])  # (G,) the inserted vehicles' own
        v_follow = insertion.insertion_speed(
            v_lane, v_lane, speed[j],
            jnp.where(free_lane, 1e6, jnp.maximum(gap, 0.0)),
            pi, self.dt, self.n_substeps,
        )  # fmt: skip
        v_ins = jnp.where(free_lane, v_lane, v_follow)
        v_ins = insertion.insertion_stop_speed(
            v_ins, v_lane, net.yield_offset[route] - front, pi, self.dt,
            self.n_substeps,
        )  # fmt: skip
        room = free_lane | (gap >= 0.0)
        ok = has & room
        # slots: the k-th inserting leg takes the k-th free slot
        free = jnp.nonzero(~state.active, size=g, fill_value=m)[0]  # (G,)
        rank = jnp.cumsum(ok) - 1
        slot = jnp.where(ok, free[jnp.clip(rank, 0, g - 1)], m)
        overflow = ok & (slot >= m)
        ok = ok & (slot < m)
        slot = jnp.where(ok, slot, m)  # m: dropped by the scatters below
        vids = jnp.where(ok, c, n)

        def put(arr: jax.Array, values: jax.Array) -> jax.Array:
            return arr.at[slot].set(values.astype(arr.dtype), mode="drop")

        return state.replace(
            active=put(state.active, jnp.ones(g, bool)),
            vid=put(state.vid, c),
            route=put(state.route, route),
            pos=put(state.pos, front),
            speed=put(state.speed, v_ins),
            accel=put(state.accel, jnp.zeros(g)),
            is_av=put(state.is_av, s.is_av[c]),
            speed_factor=put(state.speed_factor, s.speed_factor[c]),
            waiting_s=put(state.waiting_s, jnp.zeros(g)),
            co2_mg=put(state.co2_mg, jnp.zeros(g)),
            fuel_mg=put(state.fuel_mg, jnp.zeros(g)),
            inserted=state.inserted.at[vids].set(True, mode="drop"),
            insert_s=state.insert_s.at[vids].set(t, mode="drop"),
            overflow=state.overflow + jnp.sum(overflow),
        )

    def _count_queues(
        self, state: EnvState, params: EnvParams, t: jax.Array
    ) -> EnvState:
        """Queued vehicles per leg: halting on the approach plus waiting to enter."""
        q = queued_per_leg(self.net, state, t, jnp.float32(0.0))
        within = t <= params.duration_s + 1e-4
        return state.replace(
            queue_sum=state.queue_sum + jnp.where(within, q, 0.0),
            queue_max=jnp.where(
                within, jnp.maximum(state.queue_max, q), state.queue_max
            ),
            queue_samples=state.queue_samples + within.astype(jnp.int32),
        )

    def observation(self, state: EnvState, params: EnvParams) -> jax.Array:
        """The configured observer's rows, float (M, obs_size) (`jaxround.observe`)."""
        if self.observer == "paper":
            return observe.paper_observation(self.net, state, params)[0]
        return observe.rich_observation(self.net, state, params, self.route_destination)


def queued_per_leg(
    net: NetArrays, state: EnvState, t: jax.Array, temperature: jax.Array
) -> jax.Array:
    """Vehicles queued on each approach at time `t`, float (G,): halting there
    (speed below `dynamics.HALTING_SPEED`, as SUMO's getLastStepHaltingNumber)
    plus those due that wait to be inserted. Above temperature 0 (m/s) the
    halting test is smooth (`jaxround.relax`); insertion stays exact."""
    s = state.schedule
    n_legs = net.entry_lane.shape[0]
    _, lane, _ = geometry.locate(net, state.route, state.pos)
    on_entry = lane[None, :] == net.entry_lane[:, None]  # (G, M)
    slow = soft_step(dynamics.HALTING_SPEED - state.speed, temperature)
    halting = state.active * slow
    pending = ~state.inserted & (s.depart_s <= t + 1e-4)
    waiting = pending[None, :] & (s.origin[None, :] == jnp.arange(n_legs)[:, None])
    return jnp.sum(on_entry * halting[None, :], axis=1) + jnp.sum(waiting, axis=1)


def command_from_action(
    state: EnvState, action: jax.Array, params: EnvParams, dt: float
) -> jax.Array:
    """Each slot's speed command for this step, float (M,), NaN for none.

    An AV's ``action[:, 0]`` is an acceleration (m/s^2), sent as the speed
    command `jaxround.command.commanded_speed` (what the SUMO controller sends
    with ``setSpeed``); a NaN acceleration sends none, so the AV drives its
    vType as without a controller. Human drivers and empty slots get none.

    Args:
        state: the state at the start of the step.
        action: float (M, 2) the policy's action.
        params: the per-vehicle parameters (`EnvParams.for_vehicles`).
        dt: step length (s).
    """
    command = traci.commanded_speed(state.speed, action[:, 0], params, dt)
    return jnp.where(state.active & state.is_av, command, jnp.nan)


def check_driver_classes(cfg: ScenarioConfig) -> None:
    """The JAX environment drives both classes with the IDM and shares some of
    their numbers; a config that differs there gets a clear error."""
    hv, av = cfg.drivers.hv, cfg.drivers.av
    for name in SHARED_DRIVER_FIELDS:
        if getattr(hv, name) != getattr(av, name):
            raise ConfigError(
                f"drivers.av.{name}: {getattr(av, name)!r} differs from "
                f"drivers.hv.{name} {getattr(hv, name)!r}; the JAX environment "
                "drives both classes as an IDM with these numbers shared (AVs may "
                "differ in accel, tau, jm_timegap_minor, impatience, speed_dev)"
            )


def make(
    scenario: str | Path | ScenarioConfig = "milan",
    max_vehicles: int | None = None,
    episode_s: float | None = None,
    workdir: str | Path | None = None,
) -> tuple[RoundaboutEnv, EnvParams]:
    """Build the environment of a scenario: its network is compiled by netconvert.

    Args:
        scenario: a built-in name, a YAML path, or a `ScenarioConfig`.
        max_vehicles: vehicle slots M; None: the config's, else what the road holds.
        episode_s: episode length; default demand horizon + 300 s.
        workdir: where to write the SUMO network; a cache folder if None.

    Returns:
        (env, default params).
    """
    cfg = scenario if isinstance(scenario, ScenarioConfig) else load_config(scenario)
    net_path = network_file(cfg, workdir)
    env = RoundaboutEnv(
        cfg, compile_network(net_path, cfg.n_legs), max_vehicles, episode_s
    )
    return env, env.default_params


def network_file(cfg: ScenarioConfig, workdir: str | Path | None = None) -> Path:
    """The scenario's `.net.xml`, built once per network fingerprint and cached.

    The cache lives in ``$XDG_CACHE_HOME/jaxround/networks`` (``~/.cache`` by
    default); a network is built in a temporary folder and moved into place, so
    parallel processes never see half a file.
    """
    import os
    import tempfile

    from sumo_export.network import build_network

    if workdir is None:
        cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
        workdir = cache / "jaxround" / "networks" / f"{cfg.name}-{cfg.fingerprint()}"
    workdir = Path(workdir)
    path = workdir / f"{cfg.name}.net.xml"
    if not path.exists():
        workdir.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=workdir) as tmp:
            built = build_network(cfg.network, Path(tmp), cfg.name)
            os.replace(built, path)
    return path
