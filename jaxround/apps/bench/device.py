"""The batches `jaxround bench` times, sized to the device it runs on.

On a CPU the benchmark keeps its batches (`CPU_BATCHES`: up to 4,096
roundabouts, about 2 GB at the peak) and its policy rollout of 256. On an
accelerator it goes on doubling up to what the device holds: the largest
batch is `ROUNDABOUTS_PER_GIB` roundabouts per GiB of the memory JAX may use
there (the rule's device description is `agents.common.device_batch`'s),
a power of two, at most `MAX_BATCH`: 32,768 on an H100 (60 GiB for XLA),
65,536 on an H200. The policy rollout takes a quarter of the largest batch;
PPO the training config's batch (``n_envs: auto``: the device's).
"""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

from agents.common.device_batch import Device, device_n_envs

#: The batches of a CPU run.
CPU_BATCHES = (1, 16, 256, 1024, 4096)
#: The JAX policy rollout's roundabouts on a CPU.
CPU_POLICY_BATCH = 256
#: Roundabouts of the environment alone per GiB of device memory (a window
#: of 60 steps takes about half a MiB per roundabout at 76 slots).
ROUNDABOUTS_PER_GIB = 1024
#: The largest batch timed on any device.
MAX_BATCH = 65_536


def largest_batch(device: Device) -> int:
    """The largest batch of roundabouts timed on `device`."""
    if device.platform == "cpu":
        return CPU_BATCHES[-1]
    fit = max(device.memory_gib * ROUNDABOUTS_PER_GIB * device.count, 1)
    return max(CPU_BATCHES[-1], min(2 ** int(math.log2(fit)), MAX_BATCH))


def device_batches(device: Device) -> tuple[int, ...]:
    """The batches B timed on `device`: the CPU's, then doubling (by 2, from
    4,096) up to `largest_batch`."""
    batches = list(CPU_BATCHES)
    while batches[-1] < largest_batch(device):
        batches.append(2 * batches[-1])
    return tuple(batches)


def policy_batch(device: Device) -> int:
    """Roundabouts of the exported policy's JAX rollout on `device`."""
    if device.platform == "cpu":
        return CPU_POLICY_BATCH
    return max(CPU_POLICY_BATCH, largest_batch(device) // 4)


def device_record(device: Device) -> dict[str, Any]:
    """The device and the batches the rule gives it, for the result's JSON."""
    return {
        **asdict(device),
        "memory_gib": None if device.platform == "cpu" else round(device.memory_gib, 1),
        "batches": list(device_batches(device)),
        "policy_batch": policy_batch(device),
        "training_n_envs": device_n_envs(device),
    }
