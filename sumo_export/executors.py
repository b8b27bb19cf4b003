"""Where SUMO runs go: a local process pool (the default) or a Ray cluster.

    use_executor("ray")            # what ``--executor ray`` does
    with sumo_pool(workers=4) as pool:
        future = pool.submit(fn, job)

Every SUMO sweep goes through `sumo_export.runner.run_many`, which takes its
pool here, so one choice covers ``jaxround sumo``, ``evaluate --sim sumo``,
``parity``, the calibration survey and ``run``. A run is the same function on
the same job in either pool (one simulation per worker process: libsumo holds
one per process), so the results are the same.

Ray (``pip install "jaxround[ray]"``) connects to the cluster at
``RAY_ADDRESS`` when that is set (Ray's own rule), else starts a local one
with `workers` CPUs (all of them by default) on 127.0.0.1, without its
dashboard. Each run is one Ray task of one
CPU; the cluster's nodes need jaxround installed (the same version).

Either way the processes that run SUMO keep JAX on the CPU
(`jaxround.sumo_files.processes`): the local pool's workers are spawned
with ``JAX_PLATFORMS=cpu``, Ray's tasks get it in their runtime environment
and pin JAX before the run, and the caller keeps the accelerator.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from typing import Any, Protocol

from jaxround.sumo_files.processes import (
    PLATFORMS_VARIABLE,
    SUMO_PROCESS_PLATFORM,
    cpu_process_pool,
    pin_jax_to_cpu,
)

#: The pools a sweep can run in.
EXECUTORS = ("local", "ray")
#: The pool `sumo_pool` gives when none is named (`use_executor`).
_default = "local"


class Pool(Protocol):
    """What `run_many` needs of a pool: ``submit(fn, *args) -> Future``."""

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> Future: ...


def check_executor(name: str) -> str:
    """`name` if it is a known pool whose library imports; ValueError naming
    what is wrong (and the extra that installs Ray) otherwise."""
    if name not in EXECUTORS:
        raise ValueError(f"executor {name!r}, expected one of {list(EXECUTORS)}")
    if name == "ray":
        try:
            import ray  # noqa: F401
        except ImportError as err:
            raise ValueError(
                f'executor "ray" needs Ray: pip install "jaxround[ray]" ({err})'
            ) from None
    return name


def use_executor(name: str) -> None:
    """Make `name` the pool of every sweep of this process from now on."""
    global _default
    _default = check_executor(name)


def current_executor() -> str:
    return _default


@contextlib.contextmanager
def sumo_pool(
    workers: int | None = None, executor: str | None = None
) -> Iterator[Pool]:
    """A pool for SUMO runs.

    Args:
        workers: local processes side by side (default: the CPUs); with Ray,
            the CPUs of a local cluster it starts (a cluster at
            ``RAY_ADDRESS`` has its own).
        executor: "local" or "ray"; None: `current_executor()`.
    """
    name = check_executor(executor or _default)
    if name == "ray":
        yield RayPool(workers)
        return
    with cpu_process_pool(workers or os.cpu_count() or 1) as pool:
        yield pool


class RayPool:
    """Runs each submitted call as a Ray task of one CPU.

    Connects to ``RAY_ADDRESS`` if set, else starts a local cluster of
    `workers` CPUs; an already connected Ray is used as it is.
    """

    def __init__(self, workers: int | None = None) -> None:
        import ray

        if not ray.is_initialized():
            if os.environ.get("RAY_ADDRESS"):
                ray.init(log_to_driver=False)
            else:  # a local cluster, reachable from this machine only
                ray.init(
                    num_cpus=workers or os.cpu_count(),
                    include_dashboard=False,
                    log_to_driver=False,
                    _node_ip_address="127.0.0.1",
                )
        self._ray = ray
        self._task = ray.remote(
            num_cpus=1,
            runtime_env={"env_vars": {PLATFORMS_VARIABLE: SUMO_PROCESS_PLATFORM}},
        )(_call)

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> Future:
        return self._task.remote(fn, *args).future()


def _call(fn: Callable[..., Any], *args: Any) -> Any:
    pin_jax_to_cpu()
    return fn(*args)
