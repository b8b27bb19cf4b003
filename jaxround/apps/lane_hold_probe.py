"""Which vehicles make SUMO 1.28 hold back a wanted lane change on a
roundabout's entry: held vehicle-steps, and a removal experiment on one.

    python -m jaxround.apps.lane_hold_probe --config two_lane --duration 300
    python -m jaxround.apps.lane_hold_probe --time 148 --vehicle v00101

SUMO's changer can refuse a change its LC2013 model wants with nothing
blocking it in the model: `libsumo.vehicle.getLaneChangeState(id, 1)` then
gives the model's state without `LCA_BLOCKED` bits and a final state with
all of them (docs/lc2013-map.md section 12, "What holds it back"). The
first form lists those vehicle-steps on right entry lanes wanting the left
lane; the second saves SUMO's state before the given step and runs that
step again with other vehicles removed (every one, then each one kept
alone), and reports the vehicles that alone hold the change. The rule
itself was later read from 1.28's compiled lane changer; the JAX step holds
as it does (`jaxround.lanes.entry_hold`).
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from jaxround.lanes import actions as lca
from jaxround.scenario.config import ScenarioConfig, load_config
from jaxround.scenario.schedule import make_schedule


@dataclass(frozen=True)
class Held:
    """A vehicle-step where the model wants the left lane, unblocked, and
    the changer blocks it: the step's 0-based index (the state read after
    ``step + 1`` steps), vehicle, lane, distance to the lane's end (m) and
    speed (m/s)."""

    step: int
    vehicle: str
    lane: str
    seen: float
    speed: float


def is_held(states: tuple[int, int]) -> bool:
    """Model wants left and is not blocked; the final state has every bit of
    SUMO's LCA_BLOCKED (`jaxround.lanes.actions.HELD`)."""
    model, final = states
    return (
        bool(model & lca.LEFT)
        and not model & lca.HELD
        and (final & lca.HELD) == lca.HELD
    )


@contextmanager
def sumo_run(cfg: ScenarioConfig, seed: int) -> Iterator[object]:
    """libsumo running the scenario with schedule ``seed``, as `jaxround sumo`."""
    import libsumo

    from sumo_export.runner import sumo_arguments
    from sumo_export.scenario import write_scenario

    with tempfile.TemporaryDirectory(prefix="jaxround-hold-") as tmp:
        out = Path(tmp)
        files = write_scenario(cfg, make_schedule(cfg, seed=seed), out)
        libsumo.start(
            sumo_arguments(files.sumocfg, out / "trips.xml", out / "stats.xml")
        )
        try:
            yield libsumo
        finally:
            libsumo.close()


def held_steps(cfg: ScenarioConfig, duration_s: float, seed: int = 0) -> list[Held]:
    """Every held vehicle-step on a right entry lane in the first ``duration_s``."""
    found = []
    with sumo_run(cfg, seed) as sumo:
        vehicle, lane = sumo.vehicle, sumo.lane
        for step in range(int(round(duration_s / cfg.simulation.dt_s))):
            sumo.simulationStep()
            for vid in vehicle.getIDList():
                on = vehicle.getLaneID(vid)
                if not (on.startswith("in_") and on.endswith("_0")):
                    continue
                if is_held(vehicle.getLaneChangeState(vid, 1)):
                    seen = lane.getLength(on) - vehicle.getLanePosition(vid)
                    found.append(Held(step, vid, on, seen, vehicle.getSpeed(vid)))
    return found


@dataclass(frozen=True)
class Removal:
    """The removal experiment's outcome for one held vehicle-step: held with
    everyone present, held with every other vehicle removed, and the
    vehicles that hold it alone (by id, with their routes)."""

    with_all: bool
    alone: bool
    sufficient: dict[str, list[str]]


def holders(cfg: ScenarioConfig, step: int, vid: str, seed: int = 0) -> Removal:
    """The removal experiment on ``vid`` at step ``step`` (0-based, as `Held`:
    the state after ``step + 1`` steps; at least 1).

    Keeping one vehicle alone changes the held vehicle's own approach too
    (its leaders are gone), so a foe can hold it only beside others: such a
    change has no `Removal.sufficient` vehicle.
    """
    with sumo_run(cfg, seed) as sumo, tempfile.TemporaryDirectory() as tmp:
        vehicle = sumo.vehicle
        for _ in range(step - 1):
            sumo.simulationStep()
        saved = str(Path(tmp) / "state.xml")
        sumo.simulation.saveState(saved)
        others = [v for v in vehicle.getIDList() if v != vid]
        routes = {v: list(vehicle.getRoute(v)) for v in others}

        def held_keeping(keep: set[str]) -> bool:
            # a loaded state has no saved lane-change states: the step before
            # the one looked at rebuilds them
            sumo.simulation.loadState(saved)
            for other in others:
                if other not in keep:
                    vehicle.remove(other)
            sumo.simulationStep()
            sumo.simulationStep()
            return vid in vehicle.getIDList() and is_held(
                vehicle.getLaneChangeState(vid, 1)
            )

        return Removal(
            with_all=held_keeping(set(others)),
            alone=held_keeping(set()),
            sufficient={v: routes[v] for v in others if held_keeping({v})},
        )


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default="two_lane")
    p.add_argument("--seed", type=int, default=0, help="schedule seed (default 0)")
    p.add_argument("--duration", type=float, default=300.0, help="seconds to list")
    p.add_argument("--time", type=float, help="removal experiment at this time (s)")
    p.add_argument("--vehicle", help="the held vehicle of the removal experiment")
    args = p.parse_args(argv)
    cfg = load_config(args.config)
    if (args.time is None) != (args.vehicle is None):
        p.error("--time and --vehicle go together")
    if args.vehicle is None:
        rows = held_steps(cfg, args.duration, args.seed)
        for h in rows:
            time_s = (h.step + 1) * cfg.simulation.dt_s
            print(f"{time_s:8.1f} s  {h.vehicle:>8}  {h.lane:>7}  "
                  f"{h.seen:5.1f} m to the line  {h.speed:5.2f} m/s")  # fmt: skip
        print(f"{len(rows)} held vehicle-steps in {args.duration:g} s")
        return
    step = int(round(args.time / cfg.simulation.dt_s)) - 1
    if step < 1:
        p.error(f"--time must be at least {2 * cfg.simulation.dt_s:g} s")
    result = holders(cfg, step, args.vehicle, args.seed)
    print(f"{args.vehicle} at {args.time:g} s: held {result.with_all}; "
          f"held with every other vehicle removed {result.alone}")  # fmt: skip
    for other, route in result.sufficient.items():
        print(f"  {other} alone holds it (route {' '.join(route)})")


if __name__ == "__main__":
    main()
