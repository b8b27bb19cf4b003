"""The best constant AV setting of a scenario, kept as a small versioned file.

``configs/best_constant/<scenario>.json`` (written by ``jaxround search``
into its output folder as ``best_constant.json``, then copied here):

    {"scenario": "milan",
     "setting": {"tau": 0.5, "impatience": 1.0, ..., "cruise_mps": null},
     "objective": {"description": "...", "time_weight": 1.0, ...},
     "found": {"penetration": 1.0, "window_s": 1800.0, ...},
     "command": "jaxround search --out DIR ...",
     "front": {"penetration": 1.0, "points": [{"time_s", "co2_g",
               "objective", "setting"}, ...]}}

``setting`` names AV vType numbers (`DriverConfig` fields) and, optionally,
``cruise_mps``: a speed every AV is commanded toward (``cruise:V``, as the
scripted controller), null for none. Whatever numbers the file holds are
applied; nothing here assumes which. ``front`` (optional) is the search's
front of crossing time against CO2 over the constants it scored.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from jaxround.scenario.config import (
    SHARED_DRIVER_FIELDS,
    ConfigError,
    DriverConfig,
    DriversConfig,
    ScenarioConfig,
)

#: The setting's optional speed command, m/s (not a vType number).
CRUISE = "cruise_mps"
#: Folder of the built-in files inside the `configs` package.
FOLDER = "best_constant"


@dataclass(frozen=True)
class BestConstant:
    """A constant AV setting and where it came from (module docstring).

    Attributes:
        scenario: the scenario it was found for.
        setting: name -> value; AV vType numbers and optionally ``cruise_mps``.
        objective: what it minimises (a ``description`` and the weights).
        command: the ``jaxround search`` command that regenerates it.
        found: the search's case (penetration, window, seeds), free-form.
        front: ``{"penetration", "points": [{"time_s", "co2_g", ...}]}`` or
            empty.
        source: the file it was read from, as given, or
            ``configs/best_constant/<name>.json`` for a built-in one ('' if
            built in memory).
    """

    scenario: str
    setting: dict[str, float | None]
    objective: dict[str, Any]
    command: str
    found: dict[str, Any] = field(default_factory=dict)
    front: dict[str, Any] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        known = {f.name for f in dataclasses.fields(DriverConfig)} | {CRUISE}
        unknown = set(self.setting) - known
        if unknown:
            raise ConfigError(
                f"best constant: unknown setting number(s) {sorted(unknown)}"
            )
        if not self.vtype and self.cruise_mps is None:
            raise ConfigError("best constant: the setting changes nothing")

    @property
    def vtype(self) -> dict[str, float]:
        """The AV vType numbers the setting sets."""
        return {k: float(v) for k, v in self.setting.items() if k != CRUISE}

    @property
    def cruise_mps(self) -> float | None:
        """The commanded cruise speed, m/s; None: no speed command."""
        value = self.setting.get(CRUISE)
        return None if value is None else float(value)

    @property
    def controller_spec(self) -> str | None:
        """The scripted controller of the cruise speed (``cruise:V``) or None."""
        return None if self.cruise_mps is None else f"cruise:{self.cruise_mps:.4g}"

    def config_for(self, cfg: ScenarioConfig) -> ScenarioConfig:
        """`cfg` with the setting's numbers in its AV vType, validated.

        Raises:
            ConfigError: a number out of its range, or one the two classes
                must share (`SHARED_DRIVER_FIELDS`) changed for the AVs only.
        """
        shared = sorted(
            k
            for k, v in self.vtype.items()
            if k in SHARED_DRIVER_FIELDS and v != getattr(cfg.drivers.av, k)
        )
        if shared:
            raise ConfigError(
                f"best constant: {shared} are shared by both classes in JAX; "
                "a setting of the AVs alone cannot change them"
            )
        av = dataclasses.replace(cfg.drivers.av, **self.vtype)
        drivers = DriversConfig(hv=cfg.drivers.hv, av=av)
        new = dataclasses.replace(cfg, drivers=drivers)
        new.validate()
        return new

    def describe(self) -> str:
        """The setting in a few words, e.g. ``tau 0.5, impatience 1, ...``."""
        return ", ".join(
            f"{k} {'none' if v is None else f'{float(v):.3g}'}"
            for k, v in self.setting.items()
        )

    def to_dict(self) -> dict[str, Any]:
        """The file's JSON object (``source`` left out)."""
        out = dataclasses.asdict(self)
        out.pop("source")
        return out


def builtin_path(scenario: str) -> Path | None:
    """The built-in file of a scenario, or None if it has none."""
    path = Path(str(resources.files("configs").joinpath(FOLDER, f"{scenario}.json")))
    return path if path.is_file() else None


def load_best_constant(source: str | Path) -> BestConstant:
    """Read a best-constant file: a path, or a built-in scenario's name.

    Raises:
        ConfigError: no such file, not JSON, or fields missing or wrong.
    """
    path, name = Path(source), str(source)
    if not path.is_file():
        builtin = builtin_path(str(source))
        if builtin is None:
            raise ConfigError(f"best constant {source!r}: no such file or scenario")
        path, name = builtin, f"configs/{FOLDER}/{source}.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ConfigError(f"best constant {path}: {err}") from None
    fields = {f.name for f in dataclasses.fields(BestConstant)} - {"source"}
    missing = {"scenario", "setting", "objective", "command"} - set(data)
    if missing or set(data) - fields:
        raise ConfigError(
            f"best constant {path}: missing {sorted(missing)}, "
            f"unknown {sorted(set(data) - fields)}"
        )
    return BestConstant(**data, source=name)
