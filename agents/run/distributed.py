"""Training over several processes and hosts with `jax.distributed`.

    jaxround train --out runs/ppo --coordinator 10.0.0.1:7777 \\
        --num-processes 2 --process-id 0        # on every process, its own id

Every process runs the same program (JAX's multi-controller model): the
roundabout batch is split over the devices of all processes
(`agents.common.batch.batch_sharding` takes `jax.devices()`), each process
steps its share of the roundabouts, and the gradients are averaged across
them by XLA's collectives (Gloo on CPUs). So `n_envs` is the global batch:
the same config and seed give the learning curve of one process, up to the
rounding of the cross-process sums (measured: 1e-7 on the tiny test run).

Process 0 writes the run folder (CSV files, curves, the exported policy);
every process takes part in the checkpoints, which Orbax writes as one.
"""

from __future__ import annotations

import jax

#: How to address the coordinator: host and port.
ADDRESS_FORM = "HOST:PORT"


def check_address(address: str) -> str:
    """`address` if it is HOST:PORT with a port number; ValueError otherwise."""
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"coordinator {address!r}, expected {ADDRESS_FORM}")
    return address


def initialize(coordinator: str, num_processes: int, process_id: int) -> None:
    """Join the training of `num_processes` processes; call before any JAX work.

    Args:
        coordinator: HOST:PORT of process 0, which listens there.
        num_processes: processes in all (hosts x processes per host).
        process_id: this process's number, 0 .. num_processes - 1.

    Raises:
        ValueError: a bad address, count or id, named before anything starts.
    """
    check_address(coordinator)
    if num_processes < 1:
        raise ValueError(f"num_processes: {num_processes}, expected >= 1")
    if not 0 <= process_id < num_processes:
        raise ValueError(f"process_id: {process_id}, expected 0 .. {num_processes - 1}")
    if num_processes == 1:
        return
    # CPU devices talk through Gloo (GPUs bring their own collectives)
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        coordinator_address=coordinator,
        num_processes=num_processes,
        process_id=process_id,
    )


def is_primary() -> bool:
    """This is the process that writes the run's files (process 0)."""
    return jax.process_index() == 0
