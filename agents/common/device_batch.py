"""``n_envs: auto``: a training batch sized to the device it runs on.

    device = this_device()                 # the platform, kind and memory
    data, choice = size_for_device(PPOConfig, data, device)

The rule:

- **On a CPU** the batch is `CPU_N_ENVS` (64) roundabouts and nothing else
  changes: ``n_envs: auto`` there gives exactly the config as written with
  ``n_envs: 64`` (same seed, same numbers).
- **On an accelerator** (GPU, TPU) the batch per device is
  `ROUNDABOUTS_PER_GIB` roundabouts per GiB of the memory JAX may use there
  (XLA's allocator limit; where JAX reports none, the memory of the device
  kind in `KNOWN_MEMORY_GIB`, else `FALLBACK_MEMORY_GIB`), rounded down to
  a power of two and kept within [`MIN_DEVICE_N_ENVS`, `MAX_DEVICE_N_ENVS`],
  times the devices. An H100 (80 GB, XLA's 75%: 60 GiB) gets 4,096, an
  H200 (141 GB: 105 GiB) 8,192.
- **The run keeps its number of updates**: ``total_env_steps`` grows with
  the batch, so the accelerator makes at least as many updates as the CPU
  run (ppo_milan: 256 updates, 67.1M env-steps at 4,096 roundabouts).
- **PPO's minibatches and learning rate follow the batch**: with the batch
  S times the CPU's, the minibatches per epoch grow by ``2**ceil(log2(S) / 2)``
  (about sqrt(S): 8x at S = 64), so each minibatch grows by the rest; the
  learning rate grows with the square root of that minibatch growth (the
  square-root rule for Adam), at most `MAX_LR_GROWTH` times. APG keeps its
  learning rate: its one gradient per update averages over the batch.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from typing import Any

#: The batch of the CPU, and of the built-in configs' numbers.
CPU_N_ENVS = 64
#: Roundabouts of training per GiB of device memory (a PPO update of 4,096
#: roundabouts x 64 steps x 32 slots fits in a few GiB; the rest is margin).
ROUNDABOUTS_PER_GIB = 100
MIN_DEVICE_N_ENVS = 256
MAX_DEVICE_N_ENVS = 8192
#: Memory, GiB, of device kinds whose JAX reports no allocator limit.
KNOWN_MEMORY_GIB = {"H200": 105.0, "H100": 60.0, "A100": 30.0, "L4": 17.0, "T4": 11.0}
FALLBACK_MEMORY_GIB = 12.0
#: The learning rate grows at most this many times.
MAX_LR_GROWTH = 4.0
#: What a config writes to ask for the rule.
AUTO = "auto"


@dataclass(frozen=True)
class Device:
    """What the rule reads of the machine's first JAX device."""

    platform: str  # "cpu", "gpu", "tpu"
    kind: str  # JAX's device_kind, e.g. "NVIDIA H200"
    memory_bytes: int | None  # what JAX may use of one device; None: unknown
    count: int = 1  # devices of that platform (the batch is split over them)

    @property
    def memory_gib(self) -> float:
        if self.memory_bytes:
            return self.memory_bytes / 2**30
        for name, gib in KNOWN_MEMORY_GIB.items():
            if name.lower() in self.kind.lower():
                return gib
        return FALLBACK_MEMORY_GIB


def this_device() -> Device:
    """The platform, kind and memory of JAX's default devices (starts JAX)."""
    import jax

    devices = jax.devices()
    first = devices[0]
    memory = None
    if first.platform != "cpu":
        try:
            stats = first.memory_stats() or {}
        except Exception:  # a backend without memory statistics
            stats = {}
        memory = stats.get("bytes_limit")
    return Device(first.platform, first.device_kind, memory, len(devices))


def device_n_envs(device: Device) -> int:
    """Roundabouts a training batch takes on `device` (module docstring)."""
    if device.platform == "cpu":
        return CPU_N_ENVS
    per_device = 2 ** int(math.log2(max(device.memory_gib * ROUNDABOUTS_PER_GIB, 1)))
    per_device = min(max(per_device, MIN_DEVICE_N_ENVS), MAX_DEVICE_N_ENVS)
    return per_device * device.count


@dataclass(frozen=True)
class DeviceChoice:
    """What ``n_envs: auto`` chose, to print and to keep with the run."""

    device: Device
    n_envs: int
    total_env_steps: int
    updates: int
    changed: dict[str, Any]  # the fields set beside n_envs and total_env_steps

    def describe(self) -> str:
        d = self.device
        extra = "".join(f", {k} {v:g}" for k, v in self.changed.items())
        return (
            f"n_envs: auto -> {self.n_envs} roundabouts on {d.count} x {d.kind} "
            f"({d.platform}, {d.memory_gib:.0f} GiB): {self.updates} updates, "
            f"{self.total_env_steps:,} env steps{extra}"
        )

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "rule": AUTO}

    def as_comment(self) -> str:
        """YAML comment lines to head the run's ``config.yaml`` with."""
        return f"# {self.describe()}\n# {json.dumps(self.to_dict())}\n"


def size_for_device(
    cls: type, data: dict[str, Any], device: Device
) -> tuple[dict[str, Any], DeviceChoice]:
    """The config data with ``n_envs: auto`` replaced by `device`'s batch.

    Args:
        cls: `PPOConfig` or `APGConfig` (its defaults fill missing keys).
        data: the config as read, ``n_envs: "auto"``; `total_env_steps` is the
            CPU run's (of `CPU_N_ENVS` roundabouts).
        device: the device to size for.

    Returns:
        (the data with numbers in place of "auto", what was chosen).
    """
    steps_key = "n_steps" if cls.KIND == "PPO" else "horizon"
    steps = data.get(steps_key, getattr(cls, steps_key))
    total = data.get("total_env_steps", cls.total_env_steps)
    updates = max(1, total // (CPU_N_ENVS * steps))
    n_envs = device_n_envs(device)
    out = {**data, "n_envs": n_envs}
    changed: dict[str, Any] = {}
    if n_envs != CPU_N_ENVS:
        out["total_env_steps"] = updates * n_envs * steps
        if cls.KIND == "PPO":
            changed = _ppo_minibatches_and_lr(cls, data, n_envs // CPU_N_ENVS)
            out.update(changed)
    choice = DeviceChoice(device, n_envs, out.get("total_env_steps", total), updates,
                          changed)  # fmt: skip
    return out, choice


def _ppo_minibatches_and_lr(
    cls: type, data: dict[str, Any], scale: int
) -> dict[str, Any]:
    """PPO's minibatches and learning rate for a batch `scale` times the CPU's."""
    minibatches = data.get("minibatches", cls.minibatches)
    lr = data.get("lr", cls.lr)
    more = 2 ** math.ceil(math.log2(max(scale, 1)) / 2)  # about sqrt(scale)
    growth = scale / more  # of each minibatch
    return {
        "minibatches": minibatches * more,
        "lr": lr * min(math.sqrt(growth), MAX_LR_GROWTH),
    }


__all__ = [
    "AUTO",
    "CPU_N_ENVS",
    "Device",
    "DeviceChoice",
    "device_n_envs",
    "size_for_device",
    "this_device",
]
