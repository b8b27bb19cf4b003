"""jaxround: a JAX-vectorised roundabout traffic environment that matches SUMO.

    env, params = jaxround.make("milan")

The environment (and JAX) is imported on first use, so the command line and
the SUMO side start without it.
"""

from __future__ import annotations

from typing import Any

__all__ = ["RoundaboutEnv", "make"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from jaxround.envs import roundabout as env

        return getattr(env, name)
    raise AttributeError(f"module 'jaxround' has no attribute {name!r}")
