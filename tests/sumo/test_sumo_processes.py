"""Every kind of process that runs SUMO keeps JAX on the CPU
(`jaxround.sumo_files.processes`): each is started as the code starts it and
reports its JAX before any JAX call, while the parent keeps its own."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import pytest

from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import Schedule, make_schedule
from jaxround.sumo_files.processes import (
    cpu_process_pool,
    cpu_spawn_context,
    jax_platform_report,
    pin_jax_to_cpu,
)
from tests.conftest import small_config

pytestmark = pytest.mark.sumo


def tiny() -> ScenarioConfig:
    return small_config("milan", n_vehicles=6, duration_s=20.0)


def assert_pinned(report: dict[str, Any]) -> None:
    assert report["pid"] != os.getpid()
    assert report["env"] == "cpu"
    if report["jax_imported"]:
        assert report["config"] == "cpu"


@dataclass(frozen=True)
class ReportingControllerFactory:
    """A controller that does nothing but report its process's JAX, built in
    `run_many`'s worker before the run's first step."""

    def __call__(self, cfg: ScenarioConfig, schedule: Schedule) -> Any:
        return ReportingController(jax_platform_report())


@dataclass
class ReportingController:
    at_start: dict[str, Any]

    def __call__(self, libsumo: Any, time_s: float) -> None:
        pass

    def report(self) -> dict[str, Any]:
        return self.at_start


def test_the_pool_of_every_sumo_sweep_pins_its_workers() -> None:
    """`sumo_pool`: evaluate, parity, sumo, headroom, search --sumo, run."""
    from sumo_export.executors import sumo_pool

    before = os.environ.get("JAX_PLATFORMS")
    with sumo_pool(workers=2) as pool:
        reports = [pool.submit(jax_platform_report).result() for _ in range(2)]
    for report in reports:
        assert_pinned(report)
        assert not report["backends_started"]
    assert os.environ.get("JAX_PLATFORMS") == before  # the parent's is its own


def test_a_sumo_run_in_run_many_has_jax_on_the_cpu() -> None:
    from sumo_export.runner import run_many

    cfg = tiny()
    (run,) = run_many(
        cfg, [make_schedule(cfg)], workers=1, controller=ReportingControllerFactory()
    )
    assert run.records.arrived.sum() > 0  # SUMO ran
    assert_pinned(run.controller_report)
    assert not run.controller_report["backends_started"]


def test_the_bench_sumo_workers_report_jax_on_the_cpu() -> None:
    from jaxround.apps.bench.sumo_timing import run_sumo_parallel, run_sumo_window

    cfg = tiny()
    steps = 10
    one = run_sumo_window(cfg, make_schedule(cfg), steps)
    assert_pinned(one["jax"])
    both = run_sumo_parallel(cfg, [make_schedule(cfg, seed=s) for s in (0, 1)], steps)
    for row in both["per_process"]:
        assert_pinned(row["jax"])


def _mark(name: str, value: str) -> None:
    os.environ[name] = value


def _environment_value(name: str) -> str | None:
    return os.environ.get(name)


def test_an_initializer_runs_after_the_pin() -> None:
    with cpu_process_pool(
        1, initializer=_mark, initargs=("JAXROUND_MARK", "1")
    ) as pool:
        report = pool.submit(jax_platform_report).result()
        mark = pool.submit(_environment_value, "JAXROUND_MARK").result()
    assert_pinned(report)
    assert mark == "1"


def _report_through(conn: Any) -> None:
    conn.send(jax_platform_report())
    conn.close()


def test_the_study_ride_processes_start_pinned(tmp_path) -> None:
    from jaxround.study.rides import RideManager

    manager = RideManager.__new__(RideManager)  # only its process context
    RideManager.__init__(manager, settings=None, database=None, policy="")
    parent, child = manager._context.Pipe()
    process = manager._context.Process(target=_report_through, args=(child,))
    process.start()
    report = parent.recv()
    process.join(30)
    assert_pinned(report)


def _build_env_and_report(conn: Any) -> None:
    from sumo_export.pettingzoo_env import SumoParallelEnv

    SumoParallelEnv(tiny(), penetration=1.0)
    conn.send(jax_platform_report())
    conn.close()


def test_a_pettingzoo_env_in_its_own_process_pins_it() -> None:
    """As in a vector environment's worker, started by plain multiprocessing
    (no JAX_PLATFORMS given): the environment pins it before its observer."""
    pytest.importorskip("pettingzoo")
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    parent, child = context.Pipe()
    saved = os.environ.pop("JAX_PLATFORMS", None)
    try:
        process = context.Process(target=_build_env_and_report, args=(child,))
        process.start()
    finally:
        if saved is not None:
            os.environ["JAX_PLATFORMS"] = saved
    report = parent.recv()
    process.join(60)
    assert_pinned(report)


def test_ray_tasks_pin_jax() -> None:
    ray = pytest.importorskip("ray")
    from sumo_export.executors import RayPool

    ray.init(num_cpus=1, include_dashboard=False, _node_ip_address="127.0.0.1")
    try:
        report = RayPool(1).submit(jax_platform_report).result()
    finally:
        ray.shutdown()
    assert_pinned(report)


def test_a_started_backend_is_left_alone() -> None:
    """The parent (here, the test process) keeps the backend it started."""
    import jax

    jax.numpy.zeros(1).block_until_ready()
    assert pin_jax_to_cpu() is False
    assert cpu_spawn_context().get_start_method() == "spawn"


def _start_jax() -> str:
    import jax

    jax.numpy.zeros(1).block_until_ready()
    return jax.default_backend()


def test_a_worker_starts_jax_on_the_cpu_whatever_the_parent_asks(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The parent's JAX_PLATFORMS (here a GPU this machine has not) does not
    reach the workers: their JAX starts, on the CPU."""
    from sumo_export.executors import sumo_pool

    monkeypatch.setenv("JAX_PLATFORMS", "cuda")
    with sumo_pool(workers=1) as pool:
        assert pool.submit(_start_jax).result() == "cpu"
    assert os.environ["JAX_PLATFORMS"] == "cuda"
