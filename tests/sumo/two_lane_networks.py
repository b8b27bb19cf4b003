"""Two-lane roundabouts beside configs/two_lane.yaml, for the lane tests.

- `two_lane_exits`: two_lane.yaml with two-lane exits (the inner ring
  lane's exit link is minor, it crosses the outer lane going on round);
- `five_legs`: five legs 72 degrees apart, one- and two-lane entries and
  exits, a larger ring; held out while the lane modules were written.
"""

from __future__ import annotations

from jaxround.scenario.config import ScenarioConfig, config_from_dict
from tests.conftest import builtin_dict


def two_lane_exits() -> ScenarioConfig:
    d = builtin_dict("two_lane")
    for leg in d["network"]["legs"]:
        leg["exit_lanes"] = 2
    return config_from_dict(d)


def five_legs() -> ScenarioConfig:
    """Five legs 72 degrees apart; one-lane and two-lane entries and exits."""
    d = builtin_dict("two_lane")
    lanes = [(2, 1), (2, 2), (1, 1), (2, 1), (1, 2)]  # (entry, exit) per leg
    d["network"]["ring_radius_m"] = 25.0
    d["network"]["legs"] = [
        {"name": f"leg{i}", "angle_deg": 72.0 * i, "length_m": 80.0,
         "speed_limit_mps": 13.89, "entry_lanes": entry, "exit_lanes": exit_}
        for i, (entry, exit_) in enumerate(lanes)
    ]  # fmt: skip
    d["demand"]["origin_share"] = [0.2] * 5
    d["demand"]["od"] = [[0.0 if i == j else 0.25 for j in range(5)] for i in range(5)]
    return config_from_dict(d)
