"""The strict YAML-to-dataclass loader of every config: scenarios
(`jaxround.scenario.config`) and trainers (`agents.common.config`).

An unknown key, a value of the wrong type or out of range raises
`ConfigError` naming the field (for example ``demand.od[1]: row sums to 0.9,
expected 1``) before anything runs.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from importlib import resources
from pathlib import Path
from typing import Any

import yaml


class ConfigError(ValueError):
    """A configuration value is missing, unknown or out of range."""


def read_yaml(source: str | Path, builtins: list[str], what: str) -> Any:
    """The parsed YAML of a file path or of a built-in file of `configs`.

    Args:
        source: a ``.yaml`` path, or one of `builtins`.
        builtins: names of the built-in files this kind of config may use.
        what: the kind of config, for the error messages ("scenario").

    Raises:
        ConfigError: the file is missing, unknown or not YAML.
    """
    path = Path(source)
    if path.suffix in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise ConfigError(f"{what} config file {str(path)!r} does not exist")
        text = path.read_text()
    elif str(source) in builtins:
        text = resources.files("configs").joinpath(f"{source}.yaml").read_text()
    else:
        raise ConfigError(
            f"{source!r}: no {what} config file of that name, nor a built-in one "
            f"({', '.join(builtins)})"
        )
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(f"{source}: not valid YAML: {err}") from None


Dataclass = typing.TypeVar("Dataclass")


def dataclass_from_dict(cls: type[Dataclass], data: Any, what: str) -> Dataclass:
    """Build the dataclass `cls` from plain data (as parsed from YAML), strictly,
    as `config_from_dict` builds a scenario; not validated.

    Every field is a dataclass, bool, int, float, str or tuple of them. A
    missing field takes its default; an unknown key, a missing field without
    default or a value of the wrong type raises `ConfigError` naming the
    field, or `what` for the whole (``"PPO config: unknown key 'n_env'"``).
    """
    return _build(cls, data, "", what)


def _build(tp: Any, value: Any, where: str, what: str = "config") -> Any:
    """Convert plain data into the annotated type `tp`, strictly (`what`: the
    name of the whole in messages)."""
    label = where or what
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(
                f"{label}: expected a mapping, got {type(value).__name__}"
            )
        hints = typing.get_type_hints(tp)
        fields = {f.name: f for f in dataclasses.fields(tp)}
        unknown = sorted(set(value) - set(fields))
        if unknown:
            raise ConfigError(
                f"{label}: unknown key {unknown[0]!r} (allowed: {', '.join(fields)})"
            )
        kwargs = {}
        for name, f in fields.items():
            sub = f"{where}.{name}" if where else name
            if name not in value:
                if f.default is dataclasses.MISSING:
                    raise ConfigError(f"{sub}: missing")
                continue
            kwargs[name] = _build(hints[name], value[name], sub)
        return tp(**kwargs)
    origin = typing.get_origin(tp)
    if origin is types.UnionType:  # `X | None`: null, or an X
        (item_tp,) = [t for t in typing.get_args(tp) if t is not type(None)]
        return None if value is None else _build(item_tp, value, where, what)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{label}: expected a list, got {type(value).__name__}")
        (item_tp, _) = typing.get_args(tp)
        return tuple(_build(item_tp, v, f"{label}[{i}]") for i, v in enumerate(value))
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{label}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{label}: expected a finite number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{label}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{label}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{label}: expected a string, got {value!r}")
        return value
    raise TypeError(f"unsupported config type {tp!r}")  # pragma: no cover


def check_positive(x: float, where: str) -> None:
    """ConfigError unless x > 0."""
    if not x > 0:
        raise ConfigError(f"{where}: {x}, expected > 0")


def check_non_negative(x: float, where: str) -> None:
    """ConfigError unless x >= 0."""
    if not x >= 0:
        raise ConfigError(f"{where}: {x}, expected >= 0")


def check_share(x: float, where: str) -> None:
    """ConfigError unless x is in [0, 1]."""
    if not 0.0 <= x <= 1.0:
        raise ConfigError(f"{where}: {x}, expected a share in [0, 1]")


def check_distribution(row: tuple[float, ...], where: str, n: int) -> None:
    """ConfigError unless `row` has n entries >= 0 summing to 1."""
    if len(row) != n:
        raise ConfigError(f"{where}: {len(row)} entries, expected {n} (one per leg)")
    for j, x in enumerate(row):
        if x < 0:
            raise ConfigError(f"{where}[{j}]: {x}, expected >= 0")
    if abs(sum(row) - 1.0) > 1e-6:
        raise ConfigError(f"{where}: sums to {sum(row):.6g}, expected 1")
