"""Where the JAX step's time goes, phase by phase: ``jaxround bench --profile``.

    result = profile_step(load_config("milan"))
    print(format_profile(result))

The program profiled is the one `jaxround.apps.bench.jax_timing` times: one jitted
``vmap`` over B roundabouts of a ``lax.scan`` of ``env.step_env``, idle
actions. It is warmed up over the first ``sim_seconds`` of the demand, then
one more window of ``sim_seconds`` runs under ``jax.profiler``, which records
the time of every XLA operation (a fusion of many JAX operations, or a
reduction, gather, scatter ...) each time it runs.

Each phase of the step is traced in a ``jax.named_scope`` of its name
(`jaxround.core.dynamics.planned_speed`, `RoundaboutEnv.step_env`), which
XLA keeps in each operation's metadata; an operation's time goes to the
phase of the operation its result comes from (a fusion can pull in work
traced in an earlier phase: XLA recomputes cheap producers where they are
used, so read a phase's figure as what XLA spends there). "other" is what
no phase owns: the scan's own bookkeeping, copies and layout changes.

The times are CPU time: XLA runs independent operations on several cores
at once, so the phases add up to more than the wall time of the step,
which is measured beside them (same program, same window, no profiler,
the median of three runs). One run's figures move by a tenth or more on a
shared machine: compare phases within a run, not across runs.
"""

from __future__ import annotations

import gzip
import json
import re
import statistics
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import jax

from jaxround.apps.bench.jax_timing import batch_schedules, warmed_window
from jaxround.envs.roundabout import make
from jaxround.scenario.config import ScenarioConfig

#: The step's named scopes in the order it runs them, with what each follows
#: (docs/sumo-map.md has the SUMO file and method of each).
PHASES: tuple[tuple[str, str], ...] = (
    ("actions", "the AVs' actions: vType retune or TraCI speed command"),
    ("start_speeds", "planMoveInternal: the speed to start from"),
    ("neighbour_tables", "who is where, along every route (per-lane tables)"),
    ("own_leader", "getLeader, then the IDM's followSpeed"),
    ("lane_limits", "freeSpeed over the lanes ahead"),
    ("yield_line", "vWait, link leaders at the next merge, impatience"),
    ("look_ahead", "planMoveInternal's loop over the lanes ahead"),
    ("registrations", "setApproachingForAllLinks"),
    ("entry_test", "MSLink::opened in executeMove"),
    ("final_speed", "finalizeSpeed, processTraCISpeedControl"),
    ("move", "executeMove: positions, arrivals, collisions"),
    ("surrogate_safety", "MSDevice_SSM: following TTC, DRAC and conflicts"),
    ("emissions", "the emission model (docs/sumo-map.md)"),
    ("reward", "the agents' reward"),
    ("lane_changes", "MSEdgeControl::changeLanes (two-lane roads)"),
    ("insertion", "MSInsertionControl::emitVehicles"),
    ("queues", "queue statistics"),
    ("observation", "the agents' observation"),
)
OTHER = "other"
_PHASE_NAMES = frozenset(name for name, _ in PHASES)
#: Batch and window of the profile unless told otherwise.
DEFAULT_BATCH = 256
DEFAULT_SIM_SECONDS = 30.0
#: Timed runs of the window (without the profiler); their median is reported.
WALL_REPEATS = 3
#: The costliest XLA operations listed beside the phases.
TOP_OPERATIONS = 10

_INSTRUCTION = re.compile(
    r"^\s*(?:ROOT\s+)?%([\w.\-]+) = (\S+) .*?op_name=\"([^\"]*)\"", re.M
)


def phase_of(op_name: str) -> str:
    """The innermost phase named in an operation's scope path, else "other".

    >>> phase_of("jit(f)/vmap(jit(_where))/vmap(look_ahead)/select_n")
    'look_ahead'
    """
    found = OTHER
    for part in re.split(r"[/()]", op_name):
        if part in _PHASE_NAMES:
            found = part
    return found


def operation_phases(hlo_text: str) -> dict[str, tuple[str, str]]:
    """Every named instruction of a compiled program's text: its phase and
    result shape, ``{name: (phase, shape)}``."""
    return {
        name: (phase_of(op_name), shape)
        for name, shape, op_name in _INSTRUCTION.findall(hlo_text)
    }


def _trace_times(folder: Path) -> Counter[str]:
    """Microseconds spent in each XLA operation, summed over a profiler trace
    (the ``*.trace.json.gz`` that ``jax.profiler.trace`` writes)."""
    files = sorted(folder.rglob("*.trace.json.gz"))
    if not files:
        raise RuntimeError(f"jax.profiler wrote no trace under {folder}")
    with gzip.open(files[-1], "rt") as f:
        trace = json.load(f)
    events = trace["traceEvents"] if isinstance(trace, dict) else trace
    times: Counter[str] = Counter()
    for event in events:
        if event.get("ph") == "X" and "dur" in event:
            times[event["name"]] += float(event["dur"])
    return times


def profile_step(
    cfg: ScenarioConfig,
    *,
    batch: int = DEFAULT_BATCH,
    sim_seconds: float = DEFAULT_SIM_SECONDS,
    max_vehicles: int | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """Profile one window of the batched step, phase by phase.

    Args:
        cfg: the scenario.
        batch: roundabouts B stepped together.
        sim_seconds: the warm-up, then the profiled window (whole steps).
        max_vehicles: slots M; None: the config's, else what the road holds.
        seed: roundabout i runs ``make_schedule(cfg, seed + i)``.

    Returns:
        ``{"batch", "max_vehicles", "steps", "mean_vehicles",
        "wall_us_per_roundabout_step", "cpu_us_per_roundabout_step",
        "phases": [{"phase", "follows", "us", "share"}, ...] (in step order,
        "other" last), "top_operations": [{"name", "phase", "shape", "us"},
        ...]}``: microseconds per roundabout-step; "cpu_us" sums the
        operations' times, "share" is of that sum.
    """
    if not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch: {batch!r}, expected a positive integer")
    steps = round(float(sim_seconds) / cfg.simulation.dt_s)
    if not sim_seconds > 0 or steps < 1:
        raise ValueError(f"sim_seconds: {sim_seconds}, expected at least one step")
    env, params = make(cfg, max_vehicles=max_vehicles)
    window = warmed_window(env, params, batch_schedules(env, batch, seed), steps)
    compiled, states = window.run, window.states
    where = operation_phases(compiled.as_text())

    walls = []
    for _ in range(WALL_REPEATS):
        t0 = time.perf_counter()
        _, occupied, _, _ = jax.block_until_ready(compiled(states, params))
        walls.append(time.perf_counter() - t0)
    wall = statistics.median(walls)
    with tempfile.TemporaryDirectory(prefix="jaxround-profile-") as folder:
        with jax.profiler.trace(folder, create_perfetto_trace=True):
            jax.block_until_ready(compiled(states, params))
        times = _trace_times(Path(folder))

    per_step = batch * steps
    by_phase: Counter[str] = Counter()
    ops = []
    for name, us in times.items():
        if name in where:
            phase, shape = where[name]
            by_phase[phase] += us
            ops.append({"name": name, "phase": phase, "shape": shape, "us": us})
    total = sum(by_phase.values())
    if total <= 0:
        raise RuntimeError("the profiler recorded no XLA operation of the step")
    follows = dict(PHASES) | {OTHER: "scan bookkeeping, copies, layout changes"}
    phases = [
        {
            "phase": name,
            "follows": follows[name],
            "us": by_phase[name] / per_step,
            "share": by_phase[name] / total,
        }
        for name in [*(n for n, _ in PHASES), OTHER]
        if name in by_phase
    ]
    ops.sort(key=lambda op: -op["us"])
    top = [op | {"us": op["us"] / per_step} for op in ops[:TOP_OPERATIONS]]
    return {
        "scenario": cfg.name,
        "batch": batch,
        "max_vehicles": env.max_vehicles,
        "steps": steps,
        "mean_vehicles": float(jax.device_get(occupied).sum()) / per_step,
        "wall_us_per_roundabout_step": 1e6 * wall / per_step,
        "cpu_us_per_roundabout_step": total / per_step,
        "phases": phases,
        "top_operations": top,
    }


def format_profile(result: dict[str, Any], width: int = 30) -> str:
    """`profile_step`'s result as Markdown: a table of the phases with a bar
    of each one's share, then the costliest operations."""
    lines = [
        f"{result['scenario']}: {result['batch']} roundabouts x "
        f"{result['steps']} steps, M = {result['max_vehicles']} slots, "
        f"{result['mean_vehicles']:.1f} vehicles per roundabout on average",
        f"wall {result['wall_us_per_roundabout_step']:.1f} us per roundabout-step; "
        f"CPU time of the operations {result['cpu_us_per_roundabout_step']:.1f} us "
        "(several cores at once)",
        "",
        "| phase | us | share | | follows |",
        "|---|---:|---:|---|---|",
    ]
    for row in result["phases"]:
        bar = "#" * round(row["share"] * width)
        lines.append(
            f"| {row['phase']} | {row['us']:.1f} | {100 * row['share']:.1f}% "
            f"| `{bar:<{width}}` | {row['follows']} |"
        )
    lines += ["", "costliest XLA operations (us per roundabout-step):", ""]
    lines += ["| operation | phase | result shape | us |", "|---|---|---|---:|"]
    for op in result["top_operations"]:
        lines.append(
            f"| {op['name']} | {op['phase']} | {op['shape']} | {op['us']:.2f} |"
        )
    return "\n".join(lines)
