"""``jaxround bench``: the JAX environment's throughput against SUMO's.

- `run`: the benchmark in one call (`run_benchmark`), what each part times;
- `jax_timing`: the JAX environment, B roundabouts in one jitted call;
- `sumo_timing`: libsumo, in one process and in one process per core;
- `training`: PPO, and an exported policy in JAX and in SUMO in the loop,
  over windows timed in `policy_windows`;
- `profile`: the step's phases timed in the compiled program (``--profile``);
- `device`: the batches and the device the figures were taken on;
- `report`: the tables, the machine and the code version.

    from jaxround.apps.bench import format_benchmark, run_benchmark

The names are loaded on first use, so that a SUMO worker that imports
`sumo_timing` does not import the JAX side with it.
"""

from __future__ import annotations

import importlib
from typing import Any

#: Public name -> the module of this package that defines it.
_PUBLIC = {
    "run_benchmark": "run",
    "format_benchmark": "report",
    "batch_schedules": "jax_timing",
    "usable_cpus": "sumo_timing",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str) -> Any:
    if name not in _PUBLIC:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_PUBLIC[name]}"), name)
