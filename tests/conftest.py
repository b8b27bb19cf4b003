"""Shared fixtures: small scenarios derived from the built-in configs."""

from __future__ import annotations

import copy
from importlib import resources
from typing import Any

import jax
import numpy as np
import pytest
import yaml

from jaxround.config import ScenarioConfig, config_from_dict


def builtin_dict(name: str = "milan") -> dict[str, Any]:
    """The plain data of a built-in config, to be modified by a test."""
    text = resources.files("configs").joinpath(f"{name}.yaml").read_text()
    return copy.deepcopy(yaml.safe_load(text))


def small_config(
    name: str = "milan",
    n_vehicles: int = 150,
    duration_s: float = 600.0,
    **simulation: Any,
) -> ScenarioConfig:
    """A built-in scenario with fewer vehicles, for quick SUMO runs."""
    d = builtin_dict(name)
    d["demand"]["n_vehicles"] = n_vehicles
    d["demand"]["duration_s"] = duration_s
    d["simulation"].update(simulation)
    return config_from_dict(d)


@pytest.fixture
def milan_dict() -> dict[str, Any]:
    return builtin_dict("milan")


def tree_equal(a: Any, b: Any) -> bool:
    """Bitwise equality of two pytrees (nan equal to nan)."""
    la, ta = jax.tree.flatten(a)
    lb, tb = jax.tree.flatten(b)
    return ta == tb and all(
        np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)
        for x, y in zip(la, lb, strict=True)
    )
