"""Locate the SUMO programs of the `eclipse-sumo` wheel (no SUMO_HOME needed)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path


def sumo_home() -> Path:
    """The SUMO installation of the `eclipse-sumo` package."""
    import sumo  # the eclipse-sumo wheel

    return Path(sumo.SUMO_HOME)


def sumo_binary(name: str) -> str:
    """Absolute path of a SUMO program (`sumo`, `netconvert`, `sumo-gui`)."""
    path = sumo_home() / "bin" / name
    if path.exists() and os.access(path, os.X_OK):
        return str(path)
    found = shutil.which(name)
    if found:
        return found
    raise FileNotFoundError(
        f"SUMO program {name!r} not found; install it with `pip install eclipse-sumo`"
    )
