"""LC2013 on a two-lane roundabout: JAX's lane changes against SUMO's, step
by step, from SUMO's own traffic.

    python -m jaxround.apps.ring_lane_replay --config two_lane --duration 600

SUMO 1.28 runs the scenario (libsumo, the settings of `jaxround sumo`, human
drivers); after each step every vehicle's lane, position, speed and
acceleration are read, and each vehicle is followed along the lane paths
(`jaxround.lanes.paths`), which tells the lane changes SUMO made in the
step. The JAX changer (`jaxround.lanes.ring_changer`) then decides the same
step from SUMO's state before those changes (the changed vehicles put back
on their lanes, the vehicles inserted in the step left out), carrying its
own LC2013 memory from step to step. Its changes are compared with SUMO's:
the same vehicle, step and direction. Speeds and positions always come from
SUMO (the replay is open loop), so the figures measure the lane-change
decisions alone.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import xml.etree.ElementTree as ET
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from jaxround.analysis.report import markdown_table
from jaxround.lanes import actions as lca
from jaxround.lanes import ring_changer
from jaxround.lanes.best_lanes import LookAheadDriver
from jaxround.lanes.follow import Driver
from jaxround.lanes.memory import prepare_step
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.paths import LEFT, RIGHT, LanePaths
from jaxround.lanes.ring_tables import RingLanes, ring_lanes
from jaxround.lanes.views import Memory
from jaxround.scenario.config import DriverConfig, ScenarioConfig, load_config
from jaxround.scenario.schedule import Schedule, make_schedule
from jaxround.sumo_files.netconvert import network_file

#: SUMO's `MSVehicleControl::getMaxSpeedFactor` with its default vType loaded
#: (speedFactor normc(1, 0.1, 0.2, 2)): the followers' search distance.
MAX_SPEED_FACTOR = 2.0


_CHANGE = jax.jit(ring_changer.change_lanes, static_argnums=4)


@dataclass
class StepRecord:
    """One SUMO step, after its lane changes. Arrays over the vehicles on
    the network (ids in ``ids``): the lane path and position along it before
    the step's changes, the lane change made (-1 right, +1 left, 0 none),
    speed, acceleration, speed factor, AV or not, inserted this step."""

    time: float
    ids: list[str]
    path: np.ndarray
    pos: np.ndarray
    change: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    speed_factor: np.ndarray
    is_av: np.ndarray
    new: np.ndarray


@dataclass
class PathTracker:
    """Follows SUMO's vehicles along the lane paths (see the module doc)."""

    paths: LanePaths
    state: dict[str, int] = field(default_factory=dict)  # id -> path

    def __post_init__(self) -> None:
        self.index = {lid: k for k, lid in enumerate(self.paths.lane_ids)}
        self.edge = [lid.rsplit("_", 1)[0] for lid in self.paths.lane_ids]

    def step(self, vid: str, lane_id: str, route: int) -> tuple[int, int, int]:
        """(path before the step's change, path after, change -1/0/+1)."""
        lane = self.index[lane_id]
        if vid not in self.state:
            path = int(self.paths.depart_path[route, self.paths.lane_index[lane]])
            self.state[vid] = path
            return path, path, 0
        path = self.state[vid]
        on_path = next(
            int(x) for x in self.paths.path_lanes[path]
            if x >= 0 and self.edge[x] == self.edge[lane]
        )  # fmt: skip
        if on_path == lane:
            return path, path, 0
        side = LEFT if self.paths.lane_left[on_path] == lane else RIGHT
        k = int(np.nonzero(self.paths.path_lanes[path] == on_path)[0][0])
        new = int(self.paths.change_path[path, k, side])
        if new < 0 or self.paths.path_lanes[new, k] != lane:
            raise ValueError(f"{vid}: a change to {lane_id} the paths do not allow")
        self.state[vid] = new
        return path, new, 1 if side == LEFT else -1


def record_sumo(
    cfg: ScenarioConfig,
    paths: LanePaths,
    duration_s: float,
    schedule: Schedule,
) -> tuple[list[StepRecord], dict[tuple[float, str], str]]:
    """Run the first ``duration_s`` seconds of ``schedule`` in SUMO.

    Returns the steps and SUMO's reason for each change, by (time, id).
    """
    import libsumo

    from sumo_export.runner import sumo_arguments
    from sumo_export.scenario import AV_TYPE, write_scenario

    steps: list[StepRecord] = []
    dt = cfg.simulation.dt_s
    with tempfile.TemporaryDirectory(prefix="jaxround-lanes-") as tmp:
        out = Path(tmp)
        files = write_scenario(cfg, schedule, out)
        changes_xml = out / "changes.xml"
        libsumo.start(
            sumo_arguments(files.sumocfg, out / "trips.xml", out / "stats.xml")
            + ["--lanechange-output", str(changes_xml)]
        )
        tracker = PathTracker(paths)
        route_of = {}
        try:
            vehicle = libsumo.vehicle
            for _ in tqdm(range(int(round(duration_s / dt))), desc="SUMO", leave=False):
                libsumo.simulationStep()
                ids = list(vehicle.getIDList())
                new = np.array([vid not in tracker.state for vid in ids], bool)
                rows = []
                for vid, is_new in zip(ids, new, strict=True):
                    if is_new:
                        o, d = (int(x) for x in vehicle.getRouteID(vid).split("_")[1:])
                        route_of[vid] = int(paths.route_index[o, d])
                    before, _, change = tracker.step(
                        vid, vehicle.getLaneID(vid), route_of[vid]
                    )
                    lane = tracker.index[vehicle.getLaneID(vid)]
                    own = (
                        lane
                        if change == 0
                        else (paths.lane_right if change > 0 else paths.lane_left)[lane]
                    )
                    rows.append((
                        before, paths.lane_offset[before, own]
                        + vehicle.getLanePosition(vid), change,
                        vehicle.getSpeed(vid), vehicle.getAcceleration(vid),
                        vehicle.getSpeedFactor(vid),
                        vehicle.getTypeID(vid) == AV_TYPE,
                    ))  # fmt: skip
                for vid in libsumo.simulation.getArrivedIDList():
                    tracker.state.pop(vid, None)
                columns = list(zip(*rows, strict=True)) if rows else [()] * 7
                steps.append(StepRecord(
                    time=libsumo.simulation.getTime(), ids=ids,
                    path=np.array(columns[0], np.int32), pos=np.array(columns[1]),
                    change=np.array(columns[2], np.int32),
                    speed=np.array(columns[3]), accel=np.array(columns[4]),
                    speed_factor=np.array(columns[5]),
                    is_av=np.array(columns[6], bool), new=new,
                ))  # fmt: skip
        finally:
            libsumo.close()
        # the output's time is the step's start, the records' its end
        reasons = {
            (float(c.get("time")) + dt, c.get("id")): c.get("reason", "")
            for c in ET.parse(changes_xml).getroot().iter("change")
        }
    return steps, reasons


def _driver(d: DriverConfig) -> Driver:
    return Driver(d.accel, d.decel, d.emergency_decel, d.tau, d.min_gap, d.length,
                  d.delta, d.max_speed)  # fmt: skip


def replay(
    cfg: ScenarioConfig,
    tables: RingLanes,
    steps: list[StepRecord],
    reasons: dict[tuple[float, str], str],
    lc: LaneChangeParams | None = None,
) -> dict[str, Any]:
    """The JAX changer on SUMO's recorded steps; the tally of the comparison."""
    lc = lc or LaneChangeParams()
    dt = cfg.simulation.dt_s
    min_decel = min(cfg.drivers.hv.decel, cfg.drivers.av.decel, 4.5)
    net = ring_changer.RingArrays.from_tables(tables, MAX_SPEED_FACTOR, min_decel)
    # slots in sixteens, so that runs of similar traffic share one compilation
    # (a step costs about M^2: the scan takes M turns of (M,) work)
    n_slots = 16 * -(-(max(len(s.ids) for s in steps) + 8) // 16)
    hv, av = _driver(cfg.drivers.hv), _driver(cfg.drivers.av)
    memory = Memory.zeros(n_slots)
    slot_of: dict[str, int] = {}
    tally: Counter = Counter()
    mismatches: list[dict[str, Any]] = []
    jax_only: set[tuple[str, int]] = set()
    for rec in tqdm(steps, desc="JAX", leave=False):
        for vid in list(slot_of):
            if vid not in rec.ids:
                del slot_of[vid]
        free = sorted(set(range(n_slots)) - set(slot_of.values()))
        fresh = np.zeros(n_slots, bool)
        for vid in rec.ids:
            if vid not in slot_of:
                slot_of[vid] = free.pop(0)
                fresh[slot_of[vid]] = True
        slots = np.array([slot_of[v] for v in rec.ids], np.int32)
        memory = jax.tree.map(
            lambda x, z: jnp.where(fresh.reshape(-1, *([1] * (x.ndim - 1))), z, x),
            memory, Memory.zeros(n_slots),
        )  # fmt: skip
        active = np.zeros(n_slots, bool)
        active[slots] = ~rec.new

        def spread(values, fill=0.0, slots=slots):
            out = np.full(n_slots, fill, np.asarray(values).dtype)
            out[slots] = values
            return out

        is_av = spread(rec.is_av, False)
        driver = jax.tree.map(lambda h, a: jnp.where(is_av, a, h), hv, av)
        veh = ring_changer.RingVehicles(
            path=jnp.asarray(spread(rec.path, 0)), pos=jnp.asarray(spread(rec.pos)),
            speed=jnp.asarray(spread(rec.speed)), accel=jnp.asarray(spread(rec.accel)),
            active=jnp.asarray(active), driver=driver,
            speed_factor=jnp.asarray(spread(rec.speed_factor, 1.0)),
        )  # fmt: skip
        memory = prepare_step(memory)
        result, memory = _CHANGE(net, veh, memory, lc, dt)
        jax_dir = np.asarray(result.direction)[slots]
        sight = jax.tree.map(np.asarray, result.sight)
        id_of = {slot: vid for vid, slot in slot_of.items()}
        for n, vid in enumerate(rec.ids):
            if rec.new[n]:
                continue
            sumo, mine = int(rec.change[n]), int(jax_dir[n])
            if sumo:
                reason = reasons.get((rec.time, vid), "?")
                tally[f"sumo {reason}"] += 1
                tally["sumo"] += 1
            if mine:
                tally["jax"] += 1
            if sumo and sumo == mine:
                tally["matched"] += 1
            elif sumo or mine:
                tally["sumo only" if sumo else "jax only"] += 1
                if mine and not sumo:
                    jax_only.add((vid, mine))
                lane_id = tables.paths.lane_ids[
                    int(tables.paths.path_lanes[rec.path[n]][
                        np.searchsorted(
                            np.nan_to_num(tables.paths.path_lane_start[rec.path[n]],
                                          nan=np.inf), rec.pos[n], side="right") - 1])
                ]  # fmt: skip
                mismatches.append({
                    "time": rec.time, "id": vid, "lane": lane_id, "sumo": sumo,
                    "jax": mine, "reason": reasons.get((rec.time, vid), ""),
                    "jax_state": int(np.asarray(result.state)[slot_of[vid]]),
                    **_seen(sight, slot_of[vid], id_of),
                })  # fmt: skip
    tally["jax only, vehicles"] = len(jax_only)
    return {"tally": dict(tally), "mismatches": mismatches}


def _seen(sight: Any, slot: int, id_of: dict[int, str]) -> dict[str, Any]:
    """What a vehicle saw right and left, with vehicle ids."""
    out = {}
    for side, name in ((0, "right"), (1, "left")):
        out[name] = {
            "state": reason_bits(int(sight.state[slot, side])),
            "lead": id_of.get(int(sight.lead[slot, side])),
            "lead_gap": _finite(sight.lead_gap[slot, side]),
            "follow": id_of.get(int(sight.follow[slot, side])),
            "follow_gap": _finite(sight.follow_gap[slot, side]),
            "bonus": round(float(sight.bonus[slot, side]), 1),
        }
    return out


def _finite(x: Any) -> float | None:
    """A gap for JSON: rounded, None where there is nobody (inf)."""
    x = float(x)
    return round(x, 2) if np.isfinite(x) else None


def reason_bits(state: int) -> str:
    """A state's bits by name, e.g. "left|cooperative|blocked_by_left_follower"."""
    names = [name.lower() for name, bit in vars(lca).items()
             if name.isupper() and isinstance(bit, int) and bit & (bit - 1) == 0
             and state & bit]  # fmt: skip
    return "|".join(names)


def summary(result: dict[str, Any]) -> str:
    """The comparison as two markdown tables: the counts, and where JAX
    changes lanes alone (each vehicle's first such step, by lane and wish)."""
    tally = result["tally"]
    sumo = tally.get("sumo", 0)
    rows = [["SUMO's changes", str(sumo)]]
    rows += [[f"  of them {k[5:].replace('|', ', ')}", str(v)]
             for k, v in sorted(tally.items())
             if k.startswith("sumo ") and k != "sumo only"]  # fmt: skip
    matched = tally.get("matched", 0)
    share = f" ({100.0 * matched / sumo:.1f}%)" if sumo else ""
    rows += [
        ["made by JAX in the same step and direction", f"{matched}{share}"],
        ["made by SUMO only", str(tally.get("sumo only", 0))],
        ["steps where JAX changes and SUMO does not", str(tally.get("jax only", 0))],
        ["vehicles JAX moves where SUMO does not",
         str(tally.get("jax only, vehicles", 0))],
    ]  # fmt: skip
    first: dict[tuple[str, int], dict[str, Any]] = {}
    for m in result["mismatches"]:
        if m["jax"] and not m["sumo"]:
            first.setdefault((m["id"], m["jax"]), m)
    where = Counter(
        (m["lane"].rsplit("_", 1)[0], "left" if m["jax"] > 0 else "right",
         lca.reason(m["jax_state"]).replace("|", ", "))
        for m in first.values()
    )  # fmt: skip
    alone = [[edge, side, why, str(n)] for (edge, side, why), n in where.most_common()]
    return (
        markdown_table(("", "count"), rows)
        + "\nWhere JAX changes alone (first step per vehicle):\n\n"
        + markdown_table(("edge", "to the", "JAX's reason", "vehicles"), alone)
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="two_lane", help="a built-in or a file")
    parser.add_argument("--duration", type=float, default=600.0, help="seconds")
    parser.add_argument("--seed", type=int, default=0, help="schedule seed")
    parser.add_argument("--json", type=Path, help="write the comparison here (new)")
    args = parser.parse_args(argv)
    if args.duration <= 0:
        parser.error(f"--duration {args.duration}: expected seconds > 0")
    if args.seed < 0:
        parser.error(f"--seed {args.seed}: expected >= 0")
    if args.json is not None and args.json.exists():
        parser.error(f"--json {args.json}: exists; give a new file")
    cfg = load_config(args.config)
    net = network_file(cfg)
    driver = LookAheadDriver.from_config(cfg.drivers.hv, cfg.simulation.dt_s)
    tables = ring_lanes(net, driver)
    if (tables.paths.change_path < 0).all():
        parser.error(f"--config {args.config}: no edge has two lanes to change between")
    schedule = make_schedule(cfg, args.seed)
    steps, reasons = record_sumo(cfg, tables.paths, args.duration, schedule)
    result = replay(cfg, tables, steps, reasons)
    print(summary(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
