"""Run schedules in SUMO through libsumo, one process per simulation.

libsumo holds one simulation per process, so each run happens in a worker
process; `run_many` runs several side by side. A controller, called after
every step, can drive vehicles (`sumo_export.controller.PolicyController`);
`run_many` builds one per run inside its worker from a picklable factory,
in a local process pool or on a Ray cluster (`sumo_export.executors`).
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jaxround.scenario.config import DRAIN_S, ScenarioConfig
from jaxround.scenario.edges import in_edge
from jaxround.scenario.records import VehicleRecords
from jaxround.scenario.schedule import Schedule
from sumo_export.conflicts import read_conflicts
from sumo_export.executors import sumo_pool
from sumo_export.scenario import vehicle_id, write_scenario

#: Called as ``controller(libsumo, time_s)`` after every SUMO step.
Controller = Callable[[Any, float], None]
#: Builds a run's controller inside its worker process: ``factory(cfg, schedule)``.
#: It must pickle (e.g. a frozen dataclass); a controller with a ``report()``
#: method has its report kept in `SumoRun.controller_report`.
ControllerFactory = Callable[[ScenarioConfig, Schedule], Controller]


@dataclass(frozen=True)
class SumoRun:
    """One SUMO run: what happened to every vehicle, and the safety counters."""

    records: VehicleRecords
    collisions: int
    emergency_brakings: int
    teleports: int
    sim_end_s: float
    wall_s: float = 0.0  # seconds the simulation loop took, controller included
    controller_report: dict[str, Any] | None = None  # the controller's report()
    #: float (T, n_legs) queued vehicles per leg after each step of the horizon
    queues: np.ndarray | None = None
    #: the SSM device's conflicts by encounter type, ``{type: count}``
    conflict_types: dict[str, int] | None = None
    #: lane changes of all vehicles (SUMO's --lanechange-output; 0 on one lane)
    lane_changes: int = 0
    #: vehicle-seconds on each normal lane, ``{lane id: s}`` (SUMO's
    #: --lanedata-output ``sampledSeconds``); None on one-lane roads
    lane_seconds: dict[str, float] | None = None


def run_schedule(
    cfg: ScenarioConfig,
    schedule: Schedule,
    workdir: str | Path | None = None,
    controller: Controller | None = None,
    drain_s: float = DRAIN_S,
) -> SumoRun:
    """Run one schedule in SUMO in *this* process (libsumo: one run per process).

    Args:
        cfg: the scenario.
        schedule: the vehicles to insert.
        workdir: where the scenario files and SUMO's outputs go; a temporary
            folder if None.
        controller: called as ``controller(libsumo, time_s)`` after every step,
            e.g. to drive the AVs.
        drain_s: seconds after the demand horizon the run may go on for its
            last vehicles (the cap is the horizon plus this).

    Returns:
        A `SumoRun` with one record per scheduled vehicle.
    """
    import libsumo

    with tempfile.TemporaryDirectory(prefix="jaxround-sumo-") as tmp:
        out = Path(workdir) if workdir is not None else Path(tmp)
        files = write_scenario(cfg, schedule, out)
        tripinfo = out / "tripinfo.xml"
        stats = out / "statistics.xml"
        ssm = out / "ssm.xml"
        lane_change_file = out / "lanechange.xml"
        args = sumo_arguments(files.sumocfg, tripinfo, stats)
        args += cfg.safety.sumo_options(str(ssm))
        args += ["--lanechange-output", str(lane_change_file)]
        lane_data = None if cfg.network.single_lane else out / "lanedata.xml"
        if lane_data is not None:
            args += ["--lanedata-output", str(lane_data)]
        libsumo.start(args)
        try:
            started = time.perf_counter()
            queues = _simulate(libsumo, cfg, schedule, controller, drain_s)
            wall = time.perf_counter() - started
            sim_end = libsumo.simulation.getTime()
        finally:
            libsumo.close()
        conflicts = read_conflicts(ssm, schedule.n_vehicles)
        records = dataclasses.replace(
            _read_tripinfo(tripinfo, schedule, queues),
            conflicts=conflicts.count,
            min_ttc_s=conflicts.min_ttc_s,
            max_drac_mps2=conflicts.max_drac_mps2,
        )
        collisions, emergency, teleports = _read_statistics(stats)
        per_vehicle = read_lane_changes(lane_change_file, schedule.n_vehicles)
        if not cfg.network.single_lane:
            records = dataclasses.replace(records, lane_changes=per_vehicle)
        lane_seconds = None if lane_data is None else read_lane_seconds(lane_data)
    return SumoRun(
        records=records,
        collisions=collisions,
        emergency_brakings=emergency,
        teleports=teleports,
        sim_end_s=float(sim_end),
        wall_s=wall,
        queues=queues,
        conflict_types=conflicts.by_type,
        lane_changes=int(per_vehicle.sum()),
        lane_seconds=lane_seconds,
    )


def read_lane_seconds(path: Path) -> dict[str, float]:
    """``sampledSeconds`` of every lane in SUMO's lane data, summed over its
    intervals."""
    seconds: dict[str, float] = {}
    for lane in ET.parse(path).getroot().iter("lane"):
        lane_id = lane.get("id", "")
        seconds[lane_id] = seconds.get(lane_id, 0.0) + float(
            lane.get("sampledSeconds", 0.0)
        )
    return seconds


def read_lane_changes(path: Path, n_vehicles: int) -> np.ndarray:
    """int (N,): the lane changes of each scheduled vehicle in SUMO's
    ``--lanechange-output`` (one ``<change id=...>`` line per change)."""
    counts = np.zeros(n_vehicles, np.int64)
    for change in ET.parse(path).getroot().iter("change"):
        counts[int(change.get("id")[1:])] += 1
    return counts


def sumo_arguments(sumocfg: Path, tripinfo: Path, stats: Path) -> list[str]:
    """The libsumo command line of a run: emissions on every vehicle, trip and
    statistics output, quiet."""
    return [
        "sumo",
        "-c", str(sumocfg),
        "--tripinfo-output", str(tripinfo),
        "--device.emissions.probability", "1",
        "--statistic-output", str(stats),
        "--duration-log.disable", "true",
        "--no-step-log", "true",
        "--no-warnings", "true",
    ]  # fmt: skip


def _simulate(
    libsumo: object,
    cfg: ScenarioConfig,
    schedule: Schedule,
    controller: Controller | None,
    drain_s: float,
) -> np.ndarray:
    """Step until every vehicle has left or the cap (horizon + `drain_s`);
    return queue lengths, shape (T, n_legs)."""
    n_legs = cfg.n_legs
    horizon = cfg.demand.duration_s
    max_time = horizon + drain_s
    edges = [in_edge(i) for i in range(n_legs)]
    origin_of = {vehicle_id(i): int(o) for i, o in enumerate(schedule.origin)}
    samples = []
    sim = libsumo.simulation
    while sim.getMinExpectedNumber() > 0 and sim.getTime() < max_time:
        sim.step()
        t = sim.getTime()
        if controller is not None:
            controller(libsumo, t)
        if t <= horizon:
            q = np.array([libsumo.edge.getLastStepHaltingNumber(e) for e in edges])
            for vid in sim.getPendingVehicles():
                q[origin_of[vid]] += 1
            samples.append(q)
    return np.asarray(samples, dtype=np.float64).reshape(-1, n_legs)


def _read_tripinfo(
    path: Path, schedule: Schedule, queues: np.ndarray
) -> VehicleRecords:
    n = schedule.n_vehicles
    arrival = np.full(n, np.nan)
    depart = np.full(n, np.nan)
    co2 = np.full(n, np.nan)
    fuel = np.full(n, np.nan)
    for trip in ET.parse(path).getroot().iter("tripinfo"):
        i = int(trip.get("id")[1:])
        depart[i] = float(trip.get("depart"))
        arrival[i] = float(trip.get("arrival"))
        em = trip.find("emissions")
        if em is not None:
            co2[i] = float(em.get("CO2_abs")) / 1000.0  # mg -> g
            fuel[i] = float(em.get("fuel_abs")) / 1000.0
    empty = np.zeros(queues.shape[1])
    return VehicleRecords(
        is_av=schedule.is_av.copy(),
        origin=schedule.origin.copy(),
        scheduled_depart_s=schedule.depart_s.copy(),
        depart_s=depart,
        arrival_s=arrival,
        co2_g=co2,
        fuel_g=fuel,
        queue_mean_veh=queues.mean(axis=0) if len(queues) else empty,
        queue_max_veh=queues.max(axis=0) if len(queues) else empty,
    )


def _read_statistics(path: Path) -> tuple[int, int, int]:
    """(collisions, emergency brakings, teleports) from SUMO's --statistic-output."""
    root = ET.parse(path).getroot()
    safety = root.find("safety")
    teleports = root.find("teleports")
    collisions = int(safety.get("collisions", 0)) if safety is not None else 0
    emergency = int(safety.get("emergencyBraking", 0)) if safety is not None else 0
    n_teleports = int(teleports.get("total", 0)) if teleports is not None else 0
    return collisions, emergency, n_teleports


def _run_job(
    job: tuple[ScenarioConfig, Schedule, ControllerFactory | None, float],
) -> SumoRun:
    cfg, schedule, factory, drain_s = job
    if factory is None:
        return run_schedule(cfg, schedule, drain_s=drain_s)
    controller = factory(cfg, schedule)
    run = run_schedule(cfg, schedule, controller=controller, drain_s=drain_s)
    report = getattr(controller, "report", None)
    if report is None:
        return run
    return dataclasses.replace(run, controller_report=report())


def run_many(
    cfg: ScenarioConfig,
    schedules: Sequence[Schedule],
    workers: int | None = None,
    progress: Callable[[SumoRun], None] | None = None,
    controller: ControllerFactory | None = None,
    executor: str | None = None,
    drain_s: float = DRAIN_S,
) -> list[SumoRun]:
    """Run several schedules, each in its own SUMO process, in parallel.

    Args:
        cfg: the scenario shared by all runs.
        schedules: one schedule per run.
        workers: processes side by side; defaults to the number of CPUs.
        progress: called once per finished run (in completion order).
        controller: builds each run's controller in its worker process
            (e.g. `sumo_export.controller.PolicyControllerFactory`); None
            leaves every vehicle to SUMO.
        executor: "local" (a process pool) or "ray"; None: the process's
            choice (`sumo_export.executors.use_executor`, "local" by default).
        drain_s: as `run_schedule`'s.

    Returns:
        One `SumoRun` per schedule, in the order given.
    """
    workers = workers or min(len(schedules), os.cpu_count() or 1)
    with sumo_pool(workers, executor) as pool:
        jobs = [(cfg, s, controller, drain_s) for s in schedules]
        futures = [pool.submit(_run_job, job) for job in jobs]
        results = []
        for fut in futures:
            run = fut.result()
            if progress is not None:
                progress(run)
            results.append(run)
    return results
