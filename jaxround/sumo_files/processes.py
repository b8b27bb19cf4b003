"""Processes that run SUMO: spawned, with JAX pinned to the CPU.

    with cpu_process_pool(workers=4) as pool:   # a ProcessPoolExecutor
        future = pool.submit(fn, job)
    context = cpu_spawn_context()               # for Process, Pipe, Barrier

A SUMO worker needs no accelerator, but it imports JAX (the observers of the
policy controller, the scenario's schedules): left to choose, JAX in each
worker would start the machine's GPU backend, and XLA would reserve 75% of
the GPU's memory for each of them (``CUDA_ERROR_OUT_OF_MEMORY`` from the
second worker on, then ``Unable to initialize backend 'cuda'``). Every
process that runs SUMO is started here, so that none can:

- the process is spawned (never forked: a fork would copy the parent's
  started JAX), with ``JAX_PLATFORMS=cpu`` in its environment from its first
  instruction: JAX, when the child imports it, knows only its CPU backend;
- the pools' initializer, `pin_jax_to_cpu`, sets JAX's own config as well
  where JAX is imported already (by unpickling the parent's ``__main__``).

The parent keeps its accelerator: its JAX read ``JAX_PLATFORMS`` when it
was imported, and the variable is set for the child's start only.
`jax_platform_report` is what a worker says about its JAX (the tests ask
each kind of worker for it).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import multiprocessing.context
import os
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import Any

#: What a SUMO process's JAX may use.
SUMO_PROCESS_PLATFORM = "cpu"
#: The environment variable JAX reads its platforms from when imported.
PLATFORMS_VARIABLE = "JAX_PLATFORMS"

# One child's start at a time changes this process's environment.
_ENVIRONMENT_LOCK = threading.Lock()


def pin_jax_to_cpu() -> bool:
    """Keep this process's JAX on the CPU, if no JAX backend has started yet.

    Sets ``JAX_PLATFORMS=cpu`` (for a JAX imported later and for this
    process's children) and, where JAX is imported, its ``jax_platforms``
    config. A process whose JAX already runs on a backend is left alone.

    Returns:
        Whether JAX is pinned (False: a backend had already started).
    """
    jax = sys.modules.get("jax")
    if jax is not None and _backends_started():
        return False
    os.environ[PLATFORMS_VARIABLE] = SUMO_PROCESS_PLATFORM
    if jax is not None:
        jax.config.update("jax_platforms", SUMO_PROCESS_PLATFORM)
    return True


def jax_platform_report() -> dict[str, Any]:
    """This process's JAX, as far as it can be told without starting it.

    Returns:
        ``{"pid", "env" (JAX_PLATFORMS or None), "jax_imported",
        "config" (jax_platforms, or None without JAX), "backends_started"}``.
    """
    jax = sys.modules.get("jax")
    return {
        "pid": os.getpid(),
        "env": os.environ.get(PLATFORMS_VARIABLE),
        "jax_imported": jax is not None,
        "config": None if jax is None else jax.config.jax_platforms,
        "backends_started": jax is not None and _backends_started(),
    }


def _backends_started() -> bool:
    from jax._src import xla_bridge

    return bool(xla_bridge.backends_are_initialized())


class _CpuSpawnProcess(multiprocessing.context.SpawnProcess):
    """A spawned process whose environment says ``JAX_PLATFORMS=cpu``."""

    def start(self) -> None:
        with _environment_for_child():
            super().start()


class CpuSpawnContext(multiprocessing.context.SpawnContext):
    """multiprocessing's spawn context, its processes pinned to the CPU."""

    Process = _CpuSpawnProcess


def cpu_spawn_context() -> CpuSpawnContext:
    """The context of every process that runs SUMO (Process, Pipe, Barrier)."""
    return CpuSpawnContext()


def cpu_process_pool(
    workers: int,
    initializer: Callable[..., Any] | None = None,
    initargs: tuple[Any, ...] = (),
) -> ProcessPoolExecutor:
    """A pool of `workers` spawned processes, JAX pinned to the CPU in each.

    Args:
        workers: processes of the pool (at least 1).
        initializer: called with `initargs` in each worker after the pin.
    """
    return ProcessPoolExecutor(
        max_workers=max(1, workers),
        mp_context=cpu_spawn_context(),
        initializer=_start_worker,
        initargs=(initializer, initargs),
    )


def _start_worker(
    initializer: Callable[..., Any] | None, initargs: tuple[Any, ...]
) -> None:
    pin_jax_to_cpu()
    if initializer is not None:
        initializer(*initargs)


@contextlib.contextmanager
def _environment_for_child() -> Iterator[None]:
    """``JAX_PLATFORMS=cpu`` in this process's environment while a child
    starts (a spawned child copies it), the old value back after."""
    with _ENVIRONMENT_LOCK:
        before = os.environ.get(PLATFORMS_VARIABLE)
        os.environ[PLATFORMS_VARIABLE] = SUMO_PROCESS_PLATFORM
        try:
            yield
        finally:
            if before is None:
                del os.environ[PLATFORMS_VARIABLE]
            else:
                os.environ[PLATFORMS_VARIABLE] = before


def in_child_process() -> bool:
    """Whether this process was started by another's multiprocessing (a
    vector environment's or a pool's worker), not by a user."""
    return multiprocessing.parent_process() is not None


__all__ = [
    "CpuSpawnContext",
    "cpu_process_pool",
    "cpu_spawn_context",
    "in_child_process",
    "jax_platform_report",
    "pin_jax_to_cpu",
]
