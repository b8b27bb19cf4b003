"""LC2013 in JAX against SUMO 1.28 on straight two-lane roads.

    python -m jaxround.apps.lane_parity --seeds 0-9 --vehicles 30 40

Each road is a 1 km two-lane edge that vehicles of three top speeds
(half free, a quarter capped at 5 m/s, a quarter at 8) enter every 1 or
1.5 s on random lanes. It runs in SUMO (libsumo, 1 s steps, the IDM vType
without speed deviation) and in `jaxround.lanes.road`, started from SUMO's
state after each vehicle's insertion step, in float64 and float32; the
table gives the lane changes of each and the mean time on the road of the
vehicles that left it in all three (docs/lc2013-map.md, section 11). The
helpers are those `tests/sumo/test_lc2013_jax.py` compares with step by
step.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np
import sumolib
from tqdm import tqdm

from jaxround.analysis.report import markdown_table
from jaxround.lanes import road as lane_road
from jaxround.lanes.params import LaneChangeParams
from jaxround.sumo_files.binaries import sumo_binary

#: The road's speed limit (m/s).
V_MAX = 13.89
#: Top speeds of the vTypes `run_sumo` writes (m/s).
MAX_SPEED = {"t": 55.55, "slow": 5.0, "eight": 8.0}
#: Steps of a dense road (s).
DENSE_STEPS = 260

#: One jitted road for all runs: same shapes, one compilation.
_simulate = jax.jit(lane_road.simulate, static_argnums=(0, 3))


def two_lane_road(workdir: Path, length: float, left_only: bool) -> Path:
    """A two-lane edge `e1` of `length` m, 13.89 m/s. With `left_only`, only
    its left lane continues to `e2` (the right one leads to `e3`), so a
    vehicle routed e1 e2 on the right lane must change left."""
    far = length + 100
    (workdir / "n.nod.xml").write_text(
        f'<nodes><node id="A" x="0" y="0"/><node id="B" x="{length}" y="0"/>'
        f'<node id="C" x="{far}" y="0"/><node id="D" x="{far}" y="-100"/></nodes>'
    )
    edges = [f'<edge id="e1" from="A" to="B" numLanes="2" speed="{V_MAX}"/>']
    args = ["--no-turnarounds", "true"]
    if left_only:
        edges += [
            f'<edge id="{e}" from="B" to="{n}" numLanes="1" speed="{V_MAX}"/>'
            for e, n in (("e2", "C"), ("e3", "D"))
        ]
        (workdir / "n.con.xml").write_text(
            '<connections><connection from="e1" to="e2" fromLane="1" toLane="0"/>'
            '<connection from="e1" to="e3" fromLane="0" toLane="0"/></connections>'
        )
        args += ["-x", str(workdir / "n.con.xml")]
    (workdir / "n.edg.xml").write_text("<edges>" + "".join(edges) + "</edges>")
    net = workdir / "n.net.xml"
    subprocess.run(
        [sumo_binary("netconvert"), "-n", str(workdir / "n.nod.xml"),
         "-e", str(workdir / "n.edg.xml"), "-o", str(net), *args],
        check=True, capture_output=True,
    )  # fmt: skip
    return net


def run_sumo(
    workdir: Path,
    net: Path,
    vehicles: str,
    steps: int,
    probe: Callable[[int], None] | None = None,
    lc: str = "",
) -> list[dict[str, str]]:
    """Run `vehicles` (XML) for `steps` steps of 1 s in libsumo, calling
    `probe(t)` after each step t; the lane changes SUMO wrote."""
    import libsumo

    routes = workdir / "r.rou.xml"
    routes.write_text(
        f'<routes><vType id="t" carFollowModel="IDM" speedDev="0" {lc}/>'
        '<vType id="slow" carFollowModel="IDM" speedDev="0" maxSpeed="5"/>'
        '<vType id="eight" carFollowModel="IDM" speedDev="0" maxSpeed="8"/>'
        f"{vehicles}</routes>"
    )
    out = workdir / "lc.xml"
    libsumo.start(
        [sumo_binary("sumo"), "-n", str(net), "-r", str(routes),
         "--step-length", "1", "--no-step-log", "true", "--precision", "6",
         "--lanechange-output", str(out)]
    )  # fmt: skip
    try:
        for t in range(steps):
            libsumo.simulationStep()
            if probe is not None:
                probe(t)
    finally:
        libsumo.close()
    return [c.attrib for c in ET.parse(out).getroot().iter("change")]


def sumo_trace(
    workdir: Path, net: Path, vehicles: str, steps: int, lc: str = ""
) -> tuple[dict[str, np.ndarray], list[dict[str, str]]]:
    """Per vehicle (steps, 4): position, speed, lane, on e1 (NaN: absent)."""
    trace: dict[str, np.ndarray] = {}

    def probe(t: int) -> None:
        import libsumo

        for vid in libsumo.vehicle.getIDList():
            row = trace.setdefault(vid, np.full((steps, 4), np.nan))
            row[t] = (
                libsumo.vehicle.getLanePosition(vid),
                libsumo.vehicle.getSpeed(vid),
                libsumo.vehicle.getLaneIndex(vid),
                libsumo.vehicle.getRoadID(vid) == "e1",
            )

    return trace, run_sumo(workdir, net, vehicles, steps, probe, lc=lc)


def jax_run(
    net: Path,
    trace: dict[str, np.ndarray],
    types: dict[str, str],
    routes: dict[str, str],
    steps: int,
    lc: LaneChangeParams,
    slots: int = 8,
) -> tuple[list[str], lane_road.StepRecord]:
    """`jaxround.lanes.road` from SUMO's state in each vehicle's first step.
    ``routes`` maps a vehicle to "e1" (ends on the road) or "e1 e2" (only
    the left lane leads on); ``lc`` holds for the vType "t" (as
    `run_sumo` sets it), the others drive with LC2013's defaults. The
    vehicles fill at least ``slots`` slots (a multiple of 8), the rest
    never depart: runs of one slot count and length share a compilation."""
    sumo_net = sumolib.net.readNet(str(net))
    length = sumo_net.getLane("e1_0").getLength()
    ids = sorted(trace)
    first = [int(np.nonzero(~np.isnan(trace[v][:, 0]))[0][0]) for v in ids]
    start = np.array([trace[v][t] for v, t in zip(ids, first, strict=True)])
    leads_on = np.array([[routes[v] == "e1", True] for v in ids])
    # SUMO's LaneQ lengths add up normal lanes only (MSVehicle::updateBestLanes)
    after = sumo_net.getEdge("e2").getLength() if sumo_net.hasEdge("e2") else 0.0
    beyond = np.array([0.0 if routes[v] == "e1" else after for v in ids])
    slots = max(slots, -(-len(ids) // 8) * 8)
    pad = slots - len(ids)
    max_speed = [MAX_SPEED[types[v]] for v in ids] + [MAX_SPEED["t"]] * pad
    never = DENSE_STEPS * 100  # a padding slot's depart step: never
    is_t = np.array([types[v] == "t" for v in ids] + [True] * pad)
    traffic = lane_road.traffic(
        depart_pos=np.pad(start[:, 0], (0, pad)),
        depart_speed=np.pad(start[:, 1], (0, pad)),
        depart_lane=np.pad(start[:, 2].astype(int), (0, pad)),
        leads_on=np.pad(leads_on, ((0, pad), (0, 0)), constant_values=True),
        beyond=np.pad(beyond, (0, pad)),
        depart_step=np.pad(np.array(first), (0, pad), constant_values=never),
        driver=lane_road.default_driver(slots, max_speed),
        road_length=length,
    )
    default = LaneChangeParams()
    per_vehicle = jax.tree.map(
        lambda given, base: np.where(is_t, given, base), lc, default
    )
    road = lane_road.Road(n_lanes=2, speed_limit=V_MAX)
    _, record = _simulate(road, traffic, per_vehicle, steps - 1)
    record = jax.tree.map(lambda x: x[:, : len(ids)], record)
    return ids, record


def jax_run_x64(*args: Any, **kwargs: Any) -> tuple[list[str], lane_road.StepRecord]:
    """`jax_run` in double precision, as SUMO computes."""
    with jax.enable_x64(True):
        ids, record = jax_run(*args, **kwargs)
        return ids, jax.tree.map(np.asarray, record)


def vehicle_xml(vid: str, vtype: str, lane: int, pos: float, speed: float | str,
            route: str = "e1", depart: int = 0) -> str:  # fmt: skip
    return (
        f'<vehicle id="{vid}" type="{vtype}" depart="{depart}" departLane="{lane}" '
        f'departPos="{pos}" departSpeed="{speed}"><route edges="{route}"/></vehicle>'
    )


def dense_road(
    workdir: Path, seed: int, n: int, precisions: Sequence[str] = ("float32",)
) -> dict[str, Any]:
    """``n`` vehicles entering a 1 km road every 1.5 s (30 or fewer) or 1 s:
    SUMO's and JAX's lane changes (per precision), and the mean seconds on
    the road of the vehicles that left it in SUMO and every JAX run."""
    workdir.mkdir(parents=True, exist_ok=True)
    net = two_lane_road(workdir, 1000.0, left_only=False)
    rng = np.random.default_rng(seed)
    types, xml = {}, []
    spacing = 1.5 if n <= 30 else 1.0
    for k in range(n):
        vtype = str(rng.choice(["t", "t", "slow", "eight"]))
        vid = f"v{k:02d}"
        types[vid] = vtype
        speed = min(8.0, MAX_SPEED[vtype])
        lane = int(rng.integers(2))
        xml.append(vehicle_xml(vid, vtype, lane, 0, speed, depart=int(spacing * k)))
    trace, changes = sumo_trace(workdir, net, "".join(xml), DENSE_STEPS)
    routes = dict.fromkeys(types, "e1")
    ids = sorted(trace)
    left = np.array([np.isnan(trace[v][-1, 0]) for v in ids])
    on_road = np.array(
        [np.sum(~np.isnan(trace[v][1:, 0]) & (trace[v][1:, 3] == 1)) for v in ids]
    )
    runs = {}
    for precision in precisions:
        run = jax_run_x64 if precision == "float64" else jax_run
        _, record = run(
            net, trace, types, routes, DENSE_STEPS, LaneChangeParams(),
            slots=max(n, 32),
        )  # fmt: skip
        active = np.asarray(record.active)
        left &= ~active[-1]
        changed = int(np.count_nonzero(np.asarray(record.change_direction)))
        runs[precision] = (changed, active.sum(0))
    row: dict[str, Any] = {
        "seed": seed, "vehicles": n, "sumo_changes": len(changes),
        "sumo_time_s": float(on_road[left].mean()), "compared": int(left.sum()),
    }  # fmt: skip
    for precision, (changed, steps_on) in runs.items():
        row[f"{precision}_changes"] = changed
        row[f"{precision}_time_s"] = float(steps_on[left].mean())
    return row


def _seeds(text: str) -> list[int]:
    """ "0-9" or "0,3,5" as a list of ints."""
    if "-" in text:
        first, last = (int(x) for x in text.split("-"))
        return list(range(first, last + 1))
    return [int(x) for x in text.split(",")]


def report(rows: Sequence[dict[str, Any]]) -> str:
    """The rows of `dense_road` (float64 and float32) as a markdown table and
    the lane changes summed over the roads."""
    table = [
        [str(r["seed"]), str(r["vehicles"]), str(r["sumo_changes"]),
         str(r["float64_changes"]), str(r["float32_changes"]),
         f"{r['sumo_time_s']:.2f}",
         f"{100 * (r['float64_time_s'] / r['sumo_time_s'] - 1):+.2f}%",
         f"{100 * (r['float32_time_s'] / r['sumo_time_s'] - 1):+.2f}%"]
        for r in rows
    ]  # fmt: skip
    columns = (
        "seed", "vehicles", "changes SUMO", "JAX f64", "JAX f32",
        "time on road SUMO (s)", "JAX f64", "JAX f32",
    )  # fmt: skip
    total = {
        k: sum(r[f"{k}_changes"] for r in rows) for k in ("sumo", "float64", "float32")
    }
    return markdown_table(columns, table) + (
        f"\nlane changes over {len(rows)} roads: SUMO {total['sumo']}, "
        f"JAX float64 {total['float64']}, float32 {total['float32']}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m jaxround.apps.lane_parity", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--seeds", type=_seeds, default=_seeds("0-9"))
    parser.add_argument("--vehicles", type=int, nargs="+", default=[30, 40])
    parser.add_argument("--json", type=Path, help="also write the rows here")
    args = parser.parse_args(argv)
    if any(n < 2 or n > 99 for n in args.vehicles):
        parser.error(f"--vehicles {args.vehicles}: each between 2 and 99")
    if args.json is not None and args.json.exists():
        parser.error(f"--json {args.json}: exists; not overwritten")
    jobs = [(seed, n) for seed in args.seeds for n in args.vehicles]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed, n in tqdm(jobs, desc="roads (SUMO, JAX float64, float32)"):
            rows.append(
                dense_road(Path(tmp) / f"{seed}_{n}", seed, n, ("float64", "float32"))
            )
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1))
    print(report(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
