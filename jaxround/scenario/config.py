"""Scenario configuration: one YAML file describes a roundabout, its demand and drivers.

The same `ScenarioConfig` drives both simulators. It is parsed strictly: an
unknown key, a value of the wrong type or out of range raises `ConfigError`
naming the field (for example ``demand.od[1]: row sums to 0.9, expected 1``)
before anything runs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from jaxround.scenario.loader import (
    ConfigError,
    check_distribution,
    check_non_negative,
    check_positive,
    check_share,
    dataclass_from_dict,
    read_yaml,
)
from jaxround.scenario.roads import LegConfig, NetworkConfig
from jaxround.scenario.safety import SafetyConfig


@dataclass(frozen=True)
class DemandConfig:
    """How many vehicles leave from where to where within the horizon."""

    n_vehicles: int  # exact number of vehicles inserted in the horizon
    duration_s: float  # horizon over which departures are spread
    origin_share: tuple[float, ...]  # share of vehicles entering from each leg
    od: tuple[
        tuple[float, ...], ...
    ]  # od[i][j]: share of leg i's vehicles leaving at j

    def validate(self, where: str, n_legs: int) -> None:
        if self.n_vehicles < 1:
            raise ConfigError(f"{where}.n_vehicles: {self.n_vehicles}, expected >= 1")
        check_positive(self.duration_s, f"{where}.duration_s")
        check_distribution(self.origin_share, f"{where}.origin_share", n_legs)
        if len(self.od) != n_legs:
            raise ConfigError(f"{where}.od: {len(self.od)} rows, expected {n_legs}")
        for i, row in enumerate(self.od):
            check_distribution(row, f"{where}.od[{i}]", n_legs)
            if row[i] != 0.0:
                raise ConfigError(
                    f"{where}.od[{i}][{i}]: {row[i]}; U-turns are not modelled, use 0"
                )


@dataclass(frozen=True)
class DriverConfig:
    """A SUMO vType: car-following model and its parameters (SUMO names in comments)."""

    car_follow_model: str  # carFollowModel: "IDM" (human drivers) or "Krauss"
    accel: float  # accel, m/s^2
    decel: float  # decel, m/s^2
    emergency_decel: float  # emergencyDecel, m/s^2
    tau: float  # tau, desired time headway, s
    min_gap: float  # minGap, m
    delta: float  # IDM acceleration exponent
    sigma: float  # Krauss driver imperfection; 0 for a deterministic vehicle
    length: float  # length, m
    max_speed: float  # maxSpeed, m/s
    speed_dev: float  # speedDev: std of the desired-speed factor
    action_step_length: (
        float  # actionStepLength, s (SUMO floors it to a multiple of dt)
    )
    jm_timegap_minor: float  # jmTimegapMinor, s
    impatience: float  # impatience, 0..1
    jm_crossing_gap: float  # jmCrossingGap, m (pedestrian crossings only)
    emission_class: str  # emissionClass

    def validate(self, where: str) -> None:
        if self.car_follow_model not in ("IDM", "Krauss"):
            raise ConfigError(
                f"{where}.car_follow_model: {self.car_follow_model!r}, "
                "expected 'IDM' or 'Krauss'"
            )
        for name in (
            "accel",
            "decel",
            "emergency_decel",
            "tau",
            "length",
            "max_speed",
            "delta",
            "action_step_length",
        ):
            check_positive(getattr(self, name), f"{where}.{name}")
        for name in (
            "min_gap",
            "sigma",
            "speed_dev",
            "jm_timegap_minor",
            "jm_crossing_gap",
        ):
            check_non_negative(getattr(self, name), f"{where}.{name}")
        if not 0.0 <= self.impatience <= 1.0:
            raise ConfigError(f"{where}.impatience: {self.impatience}, expected [0, 1]")
        if not 0.0 <= self.sigma <= 1.0:
            raise ConfigError(f"{where}.sigma: {self.sigma}, expected [0, 1]")
        if self.emergency_decel < self.decel:
            raise ConfigError(
                f"{where}.emergency_decel: {self.emergency_decel} is below decel "
                f"{self.decel}"
            )


#: The vType numbers the JAX environment shares between the two classes (one
#: vehicle body and braking model, `jaxround.core.params.VehicleParams`); it
#: refuses a scenario whose AVs differ in them (SUMO alone accepts it).
SHARED_DRIVER_FIELDS = ("decel", "emergency_decel", "min_gap", "delta", "length",
                        "max_speed")  # fmt: skip


@dataclass(frozen=True)
class DriversConfig:
    """Vehicle types of the two classes."""

    hv: DriverConfig  # human-driven vehicles
    av: DriverConfig  # autonomous vehicles (their policy acts on top of this vType)


@dataclass(frozen=True)
class SimulationConfig:
    """Time step and the defaults a run starts from."""

    dt_s: float  # simulation step length, s
    penetration: float  # share of AVs, 0..1
    seed: int  # seed of the departure schedule
    # JAX vehicle slots M; null: what the scenario's traffic needs
    # (`jaxround.envs.slots`; max_vehicles="road" in `make`: what the road holds)
    max_vehicles: int | None = None

    def validate(self, where: str) -> None:
        check_positive(self.dt_s, f"{where}.dt_s")
        check_share(self.penetration, f"{where}.penetration")
        if self.seed < 0:
            raise ConfigError(f"{where}.seed: {self.seed}, expected >= 0")
        if self.max_vehicles is not None and self.max_vehicles < 1:
            raise ConfigError(
                f"{where}.max_vehicles: {self.max_vehicles}, expected >= 1, or "
                "null for what the traffic needs"
            )


#: Simulated seconds after the demand horizon that parity and evaluation give
#: the last vehicles to leave, in both simulators (the cap they report).
DRAIN_S = 1800.0


#: Observers of the AV policy (`jaxround.envs.observe`).
OBSERVERS = ("paper", "rich", "lanes")
#: The AVs' rewards (`jaxround.envs.reward`).
REWARDS = ("paper", "system")
#: What an AV's action means (`jaxround.envs.roundabout.RoundaboutEnv.step_env`).
ACTIONS = ("accel", "assertiveness")


@dataclass(frozen=True)
class AgentConfig:
    """What an AV's policy sees and is rewarded for (`envs.observe`, `envs.reward`)."""

    observer: str = "rich"  # "paper" (Eq. 1, 10), "rich" (Eq. 1 + 7), "lanes" (+ 7)
    reward: str = "paper"  # "paper" (Eq. 3) or "system" (time and CO2 of all)
    action: str = "accel"  # "accel" (a speed command) or "assertiveness" (vType)
    speed_weight: float = 1.0  # paper: weight of the desired-velocity term of Eq. 3
    pollution_weight: float = 1.0  # paper: weight of the pollution term of Eq. 3
    time_penalty: float = 1.0  # paper: subtracted per step (0: Eq. 3 exactly)
    time_weight: float = 1.0  # system: cost of one vehicle-second in the system
    co2_weight: float = 0.5  # system: cost of one gram of CO2
    # system: cost of one near-conflict, per vehicle of the pair (SUMO's SSM)
    conflict_weight: float = 0.0
    share: float = (
        0.5  # system: weight of all vehicles' cost (1) against the AV's own (0)
    )

    def validate(self, where: str) -> None:
        if self.observer not in OBSERVERS:
            raise ConfigError(
                f"{where}.observer: {self.observer!r}, expected one of {OBSERVERS}"
            )
        if self.action not in ACTIONS:
            raise ConfigError(
                f"{where}.action: {self.action!r}, expected one of {ACTIONS}"
            )
        if self.reward not in REWARDS:
            raise ConfigError(
                f"{where}.reward: {self.reward!r}, expected one of {REWARDS}"
            )
        check_share(self.share, f"{where}.share")
        for name in ("speed_weight", "pollution_weight", "time_penalty",
                     "time_weight", "co2_weight", "conflict_weight"):  # fmt: skip
            check_non_negative(getattr(self, name), f"{where}.{name}")
        if self.speed_weight + self.pollution_weight <= 0:
            raise ConfigError(f"{where}: speed_weight + pollution_weight must be > 0")


@dataclass(frozen=True)
class ScenarioConfig:
    """Everything both simulators need to run the same roundabout."""

    name: str  # scenario name, used for file names
    network: NetworkConfig
    demand: DemandConfig
    drivers: DriversConfig
    simulation: SimulationConfig
    agent: AgentConfig = AgentConfig()  # the AVs' observer and reward
    safety: SafetyConfig = SafetyConfig()  # near-conflicts, the AVs' tau floor
    description: str = ""  # free text

    def validate(self) -> None:
        if not self.name or not self.name.replace("_", "").replace("-", "").isalnum():
            raise ConfigError(f"name: {self.name!r} must be letters, digits, _ or -")
        self.network.validate("network")
        self.demand.validate("demand", len(self.network.legs))
        self.drivers.hv.validate("drivers.hv")
        self.drivers.av.validate("drivers.av")
        self.simulation.validate("simulation")
        self.agent.validate("agent")
        self.safety.validate("safety")
        if self.demand.duration_s < self.simulation.dt_s:
            raise ConfigError(
                "demand.duration_s: shorter than one step (simulation.dt_s)"
            )

    @property
    def n_legs(self) -> int:
        return len(self.network.legs)

    def with_overrides(self, **simulation: Any) -> ScenarioConfig:
        """A validated copy with these `simulation` fields replaced."""
        unknown = set(simulation) - {
            f.name for f in dataclasses.fields(SimulationConfig)
        }
        if unknown:
            raise ConfigError(f"simulation: unknown override(s) {sorted(unknown)}")
        new = dataclasses.replace(
            self, simulation=dataclasses.replace(self.simulation, **simulation)
        )
        new.validate()
        return new

    def with_human_drivers(self, **values: float) -> ScenarioConfig:
        """A validated copy with these human-driver (`drivers.hv`) numbers
        replaced, e.g. ``with_human_drivers(accel=2.0, tau=1.1)``. Numbers of
        `SHARED_DRIVER_FIELDS` change for the AVs too."""
        unknown = set(values) - {f.name for f in dataclasses.fields(DriverConfig)}
        if unknown:
            raise ConfigError(f"drivers.hv: unknown field(s) {sorted(unknown)}")
        numbers = {k: float(v) for k, v in values.items()}
        shared = {k: v for k, v in numbers.items() if k in SHARED_DRIVER_FIELDS}
        drivers = DriversConfig(
            hv=dataclasses.replace(self.drivers.hv, **numbers),
            av=dataclasses.replace(self.drivers.av, **shared),
        )
        new = dataclasses.replace(self, drivers=drivers)
        new.validate()
        return new

    def to_dict(self) -> dict[str, Any]:
        """The plain data of the scenario (lane counts of 1 left out, as in
        `NetworkConfig.to_dict`); `config_from_dict` builds it back."""
        d = dataclasses.asdict(self)
        d["network"] = self.network.to_dict()
        return d

    def roads_and_drivers_fingerprint(self) -> str:
        """Short hash of what a trained policy depends on: network, drivers, dt
        (not demand, seed, penetration or the observer, which a policy names)."""
        d = {"network": self.to_dict()["network"], "drivers": self.to_dict()["drivers"]}
        d["dt_s"] = self.simulation.dt_s
        blob = json.dumps(d, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def fingerprint(self) -> str:
        """Short hash of network, demand and drivers (not of seed or penetration)."""
        d = self.to_dict()
        d.pop("simulation")
        d.pop("description")
        d.pop("agent")
        d.pop("safety")
        d["dt_s"] = self.simulation.dt_s
        blob = json.dumps(d, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


#: Files in `configs` whose name starts so are trainer configs, not scenarios.
TRAINER_PREFIXES = ("ppo_", "apg_")


def builtin_configs() -> list[str]:
    """Names of the scenarios shipped in the `configs` package."""
    files = resources.files("configs").iterdir()
    return sorted(
        p.name[:-5]
        for p in files
        if p.name.endswith(".yaml") and not p.name.startswith(TRAINER_PREFIXES)
    )


def load_config(source: str | Path | None = None) -> ScenarioConfig:
    """Load and validate a scenario.

    Args:
        source: a path to a YAML file, or the name of a built-in scenario
            (``"milan"``); None gives the built-in default, ``"milan"``.

    Returns:
        The validated `ScenarioConfig`.

    Raises:
        ConfigError: the file is missing, not YAML, or a field is wrong.
    """
    source = "milan" if source is None else source
    return config_from_dict(read_yaml(source, builtin_configs(), "scenario"))


def config_from_dict(data: Any) -> ScenarioConfig:
    """Build and validate a `ScenarioConfig` from plain data (as parsed from YAML)."""
    cfg = dataclass_from_dict(ScenarioConfig, data, "config")
    cfg.validate()
    return cfg


__all__ = [
    "AgentConfig",
    "DRAIN_S",
    "ConfigError",
    "DemandConfig",
    "DriverConfig",
    "DriversConfig",
    "LegConfig",
    "NetworkConfig",
    "ScenarioConfig",
    "SafetyConfig",
    "SimulationConfig",
    "builtin_configs",
    "config_from_dict",
    "load_config",
]
