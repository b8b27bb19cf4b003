"""Shared fixtures: small scenarios derived from the built-in configs."""

from __future__ import annotations

import contextlib
import copy
import gc
import os
import shutil
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


#: JAX slots of `small_config`'s scenarios: Milan's own at its full demand.
SMALL_SLOTS = 32

#: two_lane.yaml's slots as `jaxround.envs.slots` sizes them from its traffic,
#: for the tests that run its demand: sizing runs the scenario first (about
#: a minute), and whichever test sized it first paid for the others.
TWO_LANE_SLOTS = 56


def small_config(
    name: str = "milan",
    n_vehicles: int = 150,
    duration_s: float = 600.0,
    **simulation: Any,
) -> ScenarioConfig:
    """A built-in scenario with fewer vehicles, for quick SUMO runs.

    Its JAX slots are `SMALL_SLOTS` unless given (``max_vehicles=None``: sized
    from the traffic, `jaxround.envs.slots`, which runs the scenario first);
    these demands never fill them, and parity redoes a run that would.
    """
    simulation.setdefault("max_vehicles", SMALL_SLOTS)
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


#: JAX reads it at import: XLA compiles with few optimisations when "1".
QUICK_ENV = "JAX_DISABLE_MOST_OPTIMIZATIONS"

#: Set by the controlling pytest process: a cache folder shared by the whole
#: test session (every xdist worker and every subprocess), removed at its end.
SESSION_CACHE_ENV = "JAXROUND_TEST_SESSION_CACHE"


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: one worker more than the cores. Some tests mostly wait
    (the study's browser rides run in real time, SUMO runs in its own
    processes), and a spare worker uses the core they leave idle."""
    return (os.cpu_count() or 1) + 1


#: The slowest test files (seconds on a 2-core CPU with the other workers
#: running, `pytest --durations` of a full run), slowest first. They are
#: handed out first, so that pytest-xdist's workers (one file each at a
#: time, ``--dist loadfile``) finish together rather than one of them
#: ending the run with a long file.
SLOW_FILES = (
    "tests/e2e/test_two_lane_agents.py",  # 655: training, evaluations, a search
    "tests/unit/test_ring_turns.py",  # 270 before a gradient compile less: 4 min
    "tests/e2e/test_pipeline.py",  # 275
    "tests/e2e/test_notebooks.py",  # 255
    "tests/sumo/test_lane_requests.py",  # 210: three SUMO runs and replays
    "tests/sumo/test_bench.py",  # 210
    "tests/unit/test_gradients.py",  # 205
    "tests/sumo/test_turn_order.py",  # 200: 31 s and 36 s of two legs, step by step
    "tests/sumo/test_drivers.py",  # 180
    "tests/sumo/test_look_ahead_sumo.py",  # 180: 27 s of five legs, 30 s of two_lane
    "tests/study/test_study_browser.py",  # 175: rides in real time
    "tests/unit/test_ppo.py",  # 165
    "tests/sumo/test_lane_hold_probe.py",  # 150: SUMO's holds, 3 x 600 s in both
    "tests/sumo/test_env.py",  # 150
    "tests/e2e/test_train_cli.py",  # 145
    "tests/sumo/test_two_lane_step.py",  # 120: a parity run on two lanes
    "tests/unit/test_setting_search.py",  # 115
    "tests/sumo/test_ring_changer.py",  # 110
    "tests/sumo/test_av.py",  # 110
    "tests/e2e/test_distributed_train.py",  # 105
    "tests/e2e/test_apg.py",  # 105
    "tests/unit/test_entry_hold.py",  # 100: 200 s of two lanes, the changer each step
    "tests/unit/test_capacity.py",  # 100
    "tests/sumo/test_entry_hold_sumo.py",  # 90
    "tests/e2e/test_search_cli.py",  # 85
    "tests/e2e/test_cli.py",  # 80
    "tests/unit/test_constrained_ppo.py",  # 80
    "tests/sumo/test_lane_action.py",  # 75: a lane rule in both simulators
    "tests/unit/test_demand_gradient.py",  # 75
    "tests/sumo/test_conflicts_sumo.py",  # 70
    "tests/sumo/test_lc2013_jax.py",  # 65
    "tests/sumo/test_ring_changer_traffic.py",  # 65
    "tests/sumo/test_crossing_leaders.py",  # 65: 10 minutes of two lanes
    "tests/unit/test_rollout.py",  # 55
    "tests/sumo/test_controller.py",  # 55
    "tests/integrations/test_gymnax_env.py",  # 50
    "tests/sumo/test_parity.py",  # 45
    "tests/sumo/test_entry_stop_line.py",  # 40
    "tests/integrations/test_jaxmarl_env.py",  # 40
)


def refused(main: Any, argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """A command's ``main(argv)`` that argparse refuses (exit status 2),
    and what it printed to stderr."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    return capsys.readouterr().err


def pytest_collection_modifyitems(
    session: pytest.Session, config: pytest.Config, items: list[pytest.Item]
) -> None:
    """The files of `SLOW_FILES` first, in that order; the rest as collected."""
    rank = {name: i for i, name in enumerate(SLOW_FILES)}

    def order(item: pytest.Item) -> int:
        path = item.nodeid.split("::", 1)[0]
        return rank.get(path, len(SLOW_FILES))

    items.sort(key=order)


def pytest_configure(config: pytest.Config) -> None:
    """One cache for the session: XLA programs and slot sizings, fresh per run.

    ``XDG_CACHE_HOME`` points at a new temporary folder (the CLI, the
    notebooks' kernels and `jaxround.envs.slots` keep their caches under it),
    and this process compiles into ``<it>/jaxround/xla``. The same program is
    then compiled once per session, not once per test, worker and subprocess
    that builds it (most tests build their own environment, whose step is the
    same XLA program). A run neither reads the user's cache nor depends on
    what an earlier run left.
    """
    import tempfile

    if SESSION_CACHE_ENV not in os.environ:  # the controller, before any worker
        os.environ[SESSION_CACHE_ENV] = tempfile.mkdtemp(prefix="jaxround-tests-")
        config.stash[_OWNS_CACHE] = True
    cache = os.environ[SESSION_CACHE_ENV]
    os.environ["XDG_CACHE_HOME"] = cache
    # Few optimisations everywhere (subprocesses inherit it): the tests' time
    # goes into compiling many programs that each run briefly, and no test
    # asserts a timing. JAX_DISABLE_MOST_OPTIMIZATIONS=0 before pytest
    # compiles them fully.
    os.environ.setdefault(QUICK_ENV, "1")
    jax.config.update("jax_disable_most_optimizations", os.environ[QUICK_ENV] == "1")
    if os.environ[QUICK_ENV] == "1":
        os.environ["XLA_FLAGS"] = quick_xla_flags(os.environ.get("XLA_FLAGS", ""))
    jax.config.update("jax_compilation_cache_dir", session_xla_cache())
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    # Tracing the step builds many short-lived objects, and Python's cyclic
    # collector, run every 700 allocations by default, scans them again and
    # again: tracing took 33 s against 41 s (test_setting_search.py with
    # test_gradients.py) with it run every 100,000.
    gc.set_threshold(100_000, 50, 100)


#: XLA's CPU flag for the elemental emitter in place of the MLIR fusion
#: emitters: each of the step's hundreds of small fusions then skips building
#: and lowering an MLIR module; compiling takes about a fifth less (4.3 s
#: against 5.3 s for a 100-step episode, and 143 s against 175 s for
#: test_capacity.py beside test_setting_search.py). The programs compute the
#: same operations; read by XLA when its CPU backend starts.
QUICK_XLA_FLAG = "--xla_cpu_use_fusion_emitters=false"


@contextlib.contextmanager
def fully_optimised() -> Iterator[None]:
    """XLA's full optimisations for what is compiled inside, for the few tests
    whose time goes into running a program rather than compiling it."""
    before = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", False)
    try:
        yield
    finally:
        jax.config.update("jax_disable_most_optimizations", before)


def quick_xla_flags(flags: str) -> str:
    """``XLA_FLAGS`` with `QUICK_XLA_FLAG` added, unless it sets it already."""
    if QUICK_XLA_FLAG.split("=")[0] in flags:
        return flags
    return f"{flags} {QUICK_XLA_FLAG}".strip()


def pytest_unconfigure(config: pytest.Config) -> None:
    if config.stash.get(_OWNS_CACHE, False):
        shutil.rmtree(os.environ.pop(SESSION_CACHE_ENV), ignore_errors=True)


_OWNS_CACHE = pytest.StashKey[bool]()


def session_xla_cache() -> str:
    """The session's folder of compiled XLA programs."""
    return str(Path(os.environ[SESSION_CACHE_ENV]) / "jaxround" / "xla")


@pytest.fixture(autouse=True)
def _session_compilation_cache() -> Iterator[None]:
    """A test that points the XLA cache elsewhere has it pointed back after."""
    from jax.experimental.compilation_cache import compilation_cache as cc

    yield
    if jax.config.jax_compilation_cache_dir != session_xla_cache():
        jax.config.update("jax_compilation_cache_dir", session_xla_cache())
        cc.reset_cache()
