"""The roundabout's roads: its legs, its ring, and the lanes of each.

`NetworkConfig` is the ``network:`` section of a scenario
(`jaxround.scenario.config`), parsed by the same strict loader. A ring and
each leg's entry and exit have one or two lanes (``ring_lanes``,
``entry_lanes``, ``exit_lanes``; 1 by default). The lane counts at their
default are left out of `NetworkConfig.to_dict`, so that a single-lane
scenario keeps the plain data, fingerprints and cached SUMO network it had
before lanes could be counted.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from jaxround.scenario.loader import ConfigError, check_positive

#: The lane counts a ring, an entry or an exit may have.
LANE_COUNTS = (1, 2)

#: SUMO's default lane width (m; netconvert's ``--default.lane-width``).
LANE_WIDTH_M = 3.2


def check_lanes(count: int, where: str) -> None:
    """ConfigError unless `count` is one of `LANE_COUNTS`."""
    if count not in LANE_COUNTS:
        raise ConfigError(f"{where}: {count} lanes, expected 1 or 2")


@dataclass(frozen=True)
class LegConfig:
    """One approach of the roundabout: an incoming road (the entry) and an
    outgoing one (the exit), of one or two lanes each."""

    name: str  # used in SUMO ids: letters, digits and '_' only
    angle_deg: float  # direction of the leg seen from the ring centre, CCW from east
    length_m: float  # length of the approach (and of the exit) road
    speed_limit_mps: float  # speed limit on the approach and the exit
    entry_lanes: int = 1  # lanes of the incoming road (1 or 2)
    exit_lanes: int = 1  # lanes of the outgoing road (1 or 2)

    def validate(self, where: str) -> None:
        if not self.name or not self.name.replace("_", "").isalnum():
            raise ConfigError(f"{where}.name: {self.name!r} must be letters, digits, _")
        check_positive(self.length_m, f"{where}.length_m")
        check_positive(self.speed_limit_mps, f"{where}.speed_limit_mps")
        check_lanes(self.entry_lanes, f"{where}.entry_lanes")
        check_lanes(self.exit_lanes, f"{where}.exit_lanes")


@dataclass(frozen=True)
class NetworkConfig:
    """Geometry of a single-ring roundabout with 3 to 6 legs.

    The ring's edges follow the circle of `ring_radius_m`; SUMO lays their
    lanes outside it (netconvert's default ``spreadType="right"``, right-hand
    traffic going counter-clockwise), each `LANE_WIDTH_M` wide: the inner
    lane's centre line is half a lane outside the circle, and the inscribed
    circle's radius is the circle's plus one lane width per ring lane.
    """

    ring_radius_m: float  # radius of the ring edges' line (the inner lane's border)
    ring_speed_limit_mps: float  # speed limit on the ring
    legs: tuple[LegConfig, ...]  # in counter-clockwise order
    ring_lanes: int = 1  # lanes of the circulating roadway (1 or 2)

    def validate(self, where: str) -> None:
        check_positive(self.ring_radius_m, f"{where}.ring_radius_m")
        check_positive(self.ring_speed_limit_mps, f"{where}.ring_speed_limit_mps")
        check_lanes(self.ring_lanes, f"{where}.ring_lanes")
        if not 3 <= len(self.legs) <= 6:
            raise ConfigError(f"{where}.legs: {len(self.legs)} legs, expected 3 to 6")
        for i, leg in enumerate(self.legs):
            leg.validate(f"{where}.legs[{i}]")
        self._check_lane_connections(where)
        names = [leg.name for leg in self.legs]
        if len(set(names)) != len(names):
            raise ConfigError(f"{where}.legs: leg names repeat: {names}")
        angles = [leg.angle_deg % 360.0 for leg in self.legs]
        gaps = [
            (angles[(i + 1) % len(angles)] - a) % 360.0 for i, a in enumerate(angles)
        ]
        if abs(sum(gaps) - 360.0) > 1e-6 or min(gaps) < 30.0:
            raise ConfigError(
                f"{where}.legs: angles {angles} must increase counter-clockwise "
                "and be at least 30 degrees apart"
            )
        min_arc = min(gaps) * math.pi / 180.0 * self.ring_radius_m
        if min_arc < self.min_arc_m:
            raise ConfigError(
                f"{where}.ring_radius_m: {self.ring_radius_m} m leaves only "
                f"{min_arc:.1f} m of ring between two legs; need at least "
                f"{self.min_arc_m:g} m"
                + ("" if self.single_lane else " where a road has two lanes")
            )

    def _check_lane_connections(self, where: str) -> None:
        """Refuse a leg whose lanes cannot connect to the ring lane by lane:
        a two-lane entry or exit beside a one-lane ring (netconvert would
        join both of its lanes to the one ring lane, or leave one unused)."""
        if self.ring_lanes == 2:
            return
        for i, leg in enumerate(self.legs):
            for key in ("entry_lanes", "exit_lanes"):
                if getattr(leg, key) == 2:
                    raise ConfigError(
                        f"{where}.legs[{i}].{key}: 2 lanes on a one-lane ring "
                        f"({where}.ring_lanes: 1); a two-lane {key[:-6]} needs "
                        "ring_lanes: 2"
                    )

    @property
    def min_arc_m(self) -> float:
        """The shortest ring (m, along the edges' circle) between two legs:
        6 m on single-lane roads; 24 m where any road has two lanes.

        netconvert (1.28) makes a junction as wide as its roads, and a
        junction of two-lane roads takes about 15 m of the ring: with 24 m
        between two legs the ring edge left between their junctions is at
        least 7 m long (a car and its gap) in every lane layout, with 12 m
        it is 0.2 m in most, and a vehicle could not change lanes between
        an entry and the next exit.
        """
        return 6.0 if self.single_lane else 24.0

    @property
    def inscribed_diameter_m(self) -> float:
        """Across the ring's outer border, the design guides' size of a roundabout."""
        return 2.0 * (self.ring_radius_m + self.ring_lanes * LANE_WIDTH_M)

    @property
    def single_lane(self) -> bool:
        """Every road has one lane: the roundabouts the JAX side runs."""
        return not self.multi_lane_keys()

    def multi_lane_keys(self, where: str = "network") -> list[str]:
        """The settings with two lanes, as ``"network.ring_lanes: 2"``."""
        keys = [f"{where}.ring_lanes: 2"] if self.ring_lanes != 1 else []
        for i, leg in enumerate(self.legs):
            for key in ("entry_lanes", "exit_lanes"):
                if getattr(leg, key) != 1:
                    keys.append(f"{where}.legs[{i}].{key}: {getattr(leg, key)}")
        return keys

    def to_dict(self) -> dict[str, Any]:
        """The plain data of the section, lane counts of 1 left out (as a
        single-lane file has it)."""
        d = dataclasses.asdict(self)
        if d["ring_lanes"] == 1:
            del d["ring_lanes"]
        for leg in d["legs"]:
            for key in ("entry_lanes", "exit_lanes"):
                if leg[key] == 1:
                    del leg[key]
        return d
