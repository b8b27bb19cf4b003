"""Shared fixtures: small scenarios derived from the built-in configs."""

from __future__ import annotations

import contextlib
import copy
from collections.abc import Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pytest
import yaml

from jaxround.scenario.config import ScenarioConfig, config_from_dict


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


@contextlib.contextmanager
def quick_compilation(cache_dir: Path) -> Iterator[None]:
    """Compile with few optimisations, into a persistent cache; restore after.

    For test modules whose time goes into compiling large programs (PPO, APG,
    gradients) rather than running them.
    """
    from jax.experimental.compilation_cache import compilation_cache as cc

    old_dir = jax.config.jax_compilation_cache_dir
    old_opt = jax.config.values["jax_disable_most_optimizations"]
    jax.config.update("jax_compilation_cache_dir", str(cache_dir))
    jax.config.update("jax_disable_most_optimizations", True)
    try:
        yield
    finally:
        jax.config.update("jax_compilation_cache_dir", old_dir)
        jax.config.update("jax_disable_most_optimizations", old_opt)
        cc.reset_cache()


@pytest.fixture(autouse=True)
def _private_compilation_cache(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> Iterator[None]:
    """Keep the tests' XLA cache out of the user's home, and contained to a test.

    The CLI and the notebooks keep compiled programs in
    ``$XDG_CACHE_HOME/jaxround/xla``
    (`agents.common.compilation.enable_compilation_cache`); under the tests
    that folder is a temporary one (kernels and subprocesses inherit it), so
    a run neither writes into the user's cache nor depends on what an earlier
    run left there. A test that turns the cache on in this
    process has it turned back off afterwards.
    """
    from jax.experimental.compilation_cache import compilation_cache as cc

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path_factory.getbasetemp() / "cache"))
    before = jax.config.jax_compilation_cache_dir
    yield
    if jax.config.jax_compilation_cache_dir != before:
        jax.config.update("jax_compilation_cache_dir", before)
        cc.reset_cache()
