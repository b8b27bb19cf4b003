"""The traced numbers of the JAX environment, grouped by what they describe.

`EnvParams` holds continuous numbers a `vmap` may sweep:

- `human`, `av`: each driver class's own numbers (`DriverParams`, from the
  scenario's `drivers.hv` and `drivers.av` vTypes);
- `vehicle`: the body and braking both classes share (`VehicleParams`);
- `demand`: where vehicles come from and go, and the AV share (`DemandParams`);
- `reward`: the weights of the AVs' rewards (`RewardParams`);
- `relax_temperature`: 0 for the exact (SUMO-parity) step.

The dynamics never read `EnvParams` directly: `EnvParams.for_vehicles(is_av)`
gives them one `CarFollowing` bundle, each vehicle with its class's numbers.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from jaxround.core.idm import IDMParams
from jaxround.core.lane_change_params import LaneChangeParams
from jaxround.scenario.config import SHARED_DRIVER_FIELDS, DriverConfig, ScenarioConfig

#: Seconds of waiting that add 1 to a driver's impatience (SUMO's
#: `MSVehicle::getImpatience`, time-to-impatience default 180 s).
TIME_TO_IMPATIENCE_S = 180.0


@struct.dataclass
class DriverParams:
    """The numbers in which the two driver classes' vTypes differ. Scalars.

    Attributes:
        accel: maximum acceleration a (IDM), m/s^2.
        tau: desired time headway T, s.
        jm_timegap_minor: gap an entering vehicle needs before a ring vehicle, s.
        impatience: base impatience, 0..1.
        speed_dev: std of the desired-speed factor (drawn per vehicle at reset).
    """

    accel: jax.Array
    tau: jax.Array
    jm_timegap_minor: jax.Array
    impatience: jax.Array
    speed_dev: jax.Array


@struct.dataclass
class VehicleParams:
    """Body and braking, one set for both classes (the JAX step has a single
    vehicle length and braking model; `RoundaboutEnv` refuses a scenario whose
    vTypes differ in them). Scalars.

    Attributes:
        decel: comfortable deceleration b, m/s^2.
        emergency_decel: the bound on braking, m/s^2.
        min_gap: standstill gap s0, m.
        delta: IDM acceleration exponent.
        length: vehicle length, m.
        max_speed: vehicle maximum speed, m/s.
        time_to_impatience: waiting seconds that add 1 to the impatience.
    """

    decel: jax.Array
    emergency_decel: jax.Array
    min_gap: jax.Array
    delta: jax.Array
    length: jax.Array
    max_speed: jax.Array
    time_to_impatience: jax.Array


@struct.dataclass
class DemandParams:
    """The departures drawn at reset.

    Attributes:
        penetration: share of AVs, scalar.
        origin_share: (n_legs,) share of vehicles entering at each leg.
        od: (n_legs, n_legs) exit shares per origin.
        duration_s: demand horizon over which the N departures are spread.
    """

    penetration: jax.Array
    origin_share: jax.Array
    od: jax.Array
    duration_s: jax.Array


@struct.dataclass
class RewardParams:
    """Weights of the AVs' rewards (`jaxround.envs.reward`). Scalars.

    Attributes:
        speed_weight: paper reward: weight of the desired-velocity term.
        pollution_weight: paper reward: weight of the pollution term.
        time_penalty: paper reward: subtracted every step in the network.
        time_weight: system reward: cost of a vehicle-second, per s.
        co2_weight: system reward: cost of a gram of CO2, per g.
        conflict_weight: system reward: cost of a near-conflict, per vehicle
            of the pair (`jaxround.core.surrogate_safety`).
    """

    speed_weight: jax.Array
    pollution_weight: jax.Array
    time_penalty: jax.Array
    time_weight: jax.Array
    co2_weight: jax.Array
    conflict_weight: jax.Array


@struct.dataclass
class CarFollowing:
    """What each vehicle drives with: the one bundle the dynamics read.

    `accel`, `tau`, `jm_timegap_minor` and `impatience` are (M,) (each vehicle
    its class's value; scalars also work); the others are scalars.
    `relax_temperature`: 0 runs the exact dynamics; above 0, hard decisions
    become smooth so that gradients flow through them (`jaxround.core.relax`).
    Margins are divided by it in their own units (s for gap acceptance, m/s
    for halting, m for arrival).
    """

    accel: jax.Array
    tau: jax.Array
    jm_timegap_minor: jax.Array
    impatience: jax.Array
    decel: jax.Array
    emergency_decel: jax.Array
    min_gap: jax.Array
    delta: jax.Array
    length: jax.Array
    max_speed: jax.Array
    time_to_impatience: jax.Array
    relax_temperature: jax.Array

    @property
    def idm(self) -> IDMParams:
        """The IDM's numbers of each vehicle (`jaxround.core.idm`)."""
        return IDMParams(self.accel, self.decel, self.tau, self.min_gap, self.delta)

    def columns(self) -> CarFollowing:
        """Per-vehicle fields (M,) as (M, 1), to broadcast against (M, K) arrays."""
        return self.replace(
            **{
                name: getattr(self, name)[..., None]
                for name in PER_CLASS_FIELDS
                if jnp.ndim(getattr(self, name)) >= 1
            }
        )


#: The car-following numbers each vehicle takes from its own class.
PER_CLASS_FIELDS = ("accel", "tau", "jm_timegap_minor", "impatience")


@struct.dataclass
class EnvParams:
    """Traced parameters of one roundabout (a vmapped batch adds leading axes).

    Attributes:
        human: the human drivers' `DriverParams` (vType `drivers.hv`).
        av: the AVs' `DriverParams` (vType `drivers.av`); the policy acts on top.
        vehicle: `VehicleParams` both classes share.
        demand: `DemandParams` of the departures drawn at reset.
        reward: `RewardParams` of the AVs' rewards.
        relax_temperature: 0 for the exact step (see `CarFollowing`).
        lane_change: LC2013's `LaneChangeParams` of both classes on a
            roundabout with two-lane roads (SUMO's defaults: the config has
            no lane-change keys yet); None on one-lane roads.
    """

    human: DriverParams
    av: DriverParams
    vehicle: VehicleParams
    demand: DemandParams
    reward: RewardParams
    relax_temperature: jax.Array
    lane_change: LaneChangeParams | None

    @classmethod
    def from_config(cls, cfg: ScenarioConfig) -> EnvParams:
        """The traced numbers of a scenario."""
        f = jnp.float32
        hv = cfg.drivers.hv

        def driver(vtype: DriverConfig) -> DriverParams:
            return DriverParams(
                **{n: f(getattr(vtype, n)) for n in _names(DriverParams)}
            )

        vehicle = {name: f(getattr(hv, name)) for name in SHARED_DRIVER_FIELDS}
        return cls(
            human=driver(hv),
            av=driver(cfg.drivers.av),
            vehicle=VehicleParams(
                **vehicle, time_to_impatience=f(TIME_TO_IMPATIENCE_S)
            ),
            demand=DemandParams(
                penetration=f(cfg.simulation.penetration),
                origin_share=jnp.asarray(cfg.demand.origin_share, jnp.float32),
                od=jnp.asarray(cfg.demand.od, jnp.float32),
                duration_s=f(cfg.demand.duration_s),
            ),
            reward=RewardParams(
                speed_weight=f(cfg.agent.speed_weight),
                pollution_weight=f(cfg.agent.pollution_weight),
                time_penalty=f(cfg.agent.time_penalty),
                time_weight=f(cfg.agent.time_weight),
                co2_weight=f(cfg.agent.co2_weight),
                conflict_weight=f(cfg.agent.conflict_weight),
            ),
            relax_temperature=f(0.0),
            lane_change=None
            if cfg.network.single_lane
            else jax.tree.map(f, LaneChangeParams()),
        )

    def for_vehicles(self, is_av: jax.Array) -> CarFollowing:
        """Each vehicle's car-following numbers: the per-class fields take the
        shape of `is_av` (bool, e.g. (M,)), the shared ones stay scalars."""
        per_class = {
            name: jnp.where(is_av, getattr(self.av, name), getattr(self.human, name))
            for name in PER_CLASS_FIELDS
        }
        shared = {name: getattr(self.vehicle, name) for name in _names(VehicleParams)}
        return CarFollowing(
            **per_class, **shared, relax_temperature=self.relax_temperature
        )

    def with_human(self, **values: jax.Array) -> EnvParams:
        """A copy with these human-driver numbers replaced; names of
        `DriverParams` go to `human`, names of `VehicleParams` (shared by both
        classes, as in `ScenarioConfig.with_human_drivers`) to `vehicle`.
        E.g. ``params.with_human(accel=2.0, decel=4.0)``."""
        own = {k: v for k, v in values.items() if k in _names(DriverParams)}
        body = {k: v for k, v in values.items() if k in _names(VehicleParams)}
        unknown = set(values) - set(own) - set(body)
        if unknown:
            known = _names(DriverParams) + _names(VehicleParams)
            raise ValueError(
                f"with_human: unknown driver number(s) {sorted(unknown)}; "
                f"known: {', '.join(known)}"
            )
        return self.replace(
            human=self.human.replace(**own), vehicle=self.vehicle.replace(**body)
        )

    def with_penetration(self, share: float | jax.Array) -> EnvParams:
        """A copy whose schedules draw this share of AVs (a scalar, or one per
        roundabout of a batch)."""
        share = jnp.asarray(share, jnp.float32)
        return self.replace(demand=self.demand.replace(penetration=share))

    def human_number(self, name: str) -> jax.Array:
        """A human-driver number by name, from `human` or the shared `vehicle`."""
        part = self.human if name in _names(DriverParams) else self.vehicle
        if name not in _names(type(part)):
            raise ValueError(f"human_number: unknown driver number {name!r}")
        return getattr(part, name)


def _names(cls: type) -> tuple[str, ...]:
    """The field names of a params dataclass, in order."""
    return tuple(field.name for field in dataclasses.fields(cls))
