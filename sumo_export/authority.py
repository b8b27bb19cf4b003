"""What authority over an AV SUMO 1.28 gives a controller, measured.

    python -m sumo_export.authority

Three probes on the Milan roundabout, AVs of the config's IDM vType:

1. One step (`one_step_probes`): after SUMO's step k one AV gets a speed
   command or a parameter setter; its speed after step k + 1 is compared
   with the same run without the call. A command above the IDM speed under
   speed mode 31 is capped there, one below is followed; setAccel,
   setSpeedFactor and setTau act in the very next step.
2. Whole runs (`setter_probes`): every AV gets a value at departure through
   a per-vehicle setter, against a run whose AV vType carries that value
   (same schedule); the share of vehicles with the same crossing time tells
   whether the setter is the vType's parameter. ``vehicle.setParameter(id,
   "junctionModel.jmTimegapMinor", ...)`` raises, so gap acceptance goes
   through ``setType`` to a copy of the vType (`libsumo.vehicletype.copy`,
   then a setter or ``setParameter`` on the copy).
3. Speed modes (`speed_mode_probes`): every AV is commanded ``v + accel*dt``
   each step under a speed mode; crossing time and collisions show whether
   any mode lifts the IDM cap and keeps SUMO's yielding and safety.
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jaxround.analysis.metrics import class_metrics
from jaxround.scenario.config import ScenarioConfig, load_config
from jaxround.scenario.records import VehicleRecords
from jaxround.scenario.schedule import Schedule, make_schedule
from sumo_export.runner import run_many, sumo_arguments
from sumo_export.scenario import AV_TYPE, write_scenario

#: The evaluation schedule of the whole-run probes.
SEED = 100
#: Copy of the AV vType that `OnDeparture` moves AVs to.
COPY_TYPE = "av_copy"


def av_config(cfg: ScenarioConfig, **values: float) -> ScenarioConfig:
    """`cfg` with these AV driver numbers (validated)."""
    driver = dataclasses.replace(cfg.drivers.av, **values)
    new = dataclasses.replace(cfg, drivers=dataclasses.replace(cfg.drivers, av=driver))
    new.validate()
    return new


# ------------------------------------------------------------------ one step

Call = Callable[[Any, str, float], None]  # (libsumo, vehicle id, speed) -> None


def trace(
    cfg: ScenarioConfig,
    schedule: Schedule,
    steps: int,
    call: Call | None = None,
    at: tuple[int, str] | None = None,
) -> dict[tuple[int, str], tuple[float, str, float]]:
    """Run in this process; (step, id) -> (speed, lane, leader gap or inf),
    calling ``call(libsumo, id, speed)`` after step ``at[0]`` on ``at[1]``."""
    import libsumo

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        files = write_scenario(cfg, schedule, Path(tmp))
        libsumo.start(
            sumo_arguments(files.sumocfg, Path(tmp, "t.xml"), Path(tmp, "s.xml"))
        )
        try:
            for k in range(1, steps + 1):
                libsumo.simulation.step()
                for vid in libsumo.vehicle.getIDList():
                    leader = libsumo.vehicle.getLeader(vid, 50.0)
                    gap = leader[1] if leader and leader[0] else np.inf
                    speed = libsumo.vehicle.getSpeed(vid)
                    out[(k, vid)] = (speed, libsumo.vehicle.getLaneID(vid), gap)
                    if call is not None and (k, vid) == at:
                        call(libsumo, vid, speed)
        finally:
            libsumo.close()
    return out


def one_step_probes(cfg: ScenarioConfig) -> list[dict[str, Any]]:
    """Each call's effect on the AV's speed one step later (60 vehicles)."""
    demand = dataclasses.replace(cfg.demand, n_vehicles=60, duration_s=120.0)
    small = dataclasses.replace(cfg, demand=demand)
    schedule = make_schedule(small, seed=3, penetration=1.0)
    steps = 120
    ref = trace(small, schedule, steps)

    def pick(want: Callable[[float, float, str, float], bool]) -> tuple[int, str]:
        for (k, vid), (v, lane, gap) in sorted(ref.items()):
            nxt = ref.get((k + 1, vid))
            if nxt is not None and want(v, nxt[0], lane, gap):
                return k, vid
        raise RuntimeError("no vehicle in the probe run fits")

    # accelerating on an exit without a leader; following closely on an approach
    free = pick(
        lambda v, n, lane, gap: (
            lane.startswith("out") and 6 < v < 12 and n > v + 0.3 and gap > 45
        )
    )
    follow = pick(lambda v, n, lane, gap: lane.startswith("in") and v > 4 and gap < 15)

    def setter(name: str, value: float) -> Call:
        return lambda sumo, vid, speed: getattr(sumo.vehicle, name)(vid, value)

    def command(boost: float, mode: int = 31) -> Call:
        def call(sumo: Any, vid: str, speed: float) -> None:
            sumo.vehicle.setSpeedMode(vid, mode)
            sumo.vehicle.setSpeed(vid, speed + boost)

        return call

    calls: list[tuple[str, tuple[int, str], Call]] = [
        ("setSpeed(v + 2), mode 31", free, command(2.0)),
        ("setSpeed(v + 0.1), mode 31", free, command(0.1)),
        ("setSpeed(v + 2), mode 0", free, command(2.0, mode=0)),
        ("setAccel(1.0)", free, setter("setAccel", 1.0)),
        ("setAccel(5.0)", free, setter("setAccel", 5.0)),
        ("setSpeedFactor(1.2)", free, setter("setSpeedFactor", 1.2)),
        ("setTau(3.0), following", follow, setter("setTau", 3.0)),
        ("setTau(0.5), following", follow, setter("setTau", 0.5)),
        ("setDecel(8.0), following", follow, setter("setDecel", 8.0)),
        ("setDecel(2.0), following", follow, setter("setDecel", 2.0)),
    ]
    rows = []
    for label, (k, vid), call in calls:
        probed = trace(small, schedule, k + 1, call, (k, vid))
        rows.append(
            {
                "call": label,
                "vehicle": vid,
                "step": k,
                "speed": ref[(k, vid)][0],
                "next_without": ref[(k + 1, vid)][0],
                "next_with": probed[(k + 1, vid)][0],
            }
        )
    return rows


# ------------------------------------------------------------------ whole runs


@dataclass(frozen=True)
class OnDeparture:
    """A controller factory (picklable) that gives every AV a value when it
    departs: a `libsumo.vehicle` setter, or ``type:<setter>`` to move it to
    a copy of the AV vType given the value by a `libsumo.vehicletype` setter
    (``type:setParameter:<key>`` for a vType parameter)."""

    setter: str
    value: float

    def __call__(self, cfg: ScenarioConfig, schedule: Schedule) -> Any:
        del cfg, schedule
        setter, value = self.setter, self.value

        def control(libsumo: Any, time_s: float) -> None:
            del time_s
            types = libsumo.vehicletype
            for vid in libsumo.simulation.getDepartedIDList():
                if libsumo.vehicle.getTypeID(vid) != AV_TYPE:
                    continue
                if not setter.startswith("type:"):
                    getattr(libsumo.vehicle, setter)(vid, value)
                    continue
                if COPY_TYPE not in types.getIDList():
                    types.copy(AV_TYPE, COPY_TYPE)
                    _, name, *key = setter.split(":")
                    args = (*key, str(value)) if key else (value,)
                    getattr(types, name)(COPY_TYPE, *args)
                libsumo.vehicle.setType(vid, COPY_TYPE)

        return control


#: (vType field, value, per-vehicle setter) of the whole-run probes.
SETTERS = (
    ("accel", 1.5, "setAccel"),
    ("accel", 1.5, "type:setAccel"),
    ("tau", 1.6, "setTau"),
    ("decel", 2.5, "setDecel"),
    ("impatience", 0.5, "setImpatience"),
    ("impatience", 0.5, "type:setImpatience"),
    ("jm_timegap_minor", 3.0, "type:setParameter:junctionModel.jmTimegapMinor"),
)


def mean_crossing(records: VehicleRecords, horizon_s: float) -> float:
    return class_metrics(records, horizon_s)["all"]["mean_crossing_time_s"]


def setter_probes(cfg: ScenarioConfig) -> list[dict[str, Any]]:
    """Per-vehicle setters against the vType, on one schedule at 100% AVs."""
    schedule = make_schedule(cfg, seed=SEED, penetration=1.0)
    horizon = cfg.demand.duration_s
    (base,) = run_many(cfg, [schedule], workers=1)
    rows = []
    for field, value, setter in SETTERS:
        (in_type,) = run_many(av_config(cfg, **{field: value}), [schedule], workers=1)
        (by_setter,) = run_many(
            cfg, [schedule], workers=1, controller=OnDeparture(setter, value)
        )
        a, b = in_type.records, by_setter.records
        same = np.abs(a.crossing_time_s - b.crossing_time_s) < 1e-6
        rows.append(
            {
                "field": field,
                "value": value,
                "setter": setter,
                "vtype_s": mean_crossing(a, horizon),
                "setter_s": mean_crossing(b, horizon),
                "base_s": mean_crossing(base.records, horizon),
                "same_vehicles": float(same.mean()),
            }
        )
    return rows


@dataclass(frozen=True)
class Commanded:
    """A controller factory (picklable): every AV under `speed_mode` and
    commanded ``setSpeed(v + accel * dt)`` after every step."""

    speed_mode: int

    def __call__(self, cfg: ScenarioConfig, schedule: Schedule) -> Any:
        del schedule
        boost = cfg.drivers.av.accel * cfg.simulation.dt_s
        mode = self.speed_mode

        def control(libsumo: Any, time_s: float) -> None:
            del time_s
            veh = libsumo.vehicle
            for vid in libsumo.simulation.getDepartedIDList():
                if veh.getTypeID(vid) == AV_TYPE:
                    veh.setSpeedMode(vid, mode)
            for vid in veh.getIDList():
                if veh.getTypeID(vid) == AV_TYPE:
                    veh.setSpeed(vid, veh.getSpeed(vid) + boost)

        return control


def speed_mode_probes(
    cfg: ScenarioConfig, modes: tuple[int, ...] = (31, 30, 23, 0, 63)
) -> list[dict[str, Any]]:
    """Every AV commanded above its IDM speed, under each speed mode."""
    schedule = make_schedule(cfg, seed=SEED, penetration=1.0)
    rows = []
    for mode in (None, *modes):
        factory = None if mode is None else Commanded(mode)
        (run,) = run_many(cfg, [schedule], workers=1, controller=factory)
        m = class_metrics(run.records, cfg.demand.duration_s)["all"]
        rows.append(
            {
                "speed_mode": mode,
                "crossing_s": m["mean_crossing_time_s"],
                "co2_g": m["co2_g_per_veh"],
                "collisions": run.collisions,
                "emergency_brakings": run.emergency_brakings,
            }
        )
    return rows


def main() -> int:
    cfg = load_config("milan")
    print("| call (one AV, one step) | speed | next, no call | next, with call |")
    print("|---|---|---|---|")
    for r in one_step_probes(cfg):
        print(
            f"| {r['call']} ({r['vehicle']}, step {r['step']}) | {r['speed']:.3f} "
            f"| {r['next_without']:.3f} | {r['next_with']:.3f} |"
        )
    print("\n| AV field = value | per-vehicle setter | vType s | setter s ", end="")
    print("| AV vType s | same crossing time |\n|---|---|---|---|---|---|")
    for r in setter_probes(cfg):
        print(
            f"| {r['field']} = {r['value']:g} | {r['setter']} | {r['vtype_s']:.3f} "
            f"| {r['setter_s']:.3f} | {r['base_s']:.3f} | {r['same_vehicles']:.1%} |"
        )
    print("\n| AVs commanded v + accel*dt, speed mode | crossing s | CO2 g ", end="")
    print("| collisions | emergency brakings |\n|---|---|---|---|---|")
    for r in speed_mode_probes(cfg):
        mode = "uncontrolled" if r["speed_mode"] is None else r["speed_mode"]
        print(
            f"| {mode} | {r['crossing_s']:.2f} | {r['co2_g']:.2f} "
            f"| {r['collisions']} | {r['emergency_brakings']} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
