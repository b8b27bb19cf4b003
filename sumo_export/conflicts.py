"""Read the near-conflicts of SUMO's SSM device (``MSDevice_SSM``).

Every vehicle carries the device (`SafetyConfig.sumo_options`), so a
conflict between two vehicles is written twice, once by each of them as its
``ego``. `read_conflicts` counts, for each scheduled vehicle, the conflicts
it wrote, and keeps the smallest TTC and largest DRAC it saw in them.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import NamedTuple

import numpy as np

#: MSDevice_SSM's encounter types (its EncounterType enum) that the counts
#: below report by name.
FOLLOWING_TYPES = {2: "following_follower", 3: "following_leader"}


class Conflicts(NamedTuple):
    """Per scheduled vehicle, (N,): conflicts written with it as ego, int;
    the smallest TTC (s) and largest DRAC (m/s^2) among them (nan: none);
    and the encounter types of all conflicts, ``{type name: count}`` (by the
    type at the smallest TTC, else at the largest DRAC)."""

    count: np.ndarray
    min_ttc_s: np.ndarray
    max_drac_mps2: np.ndarray
    by_type: dict[str, int]


def read_conflicts(path: Path, n_vehicles: int) -> Conflicts:
    """The conflicts of SSM log `path` for vehicles ``v00000``.. (N of them)."""
    count = np.zeros(n_vehicles, np.int64)
    min_ttc = np.full(n_vehicles, np.nan)
    max_drac = np.full(n_vehicles, np.nan)
    by_type: dict[str, int] = {}
    for conflict in ET.parse(path).getroot().iter("conflict"):
        ego = int(conflict.get("ego")[1:])
        count[ego] += 1
        ttc, drac = conflict.find("minTTC"), conflict.find("maxDRAC")
        measured = ttc if _has_value(ttc) else drac
        if measured is not None:
            kind = int(measured.get("type"))
            name = FOLLOWING_TYPES.get(kind, f"type_{kind}")
            by_type[name] = by_type.get(name, 0) + 1
        if _has_value(ttc):
            min_ttc[ego] = np.fmin(min_ttc[ego], float(ttc.get("value")))
        if _has_value(drac):
            max_drac[ego] = np.fmax(max_drac[ego], float(drac.get("value")))
    return Conflicts(count, min_ttc, max_drac, by_type)


def _has_value(element: ET.Element | None) -> bool:
    """A measure element with a number (SUMO writes "NA" when it has none)."""
    if element is None:
        return False
    try:
        float(element.get("value", "NA"))
    except ValueError:
        return False
    return True
