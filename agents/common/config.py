"""Trainer settings: one frozen dataclass per algorithm, loaded strictly from YAML.

    cfg = load_ppo_config("ppo_milan")          # or a path to a YAML file
    cfg = cfg.replace(seed=3, total_env_steps=10_000)
    scenario = cfg.training_scenario()          # the short training episodes
    apg = load_apg_config("apg_milan")          # the analytic-gradient trainer

``n_envs: auto`` sizes the batch to the device (`agents.common.device_batch`).

An unknown key, a value of the wrong type or out of range raises
`jaxround.scenario.config.ConfigError` naming the field (``lr: -0.1, expected > 0``)
before anything runs. Derived numbers (`num_updates`, `minibatch_size`) are
properties, never stored. `PPOConfig` and `APGConfig` share the scenario
fields and their checks (`TrainerConfig`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import yaml

from agents.common.constraint_config import ConflictConstraintConfig
from agents.common.device_batch import AUTO, DeviceChoice, size_for_device, this_device
from jaxround.scenario.config import (
    ACTIONS,
    OBSERVERS,
    REWARDS,
    ScenarioConfig,
    config_from_dict,
)
from jaxround.scenario.config import load_config as load_scenario
from jaxround.scenario.loader import ConfigError, dataclass_from_dict, read_yaml

#: Activations of the policy and value MLPs.
ACTIVATIONS = ("tanh", "relu")
Config = TypeVar("Config", bound="TrainerConfig")


#: The scenario's agent fields a trainer config may set ('' keeps the scenario's).
AGENT_FIELDS = {"observer": OBSERVERS, "action": ACTIONS, "reward": REWARDS}


class TrainerConfig:
    """What the trainers' configs share: the scenario fields' checks, YAML and
    the training scenario. Subclasses are frozen dataclasses with the fields
    `scenario`, `demand_window_s`, `episode_s`, `max_vehicles`, `penetrations`,
    `observer`, `n_envs`, `total_env_steps`, `hidden`, `activation`,
    `checkpoint_every`, `keep_checkpoints` and `seed`, and a property
    `env_steps_per_update`."""

    #: Name in error messages and file names ("PPO": ``ppo_*.yaml``).
    KIND: ClassVar[str] = ""

    @property
    def num_updates(self) -> int:
        """Updates of a run: total_env_steps // env_steps_per_update."""
        return self.total_env_steps // self.env_steps_per_update

    def validate_common(self) -> None:
        """Raise `ConfigError` naming the first bad shared field."""
        c: Any = self
        for name in ("demand_window_s", "episode_s"):
            _require(getattr(c, name) > 0, name, getattr(c, name), "> 0")
        for name in ("n_envs", "total_env_steps",
                     "checkpoint_every", "keep_checkpoints"):  # fmt: skip
            _require(getattr(c, name) >= 1, name, getattr(c, name), ">= 1")
        m = c.max_vehicles
        _require(m is None or m >= 1, "max_vehicles", m, ">= 1, or null: the road's")
        _require(c.seed >= 0, "seed", c.seed, ">= 0")
        if not c.penetrations:
            raise ConfigError("penetrations: empty, expected at least one share")
        for i, p in enumerate(c.penetrations):
            _require(0 <= p <= 1, f"penetrations[{i}]", p, "a share in [0, 1]")
        for name, allowed in AGENT_FIELDS.items():
            value = getattr(c, name)
            if value and value not in allowed:
                raise ConfigError(f"{name}: {value!r}, expected '' or one of {allowed}")
        if c.activation not in ACTIVATIONS:
            raise ConfigError(
                f"activation: {c.activation!r}, expected one of {ACTIVATIONS}"
            )
        if not c.hidden:
            raise ConfigError("hidden: empty, expected at least one layer width")
        for i, h in enumerate(c.hidden):
            _require(h >= 1, f"hidden[{i}]", h, ">= 1")

    def validate_updates(self) -> None:
        """Raise `ConfigError` if the run is shorter than one update."""
        c: Any = self
        if self.num_updates < 1:
            raise ConfigError(
                f"total_env_steps: {c.total_env_steps} is less than one update "
                f"({c.env_steps_per_update} env steps)"
            )

    def replace(self: Config, **changes: Any) -> Config:
        """A validated copy with these fields replaced (strict, as from YAML)."""
        return trainer_config_from_dict(type(self), {**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, Any]:
        """Plain data (lists for tuples), as written to YAML."""
        return _plain(dataclasses.asdict(self))

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    # ------------------------------------------------------------ scenario

    def base_scenario(self) -> ScenarioConfig:
        """The scenario as given (full demand), with `observer`, `action` and
        `reward` applied where they are set."""
        cfg = load_scenario(self.scenario)  # type: ignore[attr-defined]
        d = cfg.to_dict()
        d["agent"].update({k: v for k in AGENT_FIELDS if (v := getattr(self, k))})
        if (weight := getattr(self, "conflict_weight", None)) is not None:
            d["agent"]["conflict_weight"] = float(weight)  # a near-conflict's cost
        return config_from_dict(d) if d != cfg.to_dict() else cfg

    def slots(self) -> int:
        """The training environment's vehicle slots M: `max_vehicles`, else
        the scenario's ``simulation.max_vehicles``, else what its road holds
        (`jaxround.core.capacity`; compiles the network)."""
        c: Any = self
        if c.max_vehicles is not None:
            return c.max_vehicles
        from jaxround.envs.roundabout import make

        return make(self.training_scenario())[0].max_vehicles

    def training_scenario(self) -> ScenarioConfig:
        """The scenario cut to `demand_window_s` at its own rate of vehicles.

        The window keeps the scenario's vehicles per second:
        ``round(n_vehicles * demand_window_s / duration_s)`` vehicles (at least
        one); the first penetration is the config's default share of AVs.
        """
        c: Any = self
        base = self.base_scenario()
        d = base.to_dict()
        rate = base.demand.n_vehicles / base.demand.duration_s
        d["demand"]["n_vehicles"] = max(1, round(rate * c.demand_window_s))
        d["demand"]["duration_s"] = c.demand_window_s
        d["simulation"]["penetration"] = c.penetrations[0]
        return config_from_dict(d)


@dataclass(frozen=True)
class PPOConfig(TrainerConfig):
    """Everything `agents.ppo.make_train` needs. One env step steps all M slots."""

    scenario: str = "milan"  # built-in scenario name or YAML path (network, drivers)
    demand_window_s: float = 300.0  # training demand horizon, s; the scenario's rate
    episode_s: float = 360.0  # training episode length, s (window plus a drain)
    max_vehicles: int | None = None  # slots M; None: the scenario's (the road's)
    penetrations: tuple[float, ...] = (1.0,)  # AV shares; env i uses entry i % len
    observer: str = ""  # the AVs' observer; empty: the scenario's agent.observer
    action: str = ""  # what the AVs' action means; empty: the scenario's agent.action
    reward: str = ""  # the AVs' reward; empty: the scenario's agent.reward
    conflict_weight: float | None = None  # per conflict; None: agent.conflict_weight
    conflict_constraint: ConflictConstraintConfig | None = None  # None: a fixed price
    n_envs: int = 64  # roundabouts side by side (split over devices); YAML: auto
    n_steps: int = 64  # env steps per rollout, per roundabout
    total_env_steps: int = 1_000_000  # env steps over all roundabouts and updates
    gamma: float = 0.99  # discount per step of dt
    gae_lambda: float = 0.95  # GAE lambda
    clip_eps: float = 0.2  # PPO ratio clip, also the value clip
    vf_coef: float = 0.5  # weight of the value loss
    ent_coef: float = 0.0  # weight of the entropy bonus
    trip_noise: bool = False  # exploration noise held over each vehicle's trip
    lr: float = 3e-4  # Adam learning rate (start value when annealed)
    anneal_lr: bool = True  # decay the learning rate linearly to 0
    max_grad_norm: float = 0.5  # global gradient-norm clip
    epochs: int = 4  # passes over each rollout
    minibatches: int = 4  # minibatches per epoch (of whole env steps, M slots each)
    reward_scale: float = 1.0  # rewards are multiplied by this before GAE
    hidden: tuple[int, ...] = (64, 64)  # MLP layer widths (actor and critic alike)
    activation: str = "tanh"  # "tanh" or "relu"
    centralised: bool = False  # append the mean of the other vehicles' obs rows
    checkpoint_every: int = 10  # updates between checkpoints (CLI)
    keep_checkpoints: int = 3  # checkpoints kept on disk (CLI)
    seed: int = 0  # PRNG seed of the whole run

    KIND: ClassVar[str] = "PPO"

    # ------------------------------------------------------------ derived

    @property
    def env_steps_per_update(self) -> int:
        """Env steps of one rollout over all roundabouts: n_envs * n_steps."""
        return self.n_envs * self.n_steps

    @property
    def minibatch_env_steps(self) -> int:
        """Env steps (of M slot samples each) per minibatch."""
        return self.env_steps_per_update // self.minibatches

    @property
    def minibatch_size(self) -> int:
        """Slot samples per minibatch (agents and masked-out slots together)."""
        return self.minibatch_env_steps * self.slots()

    # ------------------------------------------------------------ checks

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad field."""
        self.validate_common()
        for name in ("lr", "clip_eps"):
            _require(getattr(self, name) > 0, name, getattr(self, name), "> 0")
        for name in ("vf_coef", "ent_coef", "max_grad_norm", "reward_scale"):
            _require(getattr(self, name) >= 0, name, getattr(self, name), ">= 0")
        for name in ("n_steps", "epochs", "minibatches"):
            _require(getattr(self, name) >= 1, name, getattr(self, name), ">= 1")
        _require(0 < self.gamma <= 1, "gamma", self.gamma, "in (0, 1]")
        _require(0 <= self.gae_lambda <= 1, "gae_lambda", self.gae_lambda, "in [0, 1]")
        if self.conflict_constraint is not None:
            self.conflict_constraint.validate(len(self.penetrations))
        if self.env_steps_per_update % self.minibatches:
            raise ConfigError(
                f"minibatches: {self.minibatches} does not divide n_envs * n_steps "
                f"= {self.env_steps_per_update}"
            )
        self.validate_updates()


@dataclass(frozen=True)
class APGConfig(TrainerConfig):
    """Everything `agents.apg.make_train` needs: the scenario fields as in
    `PPOConfig`, then the analytic-gradient settings. One env step steps all
    M slots; one update differentiates a window of `horizon` steps."""

    scenario: str = "milan"  # built-in scenario name or YAML path (network, drivers)
    demand_window_s: float = 300.0  # training demand horizon, s; the scenario's rate
    episode_s: float = 360.0  # training episode length, s (window plus a drain)
    max_vehicles: int | None = None  # slots M; None: the scenario's (the road's)
    penetrations: tuple[float, ...] = (1.0,)  # AV shares; env i uses entry i % len
    observer: str = ""  # the AVs' observer; empty: the scenario's agent.observer
    action: str = ""  # what the AVs' action means; empty: the scenario's agent.action
    reward: str = ""  # the AVs' reward; empty: the scenario's agent.reward
    relax_temperature: float = 0.5  # training dynamics' smoothness; 0: exact (eval)
    n_envs: int = 64  # roundabouts side by side (split over devices); YAML: auto
    horizon: int = 32  # env steps per differentiated window (truncated backprop)
    total_env_steps: int = 1_000_000  # env steps over all roundabouts and updates
    lr: float = 1e-3  # Adam learning rate (start value when annealed)
    anneal_lr: bool = True  # decay the learning rate linearly to 0
    max_grad_norm: float = 1.0  # global gradient-norm clip
    hidden: tuple[int, ...] = (64, 64)  # MLP layer widths (the critic is unused)
    activation: str = "tanh"  # "tanh" or "relu"
    centralised: bool = False  # append the mean of the other vehicles' obs rows
    checkpoint_every: int = 10  # updates between checkpoints (CLI)
    keep_checkpoints: int = 3  # checkpoints kept on disk (CLI)
    seed: int = 0  # PRNG seed of the whole run

    KIND: ClassVar[str] = "APG"

    @property
    def env_steps_per_update(self) -> int:
        """Env steps of one window over all roundabouts: n_envs * horizon."""
        return self.n_envs * self.horizon

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad field."""
        self.validate_common()
        _require(self.lr > 0, "lr", self.lr, "> 0")
        _require(self.max_grad_norm > 0, "max_grad_norm", self.max_grad_norm, "> 0")
        _require(self.horizon >= 1, "horizon", self.horizon, ">= 1")
        _require(
            self.relax_temperature >= 0,
            "relax_temperature",
            self.relax_temperature,
            ">= 0 (0: the exact dynamics)",
        )
        self.validate_updates()


# --------------------------------------------------------------------------- loading


def builtin_trainer_configs(kind: str) -> list[str]:
    """Names of the trainer configs of a kind ("PPO": ``configs/ppo_*.yaml``)."""
    prefix = kind.lower() + "_"
    files = resources.files("configs").iterdir()
    return sorted(
        p.name[:-5]
        for p in files
        if p.name.startswith(prefix) and p.name.endswith(".yaml")
    )


def builtin_ppo_configs() -> list[str]:
    """Names of the PPO configs shipped in the `configs` package (``ppo_*.yaml``)."""
    return builtin_trainer_configs("PPO")


def load_ppo_config(source: str | Path | None = None) -> PPOConfig:
    """Load and validate a PPO config.

    Args:
        source: a YAML path or the name of a built-in PPO config
            (``"ppo_milan"``, the default).

    Returns:
        The validated `PPOConfig`.

    Raises:
        ConfigError: the file is missing, not YAML, or a field is wrong.
    """
    return load_trainer_config(PPOConfig, source)


def load_apg_config(source: str | Path | None = None) -> APGConfig:
    """Load and validate an APG config: a YAML path or the name of a built-in
    one (``"apg_milan"``, the default); `ConfigError` as `load_ppo_config`."""
    return load_trainer_config(APGConfig, source)


def load_trainer_config(cls: type[Config], source: str | Path | None = None) -> Config:
    """Load and validate a config of class `cls` (default: its ``*_milan``)."""
    return load_trainer_config_and_choice(cls, source)[0]


def load_trainer_config_and_choice(
    cls: type[Config], source: str | Path | None = None
) -> tuple[Config, DeviceChoice | None]:
    """`load_trainer_config`, and what ``n_envs: auto`` chose (None: the
    config gives a number)."""
    kind = cls.KIND
    source = f"{kind.lower()}_milan" if source is None else source
    data = read_yaml(source, builtin_trainer_configs(kind), kind)
    return trainer_config_and_choice(cls, data if data is not None else {})


def ppo_config_from_dict(data: Any) -> PPOConfig:
    """Build and validate a `PPOConfig` from plain data; missing keys take defaults."""
    return trainer_config_from_dict(PPOConfig, data)


def apg_config_from_dict(data: Any) -> APGConfig:
    """Build and validate an `APGConfig` from plain data; missing keys take defaults."""
    return trainer_config_from_dict(APGConfig, data)


def trainer_config_from_dict(cls: type[Config], data: Any) -> Config:
    """Build and validate a config of class `cls` from plain data (strict keys
    and types; missing keys take defaults), with the scenario's loader
    (`jaxround.scenario.loader.dataclass_from_dict`)."""
    return trainer_config_and_choice(cls, data)[0]


def trainer_config_and_choice(
    cls: type[Config], data: Any
) -> tuple[Config, DeviceChoice | None]:
    """`trainer_config_from_dict`, ``n_envs: auto`` sized to this machine's
    device first; what it chose, or None."""
    choice = None
    if isinstance(data, dict) and data.get("n_envs") == AUTO:
        data, choice = size_for_device(cls, data, this_device())
    cfg = dataclass_from_dict(cls, data, f"{cls.KIND} config")
    cfg.validate()
    return cfg, choice


def _plain(data: Any) -> Any:
    """Lists for tuples, at every depth (YAML writes no tuples)."""
    if isinstance(data, dict):
        return {k: _plain(v) for k, v in data.items()}
    return [_plain(v) for v in data] if isinstance(data, tuple | list) else data


def _require(ok: bool, where: str, value: Any, expected: str) -> None:
    if not ok:
        raise ConfigError(f"{where}: {value}, expected {expected}")


__all__ = [
    "ACTIVATIONS",
    "APGConfig",
    "PPOConfig",
    "TrainerConfig",
    "apg_config_from_dict",
    "builtin_ppo_configs",
    "builtin_trainer_configs",
    "load_apg_config",
    "load_ppo_config",
    "load_trainer_config",
    "load_trainer_config_and_choice",
    "ppo_config_from_dict",
    "trainer_config_and_choice",
    "trainer_config_from_dict",
]
