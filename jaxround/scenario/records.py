"""What happened to each vehicle in one run: the record both simulators return.

`jaxround.envs.rollout` builds it from a JAX episode, `sumo_export.runner`
from a SUMO run; `jaxround.analysis.metrics` turns it into the paper's numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class VehicleRecords:
    """What happened to each scheduled vehicle in one run. Vehicle arrays are (N,).

    Attributes:
        is_av: bool (N,) vehicle class.
        origin: int (N,) entry leg.
        scheduled_depart_s: float (N,) departure time in the schedule.
        depart_s: float (N,) time the vehicle was inserted (nan if never).
        arrival_s: float (N,) time the vehicle left the network (nan if not).
        co2_g: float (N,) CO2 emitted over the trip, g (nan if not arrived).
        fuel_g: float (N,) fuel used over the trip, g (nan if not arrived).
        queue_mean_veh: float (n_legs,) mean over the steps of the demand
            horizon of the vehicles queued on each approach (halting there,
            speed below 0.1 m/s, plus those waiting to be inserted).
        queue_max_veh: float (n_legs,) the largest such queue.
        conflicts: int (N,) near-conflicts the vehicle was part of, as SUMO's
            SSM device writes them (one per vehicle of a pair; see
            `jaxround.scenario.safety`); None where the run did not count them.
        min_ttc_s: float (N,) the smallest time to collision among them
            (nan: no conflict).
        max_drac_mps2: float (N,) the largest deceleration to avoid a crash
            among them (nan: no conflict).
        lane_changes: int (N,) lane changes the vehicle made (SUMO's
            ``--lanechange-output``; `jaxround.envs.lane_changes.LaneState`
            in JAX); None on roads of one lane.
    """

    is_av: np.ndarray
    origin: np.ndarray
    scheduled_depart_s: np.ndarray
    depart_s: np.ndarray
    arrival_s: np.ndarray
    co2_g: np.ndarray
    fuel_g: np.ndarray
    queue_mean_veh: np.ndarray
    queue_max_veh: np.ndarray
    conflicts: np.ndarray | None = None
    min_ttc_s: np.ndarray | None = None
    max_drac_mps2: np.ndarray | None = None
    lane_changes: np.ndarray | None = None

    @property
    def arrived(self) -> np.ndarray:
        return np.isfinite(self.arrival_s)

    @property
    def departed(self) -> np.ndarray:
        return np.isfinite(self.depart_s)

    @property
    def conflicts_per_1000(self) -> np.ndarray | None:
        """float (N,): each vehicle's conflicts times 1,000, whose mean over
        vehicles is conflicts per 1,000 vehicles (None if not counted)."""
        if self.conflicts is None:
            return None
        return self.conflicts.astype(np.float64) * 1000.0

    @property
    def crossing_time_s(self) -> np.ndarray:
        """float (N,): arrival minus scheduled departure (nan if not arrived)."""
        return self.arrival_s - self.scheduled_depart_s
