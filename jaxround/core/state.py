"""The three kinds of settings of the JAX environment: traced params, state, statics.

- `EnvParams`: continuous numbers a `vmap` may sweep (driver parameters,
  demand shares, penetration, reward weights).
- `EnvState`: fixed-size arrays: M vehicle slots with an `active` mask, the N
  vehicles of the episode's departure schedule, and running statistics.
- Static settings (max_vehicles, dt, the compiled network) live on the
  environment object (`jaxround.envs.roundabout.RoundaboutEnv`), never traced.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from jaxround.scenario.config import ScenarioConfig

#: The driver numbers in which AVs and human drivers differ.
PER_VEHICLE_FIELDS = ("accel", "tau", "jm_timegap_minor", "impatience")


@struct.dataclass
class EnvParams:
    """Traced parameters. Scalars unless a shape is given.

    Attributes:
        accel: maximum acceleration a (IDM), m/s^2.
        decel: comfortable deceleration b, m/s^2.
        emergency_decel: the bound on braking, m/s^2.
        tau: desired time headway T, s.
        min_gap: standstill gap s0, m.
        delta: IDM acceleration exponent.
        length: vehicle length, m.
        max_speed: vehicle maximum speed, m/s.
        jm_timegap_minor: gap an entering vehicle needs before a ring vehicle, s.
        impatience: base impatience, 0..1.
        time_to_impatience: waiting seconds that add 1 to the impatience.
        speed_dev: std of the desired-speed factor (drawn per vehicle at reset).
        penetration: share of AVs drawn at reset.
        origin_share: (n_legs,) share of vehicles entering at each leg.
        od: (n_legs, n_legs) exit shares per origin.
        duration_s: demand horizon over which the N departures are spread.
        av_accel, av_tau, av_jm_timegap_minor, av_impatience, av_speed_dev:
            the AVs' own values of these (their vType); the other driver
            numbers are shared by both classes.
        reward_speed_weight: AV reward: weight of the desired-velocity term.
        reward_pollution_weight: AV reward: weight of the pollution term.
        reward_time_penalty: AV reward: subtracted every step in the network.
        reward_time_weight: system reward: cost of a vehicle-second, per s.
        reward_co2_weight: system reward: cost of a gram of CO2, per g.
        relax_temperature: 0 runs the exact (SUMO-parity) dynamics; above 0,
            hard decisions become smooth so that gradients flow through them
            (`jaxround.core.relax`). Margins are divided by it in their own units
            (s for gap acceptance, m/s for halting, m for arrival).

    `for_vehicles(is_av)` gives the per-vehicle view the dynamics use.
    """

    accel: jax.Array
    decel: jax.Array
    emergency_decel: jax.Array
    tau: jax.Array
    min_gap: jax.Array
    delta: jax.Array
    length: jax.Array
    max_speed: jax.Array
    jm_timegap_minor: jax.Array
    impatience: jax.Array
    time_to_impatience: jax.Array
    speed_dev: jax.Array
    penetration: jax.Array
    origin_share: jax.Array
    od: jax.Array
    duration_s: jax.Array
    av_accel: jax.Array
    av_tau: jax.Array
    av_jm_timegap_minor: jax.Array
    av_impatience: jax.Array
    av_speed_dev: jax.Array
    reward_speed_weight: jax.Array
    reward_pollution_weight: jax.Array
    reward_time_penalty: jax.Array
    reward_time_weight: jax.Array
    reward_co2_weight: jax.Array
    relax_temperature: jax.Array

    @classmethod
    def from_config(cls, cfg: ScenarioConfig) -> EnvParams:
        """The traced numbers of a scenario (human drivers' vType)."""
        hv, av = cfg.drivers.hv, cfg.drivers.av
        f = jnp.float32
        return cls(
            accel=f(hv.accel),
            decel=f(hv.decel),
            emergency_decel=f(hv.emergency_decel),
            tau=f(hv.tau),
            min_gap=f(hv.min_gap),
            delta=f(hv.delta),
            length=f(hv.length),
            max_speed=f(hv.max_speed),
            jm_timegap_minor=f(hv.jm_timegap_minor),
            impatience=f(hv.impatience),
            time_to_impatience=f(180.0),
            speed_dev=f(hv.speed_dev),
            penetration=f(cfg.simulation.penetration),
            origin_share=jnp.asarray(cfg.demand.origin_share, jnp.float32),
            od=jnp.asarray(cfg.demand.od, jnp.float32),
            duration_s=f(cfg.demand.duration_s),
            av_accel=f(av.accel),
            av_tau=f(av.tau),
            av_jm_timegap_minor=f(av.jm_timegap_minor),
            av_impatience=f(av.impatience),
            av_speed_dev=f(av.speed_dev),
            reward_speed_weight=f(cfg.agent.speed_weight),
            reward_pollution_weight=f(cfg.agent.pollution_weight),
            reward_time_penalty=f(cfg.agent.time_penalty),
            reward_time_weight=f(cfg.agent.time_weight),
            reward_co2_weight=f(cfg.agent.co2_weight),
            relax_temperature=f(0.0),
        )

    def for_vehicles(self, is_av: jax.Array) -> EnvParams:
        """The parameters each vehicle drives with: accel, tau, jm_timegap_minor
        and impatience take the shape of `is_av` (their class's values)."""
        return self.replace(
            **{
                name: jnp.where(is_av, getattr(self, "av_" + name), getattr(self, name))
                for name in PER_VEHICLE_FIELDS
            }
        )

    def columns(self) -> EnvParams:
        """Per-vehicle fields (M,) as (M, 1), to broadcast against (M, K) arrays."""
        return self.replace(
            **{
                name: getattr(self, name)[..., None]
                for name in PER_VEHICLE_FIELDS
                if jnp.ndim(getattr(self, name)) >= 1
            }
        )


def _check(fields: dict[str, tuple[Any, tuple[int, ...], str]], where: str) -> None:
    """Raise ValueError unless each field has its trailing shape and its kind.

    `fields` maps a name to (array, expected trailing shape, dtype kind: "b"
    bool, "i" integer, "f" float). Leading axes (a vmapped batch, a time axis)
    are allowed and must be the same for every field.
    """
    batch = None
    for name, (value, trailing, kind) in fields.items():
        shape = tuple(jnp.shape(value))
        lead = shape[: len(shape) - len(trailing)]
        if len(shape) < len(trailing) or shape[len(lead) :] != trailing:
            raise ValueError(
                f"{where}.{name}: shape {shape}, expected (..., "
                f"{', '.join(map(str, trailing))})"
            )
        if batch is None:
            batch = lead
        elif lead != batch:
            raise ValueError(
                f"{where}.{name}: leading axes {lead}, the other fields have {batch}"
            )
        actual = jnp.result_type(value).kind
        if actual != kind and not (kind == "i" and actual == "u"):
            expected = {"b": "bool", "i": "int", "f": "float"}[kind]
            raise ValueError(
                f"{where}.{name}: dtype {jnp.result_type(value)}, expected {expected}"
            )


@struct.dataclass
class Schedule:
    """The N vehicles of an episode, sorted by departure. Arrays (N,).

    Attributes:
        depart_s: float scheduled departure times.
        route: int route index (see `CompiledNetwork.route_index`).
        origin: int entry leg.
        speed_factor: float desired-speed factor.
        is_av: bool vehicle class.
    """

    depart_s: jax.Array
    route: jax.Array
    origin: jax.Array
    speed_factor: jax.Array
    is_av: jax.Array

    def validate(self) -> None:
        """Check that every field is (..., N) with its dtype; ValueError if not."""
        n = jnp.shape(self.depart_s)[-1]
        _check(
            {
                "depart_s": (self.depart_s, (n,), "f"),
                "route": (self.route, (n,), "i"),
                "origin": (self.origin, (n,), "i"),
                "speed_factor": (self.speed_factor, (n,), "f"),
                "is_av": (self.is_av, (n,), "b"),
            },
            "Schedule",
        )


class Registrations(NamedTuple):
    """Approaches registered on the ring's through link of every leg. (M, G).

    Times are absolute (s); `ok` says the vehicle requests the link (it will
    drive it, has not reached it, is within its look-ahead, wants to pass).
    """

    ok: jax.Array
    dist: jax.Array
    arrival: jax.Array
    leave: jax.Array
    arrival_speed: jax.Array
    leave_speed: jax.Array
    braking_speed: jax.Array

    @classmethod
    def empty(cls, m: int, g: int) -> Registrations:
        z = jnp.zeros((m, g), jnp.float32)
        return cls(jnp.zeros((m, g), bool), z, z, z, z, z, z)


@struct.dataclass
class EnvState:
    """State of one roundabout. M = max_vehicles slots, N scheduled vehicles.

    Attributes:
        step: int, steps done since reset.
        active: bool (M,) slot holds a vehicle.
        vid: int (M,) schedule index of the slot's vehicle (-1 if empty).
        route: int (M,) route index.
        pos: float (M,) front position along the route, m.
        speed: float (M,) m/s.
        accel: float (M,) acceleration held between action points, m/s^2.
        is_av: bool (M,).
        speed_factor: float (M,).
        waiting_s: float (M,) consecutive seconds below 0.1 m/s.
        co2_mg: float (M,) CO2 emitted so far.
        fuel_mg: float (M,) fuel used so far.
        schedule: the episode's `Schedule` (N,).
        inserted: bool (N,) the vehicle has entered the network.
        insert_s: float (N,) insertion time (nan before).
        arrival_s: float (N,) arrival time (nan before).
        trip_co2_mg: float (N,) CO2 of finished trips.
        trip_fuel_mg: float (N,) fuel of finished trips.
        queue_sum: float (n_legs,) sum over steps of queued vehicles per leg.
        queue_max: float (n_legs,) largest queue per leg.
        queue_samples: int, steps summed into `queue_sum` (within the horizon).
        overflow: int, insertions postponed because every slot was full.
        collisions: int, vehicles that ran into the one ahead (0 by design;
            counted so evaluations can show it).
        registrations: the approaches each slot registered on the ring's
            through links in the last step, (M, G) arrays (SUMO plans with
            the previous step's registrations).
    """

    step: jax.Array
    active: jax.Array
    vid: jax.Array
    route: jax.Array
    pos: jax.Array
    speed: jax.Array
    accel: jax.Array
    is_av: jax.Array
    speed_factor: jax.Array
    waiting_s: jax.Array
    co2_mg: jax.Array
    fuel_mg: jax.Array
    schedule: Schedule
    inserted: jax.Array
    insert_s: jax.Array
    arrival_s: jax.Array
    trip_co2_mg: jax.Array
    trip_fuel_mg: jax.Array
    queue_sum: jax.Array
    queue_max: jax.Array
    queue_samples: jax.Array
    overflow: jax.Array
    collisions: jax.Array
    registrations: Registrations

    def validate(self) -> None:
        """Check shapes and dtypes: per-slot fields (..., M), per-vehicle fields
        (..., N), queue fields (..., G), registrations (..., M, G), counters
        (...,), the same leading axes everywhere; ValueError naming the field.

        Call it outside `jit` (it reads shapes only, so it works on traced
        values too, but raises at trace time)."""
        m = jnp.shape(self.active)[-1]
        n = jnp.shape(self.inserted)[-1]
        g = jnp.shape(self.queue_sum)[-1]
        self.schedule.validate()
        fields: dict[str, tuple[Any, tuple[int, ...], str]] = {
            "step": (self.step, (), "i"),
            "active": (self.active, (m,), "b"),
            "vid": (self.vid, (m,), "i"),
            "route": (self.route, (m,), "i"),
            "is_av": (self.is_av, (m,), "b"),
            "inserted": (self.inserted, (n,), "b"),
            "queue_samples": (self.queue_samples, (), "i"),
            "overflow": (self.overflow, (), "i"),
            "collisions": (self.collisions, (), "i"),
            "schedule.depart_s": (self.schedule.depart_s, (n,), "f"),
            "registrations.ok": (self.registrations.ok, (m, g), "b"),
        }
        for name in ("pos", "speed", "accel", "speed_factor", "waiting_s", "co2_mg",
                     "fuel_mg"):  # fmt: skip
            fields[name] = (getattr(self, name), (m,), "f")
        for name in ("insert_s", "arrival_s", "trip_co2_mg", "trip_fuel_mg"):
            fields[name] = (getattr(self, name), (n,), "f")
        for name in ("queue_sum", "queue_max"):
            fields[name] = (getattr(self, name), (g,), "f")
        for name in Registrations._fields[1:]:
            fields[f"registrations.{name}"] = (
                getattr(self.registrations, name), (m, g), "f",
            )  # fmt: skip
        _check(fields, "EnvState")
