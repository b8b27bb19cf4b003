"""How many vehicles the road can hold, and so how many vehicle slots M a JAX
environment needs by default.

SUMO has no slots: what limits the vehicles in its network is the road. A
lane is full when its *brutto occupancy* (SUMO's ``MSLane::getBruttoOccupancy``:
the vehicles' length plus minGap, ``MSVehicleType::getLengthWithGap``, over
the lane's length) reaches 1. The JAX environment keeps every vehicle on the
road in a slot; vehicles due to depart that wait for room (SUMO's insertion
backlog) wait in the schedule (``EnvState.inserted`` false), not in a slot.
So M = `road_capacity` slots hold every vehicle the road can, and no
insertion can overflow.

The default M is smaller: what the scenario's traffic needs
(`jaxround.envs.slots`), and a config or a command may set any M
(``simulation.max_vehicles``, a trainer's ``max_vehicles``,
``--max-vehicles``). An insertion that finds every slot taken waits, counted
in ``EnvState.stats.overflow`` (vehicle-steps), and the run departs from
SUMO's: the commands that report results run it again with more slots
(`jaxround.envs.slots.redo_on_overflow`); `overflow_warning` says so where
nothing can be redone (training).
"""

from __future__ import annotations

import numpy as np

from jaxround.core.network import CompiledNetwork
from jaxround.scenario.config import ScenarioConfig


def length_with_gap(cfg: ScenarioConfig) -> float:
    """The smallest length plus minGap (m) among the scenario's vTypes (human
    drivers and AVs): the closest two vehicles' fronts stand on one lane."""
    return min(d.length + d.min_gap for d in (cfg.drivers.hv, cfg.drivers.av))


def lane_capacities(lane_length: np.ndarray, spacing: float) -> np.ndarray:
    """Vehicles whose fronts can lie on each lane at once, int (L,).

    Fronts at least `spacing` apart on a lane of length l (its front positions
    are [0, l), `jaxround.core.geometry.locate`): at most ceil(l / spacing). (The
    floor would count a lane shorter than `spacing` as holding none, yet one
    vehicle's front can always stand on it, as on the ring lanes between two
    legs of the Milan roundabout, 7.45 m long.)

    Args:
        lane_length: float (L,) metres.
        spacing: metres between two fronts, > 0.
    """
    if not spacing > 0:
        raise ValueError(f"spacing: {spacing}, expected > 0")
    return np.ceil(np.asarray(lane_length, np.float64) / spacing - 1e-9).astype(int)


def road_capacity(network: CompiledNetwork, cfg: ScenarioConfig) -> int:
    """The most vehicles the compiled network can hold at once.

    The sum over every lane the JAX network models (approaches, exits, ring
    edges and the internal junction lanes) of `lane_capacities` at the
    scenario's smallest `length_with_gap`. Internal lanes that cross or merge
    are counted each on its own, so this is an upper bound, not a jam's count.
    """
    return int(lane_capacities(network.lane_length, length_with_gap(cfg)).sum())


def overflow_warning(
    overflow: int, max_vehicles: int | None, what: str = "JAX"
) -> str | None:
    """A one-line warning when insertions waited for a free slot, else None.

    Args:
        overflow: vehicle-steps an insertion waited because all M slots
            were taken (``EnvState.stats.overflow``, summed over runs).
        max_vehicles: the slots M of the runs.
        what: the runs, for the message.
    """
    if not overflow:
        return None
    return (
        f"warning: {what}: {overflow} vehicle-steps of slot overflow with "
        f"max_vehicles = {max_vehicles}: insertions waited for a free slot, so the "
        "runs differ from SUMO's; raise --max-vehicles or the config's "
        "max_vehicles (simulation.max_vehicles: null gives what the road holds)"
    )
