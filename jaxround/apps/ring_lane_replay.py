"""LC2013 on a two-lane roundabout: JAX's lane changes against SUMO's, step
by step, from SUMO's own traffic.

    python -m jaxround.apps.ring_lane_replay --config two_lane --duration 600
    python -m jaxround.apps.ring_lane_replay --penetration 0.5 --policy gap:10

SUMO 1.28 runs the scenario and its lane changes are recorded step by step
(`jaxround.apps.ring_lane_record`). The JAX changer (`jaxround.lanes.ring_rounds`,
the same changes as `jaxround.lanes.ring_turns`) then decides the same
step from SUMO's state before those changes (the changed vehicles put back
on their lanes, the vehicles inserted in the step left out), carrying its
own LC2013 memory from step to step and taking the edges in the order SUMO
did (its list of active lanes followed from the records, `RecordedOrder`;
`jaxround.lanes.active_lanes`). Its changes are compared with SUMO's:
the same vehicle, step and direction. Speeds and positions always come from
SUMO (the replay is open loop), so the figures measure the lane-change
decisions alone. With ``--policy`` SUMO's AVs get TraCI lane requests
before every step (`ring_lane_record.scripted_policy`), and the JAX
changer the same ones (docs/lc2013-map.md section 13).
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from jaxround.analysis.report import markdown_table
from jaxround.apps.ring_lane_record import StepRecord, record_sumo, scripted_policy
from jaxround.envs.lane_changes import changer_arrays, changer_tables, driver_numbers
from jaxround.lanes import actions as lca
from jaxround.lanes import ring_changer, ring_rounds
from jaxround.lanes.active_lanes import TurnOrder, after_changes
from jaxround.lanes.memory import prepare_step
from jaxround.lanes.params import LaneChangeParams
from jaxround.lanes.ring_tables import RingLanes
from jaxround.lanes.views import Memory
from jaxround.scenario.config import ScenarioConfig, load_config
from jaxround.scenario.schedule import make_schedule
from jaxround.sumo_files.netconvert import network_file

_CHANGE = jax.jit(ring_rounds.change_lanes, static_argnums=4)


@dataclass
class SlotBook:
    """SUMO's vehicles in slots of the JAX arrays, step after step: a
    vehicle keeps its slot while it is on the network."""

    cfg: ScenarioConfig
    n_slots: int
    slot_of: dict[str, int] = field(default_factory=dict)
    #: the largest speed factor of the vehicles departed so far (SUMO's
    #: followers' search; a vehicle departs after the step's changes)
    fastest: float = 1.0

    @classmethod
    def for_steps(cls, cfg: ScenarioConfig, steps: list[StepRecord]) -> SlotBook:
        """Slots in sixteens, so that runs of similar traffic share one
        compilation (a step costs about M^2)."""
        return cls(cfg, 16 * -(-(max(len(s.ids) for s in steps) + 8) // 16))

    def vehicles(
        self, rec: StepRecord, memory: Memory
    ) -> tuple[ring_changer.RingVehicles, Memory, np.ndarray]:
        """The step's vehicles (new ones inactive), the memory with new
        vehicles' rows cleared and `prepare_step` done, and each recorded
        vehicle's slot (len(ids),)."""
        for vid in list(self.slot_of):
            if vid not in rec.ids:
                del self.slot_of[vid]
        free = sorted(set(range(self.n_slots)) - set(self.slot_of.values()))
        fresh = np.zeros(self.n_slots, bool)
        for vid in rec.ids:
            if vid not in self.slot_of:
                self.slot_of[vid] = free.pop(0)
                fresh[self.slot_of[vid]] = True
        slots = np.array([self.slot_of[v] for v in rec.ids], np.int32)
        memory = jax.tree.map(
            lambda x, z: jnp.where(fresh.reshape(-1, *([1] * (x.ndim - 1))), z, x),
            memory, Memory.zeros(self.n_slots),
        )  # fmt: skip
        active = np.zeros(self.n_slots, bool)
        active[slots] = ~rec.new
        if active[slots].any():
            self.fastest = max(self.fastest, float(rec.speed_factor[~rec.new].max()))

        def spread(values, fill=0.0):
            out = np.full(self.n_slots, fill, np.asarray(values).dtype)
            out[slots] = values
            return out

        is_av = spread(rec.is_av, False)
        hv, av = (
            driver_numbers(self.cfg.drivers.hv),
            driver_numbers(self.cfg.drivers.av),
        )
        driver = jax.tree.map(lambda h, a: jnp.where(is_av, a, h), hv, av)
        veh = ring_changer.RingVehicles(
            path=jnp.asarray(spread(rec.path, 0)), pos=jnp.asarray(spread(rec.pos)),
            speed=jnp.asarray(spread(rec.speed)), accel=jnp.asarray(spread(rec.accel)),
            active=jnp.asarray(active), driver=driver,
            speed_factor=jnp.asarray(spread(rec.speed_factor, 1.0)),
            lane_request=jnp.asarray(spread(rec.request, -1)),
            fastest_departed=jnp.float32(self.fastest),
        )  # fmt: skip
        return veh, prepare_step(memory), slots


@dataclass
class RecordedOrder:
    """SUMO's list of active lanes (`jaxround.lanes.active_lanes`) followed
    from the records, step by step, as the step follows its own: the
    changer takes the edges in the order SUMO did."""

    net: ring_changer.RingArrays
    order: TurnOrder
    dt: float
    stamp: jax.Array

    def before_changes(
        self, rec: StepRecord, veh: ring_changer.RingVehicles, slots: np.ndarray
    ) -> jax.Array:
        """This step's `RingArrays.lane_order` from SUMO's vehicles after the
        move (``veh``, the recorded ones in ``slots``); the stamps then
        take SUMO's changes of the step (``rec.change``)."""
        self.stamp, arrays = self.order.before_changes(
            self.stamp, path=veh.path, pos=veh.pos, speed=veh.speed,
            active=veh.active, dt=self.dt,
        )  # fmt: skip
        _, lane, _ = ring_changer.locate(self.net, veh.path, veh.pos)
        lane = np.array(lane)
        change = np.zeros(lane.shape, np.int32)
        change[slots] = rec.change
        beside = np.asarray(self.net.lane_side)[lane, (change > 0).astype(int)]
        lane = np.where(change != 0, beside, lane)
        self.stamp = after_changes(
            self.net, self.stamp, arrays.lane_order, jnp.asarray(lane), veh.active
        )
        return arrays.lane_order


def tables_for(cfg: ScenarioConfig) -> RingLanes:
    """The changer's tables of a config's network, for its human drivers."""
    return changer_tables(cfg, network_file(cfg))


def arrays(cfg: ScenarioConfig, tables: RingLanes) -> ring_changer.RingArrays:
    """The changer's network arrays for a config's vTypes."""
    return changer_arrays(cfg, tables)


def replay(
    cfg: ScenarioConfig,
    tables: RingLanes,
    steps: list[StepRecord],
    reasons: dict[tuple[float, str], str],
    lc: LaneChangeParams | None = None,
) -> dict[str, Any]:
    """The JAX changer on SUMO's recorded steps; the tally of the comparison
    and how many rounds `ring_rounds` took per step."""
    lc = lc or LaneChangeParams()
    dt = cfg.simulation.dt_s
    net = arrays(cfg, tables)
    book = SlotBook.for_steps(cfg, steps)
    slot_of = book.slot_of
    memory = Memory.zeros(book.n_slots)
    tally: Counter = Counter()
    rounds: Counter = Counter()
    mismatches: list[dict[str, Any]] = []
    jax_only: set[tuple[str, int]] = set()
    order = TurnOrder.of(network_file(cfg), tables.paths.lane_ids, net)
    recorded = RecordedOrder(
        net, order, dt, jnp.zeros(len(tables.paths.lane_ids), jnp.int32)
    )
    for rec in tqdm(steps, desc="JAX", leave=False):
        veh, memory, slots = book.vehicles(rec, memory)
        ordered = net._replace(lane_order=recorded.before_changes(rec, veh, slots))
        result, memory, n_rounds = _CHANGE(ordered, veh, memory, lc, dt)
        rounds[int(n_rounds)] += 1
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
    return {
        "tally": dict(tally),
        "rounds": {str(n): rounds[n] for n in sorted(rounds)},
        "mismatches": mismatches,
    }


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
    rounds = ", ".join(f"{n}: {c}" for n, c in result.get("rounds", {}).items())
    return (
        markdown_table(("", "count"), rows)
        + f"\nRounds to settle the changes (rounds: steps): {rounds}\n"
        + "\nWhere JAX changes alone (first step per vehicle):\n\n"
        + markdown_table(("edge", "to the", "JAX's reason", "vehicles"), alone)
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="two_lane", help="a built-in or a file")
    parser.add_argument("--duration", type=float, default=600.0, help="seconds")
    parser.add_argument("--seed", type=int, default=0, help="schedule seed")
    parser.add_argument("--json", type=Path, help="write the comparison here (new)")
    parser.add_argument(
        "--penetration", type=float, help="share of AVs (default: the config's)"
    )
    parser.add_argument("--policy", help="the AVs' scripted lane requests: inner, "
                        "outer or gap:X (m)")  # fmt: skip
    args = parser.parse_args(argv)
    if args.duration <= 0:
        parser.error(f"--duration {args.duration}: expected seconds > 0")
    if args.seed < 0:
        parser.error(f"--seed {args.seed}: expected >= 0")
    if args.json is not None and args.json.exists():
        parser.error(f"--json {args.json}: exists; give a new file")
    if args.penetration is not None and not 0.0 <= args.penetration <= 1.0:
        parser.error(f"--penetration {args.penetration}: expected a share in [0, 1]")
    try:
        policy = scripted_policy(args.policy) if args.policy else None
    except ValueError as err:
        parser.error(f"--policy: {err}")
    cfg = load_config(args.config)
    tables = tables_for(cfg)
    if (tables.paths.change_path < 0).all():
        parser.error(f"--config {args.config}: no edge has two lanes to change between")
    schedule = make_schedule(cfg, args.seed, penetration=args.penetration)
    steps, reasons = record_sumo(
        cfg, tables.paths, args.duration, schedule, lane_policy=policy
    )
    result = replay(cfg, tables, steps, reasons)
    print(summary(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
