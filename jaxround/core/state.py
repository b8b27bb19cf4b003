"""The state of the JAX environment: fixed-size arrays, with `validate()`.

- `EnvState`: M vehicle slots with an `active` mask, the N vehicles of the
  episode's departure `Schedule`, and running statistics.
- Traced numbers a `vmap` may sweep are `jaxround.core.params.EnvParams`;
  static settings (max_vehicles, dt, the compiled network) live on the
  environment object (`jaxround.envs.roundabout.RoundaboutEnv`), never traced.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from jaxround.core.surrogate_safety import NO_TTC_S


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


def leg_order(origin: jax.Array, n_legs: int) -> jax.Array:
    """Each leg's vehicles as schedule indices in schedule (departure) order,
    int (G, N) padded with N, from the schedule's origins, int (N,)."""
    n = origin.shape[-1]
    mine = origin[None, :] == jnp.arange(n_legs)[:, None]  # (G, N)
    rank = jnp.where(mine, jnp.cumsum(mine, axis=1) - 1, n)  # place within its leg
    legs = jnp.broadcast_to(jnp.arange(n_legs)[:, None], mine.shape)
    table = jnp.full((n_legs, n), n, jnp.int32)
    return table.at[legs, rank].set(
        jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32), mine.shape), mode="drop"
    )


class Registrations(NamedTuple):
    """Approaches registered on the ring's through link of every entry. (M, G).

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
class EpisodeStats:
    """What an episode has measured so far, kept apart from the physical state:
    the environment adds to it every step, and nothing in the step reads it.

    Attributes:
        trip_co2_mg: float (N,) CO2 of finished trips.
        trip_fuel_mg: float (N,) fuel of finished trips.
        queue_sum: float (n_legs,) sum over steps of queued vehicles per leg
            (`jaxround.envs.queues.queued_per_leg`).
        queue_max: float (n_legs,) largest queue per leg.
        queue_samples: int, steps summed into `queue_sum` (within the horizon).
        overflow: int, insertions postponed because every slot was full
            (vehicle-steps).
        collisions: int, vehicles that ran into the one ahead (0 by design;
            counted so evaluations can show it).
        conflicts: int (N,) near-conflicts each vehicle was part of, as
            SUMO's SSM device counts them (`jaxround.core.surrogate_safety`).
        min_ttc_s: float (N,) the smallest time to collision of each vehicle,
            as follower or leader (`surrogate_safety.NO_TTC_S`: never
            closing in).
        max_drac_mps2: float (N,) the largest deceleration to avoid a crash.
        encounter_leader: int (M,) the vehicle each slot's current following
            encounter is with (-1: none).
        encounter_conflict: bool (M,) that encounter is a conflict already.
    """

    trip_co2_mg: jax.Array
    trip_fuel_mg: jax.Array
    queue_sum: jax.Array
    queue_max: jax.Array
    queue_samples: jax.Array
    overflow: jax.Array
    collisions: jax.Array
    conflicts: jax.Array
    min_ttc_s: jax.Array
    max_drac_mps2: jax.Array
    encounter_leader: jax.Array
    encounter_conflict: jax.Array

    @classmethod
    def zeros(cls, n: int, n_legs: int, m: int) -> EpisodeStats:
        """Nothing measured yet: N scheduled vehicles, `n_legs` legs, M slots."""
        zero = jnp.int32(0)
        trips, legs = jnp.zeros(n, jnp.float32), jnp.zeros(n_legs, jnp.float32)
        return cls(
            trips, trips, legs, legs, zero, zero, zero,
            conflicts=jnp.zeros(n, jnp.int32),
            min_ttc_s=jnp.full(n, NO_TTC_S, jnp.float32),
            max_drac_mps2=jnp.zeros(n, jnp.float32),
            encounter_leader=-jnp.ones(m, jnp.int32),
            encounter_conflict=jnp.zeros(m, bool),
        )  # fmt: skip

    def fields(
        self, n: int, n_legs: int, m: int
    ) -> dict[str, tuple[Any, tuple[int, ...], str]]:
        """`_check`'s table of these fields, named ``stats.<field>``."""
        table: dict[str, tuple[Any, tuple[int, ...], str]] = {}
        for name in ("trip_co2_mg", "trip_fuel_mg", "min_ttc_s", "max_drac_mps2"):
            table[name] = (getattr(self, name), (n,), "f")
        table["conflicts"] = (self.conflicts, (n,), "i")
        table["encounter_leader"] = (self.encounter_leader, (m,), "i")
        table["encounter_conflict"] = (self.encounter_conflict, (m,), "b")
        for name in ("queue_sum", "queue_max"):
            table[name] = (getattr(self, name), (n_legs,), "f")
        for name in ("queue_samples", "overflow", "collisions"):
            table[name] = (getattr(self, name), (), "i")
        return {f"stats.{name}": entry for name, entry in table.items()}


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
        leg_vehicles: int (G, N) each leg's vehicles, as schedule indices in
            departure order, padded with N (`leg_order`): insertion and the
            queues read each leg's next vehicles here, not all N.
        leg_inserted: int (G,) how many of each leg's vehicles have entered
            (so ``leg_vehicles[g, leg_inserted[g]]`` is the next to enter).
        insert_s: float (N,) insertion time (nan before).
        arrival_s: float (N,) arrival time (nan before).
        registrations: the approaches each slot registered on the ring's
            through links in the last step, (M, G) arrays (SUMO plans with
            the previous step's registrations).
        stats: the episode's `EpisodeStats` (trip emissions, queues, slot
            overflow, collisions).
        lanes: on roundabouts with two-lane roads, what lane changing
            keeps (`jaxround.envs.lane_changes.LaneState`); None elsewhere.
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
    leg_vehicles: jax.Array
    leg_inserted: jax.Array
    insert_s: jax.Array
    arrival_s: jax.Array
    registrations: Registrations
    stats: EpisodeStats
    lanes: Any = None

    def validate(self) -> None:
        """Check shapes and dtypes: per-slot fields (..., M), per-vehicle fields
        (..., N), per-entry fields (..., G), registrations (..., M, G), the
        queues (..., n_legs) with n_legs <= G, counters (...,), the same
        leading axes everywhere; ValueError naming the field.

        Call it outside `jit` (it reads shapes only, so it works on traced
        values too, but raises at trace time)."""
        m = jnp.shape(self.active)[-1]
        n = jnp.shape(self.inserted)[-1]
        g = jnp.shape(self.registrations.ok)[-1]
        self.schedule.validate()
        fields: dict[str, tuple[Any, tuple[int, ...], str]] = {
            "step": (self.step, (), "i"),
            "active": (self.active, (m,), "b"),
            "vid": (self.vid, (m,), "i"),
            "route": (self.route, (m,), "i"),
            "is_av": (self.is_av, (m,), "b"),
            "inserted": (self.inserted, (n,), "b"),
            "leg_vehicles": (self.leg_vehicles, (g, n), "i"),
            "leg_inserted": (self.leg_inserted, (g,), "i"),
            "schedule.depart_s": (self.schedule.depart_s, (n,), "f"),
            "registrations.ok": (self.registrations.ok, (m, g), "b"),
        }
        for name in ("pos", "speed", "accel", "speed_factor", "waiting_s", "co2_mg",
                     "fuel_mg"):  # fmt: skip
            fields[name] = (getattr(self, name), (m,), "f")
        for name in ("insert_s", "arrival_s"):
            fields[name] = (getattr(self, name), (n,), "f")
        # legs: queue_max's (a two-lane entry is two entries G of one leg)
        n_legs = jnp.shape(self.stats.queue_max)[-1]
        if not 0 < n_legs <= g:
            raise ValueError(
                f"EnvState.stats.queue_max: {n_legs} legs, expected 1 to {g} (G)"
            )
        fields.update(self.stats.fields(n, n_legs, m))
        for name in Registrations._fields[1:]:
            fields[f"registrations.{name}"] = (
                getattr(self.registrations, name), (m, g), "f",
            )  # fmt: skip
        _check(fields, "EnvState")
