"""Scripted riders over loopback: the server's delay per step under load.

    jaxround study load --participants 4 --seconds 60

starts ``jaxround study serve`` in a subprocess on a free port of 127.0.0.1
with a temporary database, lets N scripted participants each drive their
first ride at once (order counterbalanced: half at 20% AVs, half at 80%),
each over its own WebSocket and with its own SUMO process, and reads the
server's figures back from the database: the delay per step from the step's
start in the ride process to the frame handed to the WebSocket (SUMO step,
frame out, relay; the policy acts after the frame), its phases, late steps,
rides dropped (a ride that did not end at its time limit or after its
passes), and the riders' input-to-frame latency part by part. The riders
(`jaxround.study.riders`) run in a process of their own at a lower priority.

Without ``--policy`` the AVs are driven by a stand-in with random weights
that asks for full acceleration at every step, as the trained policy does
(README: it drives exactly like uncontrolled AVs); the work per step does
not depend on the weights.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from jaxround.scenario.config import ScenarioConfig, load_config
from jaxround.study.riders import SERVER_PARTS, http_json, ride_all
from jaxround.study.settings import MAX_PARTICIPANTS_LIMIT
from jaxround.study.storage import StudyDatabase
from jaxround.study.telemetry import percentile

#: Longest load run, seconds of riding.
MAX_SECONDS = 600.0
#: Seconds the server gets to start and a ride to warm up.
START_TIMEOUT_S = 120.0


def write_standin_policy(folder: Path, cfg: ScenarioConfig) -> Path:
    """A random policy in the exported format that always asks for full
    acceleration (the AVs' IDM caps it), with the layout `jaxround train`
    gives by default (configs/ppo_milan.yaml: two tanh layers of 32)."""
    from agents.common.export import PolicyLayout, export_policy
    from jaxround.envs.observe import OBSERVATION_SIZES

    observer = cfg.agent.observer
    layout = PolicyLayout(
        observer=observer,
        obs_size=OBSERVATION_SIZES[observer],
        hidden=(32, 32),
        activation="tanh",
        centralised=False,
        accel_bounds=(-cfg.drivers.av.decel, cfg.drivers.av.accel),
        scenario=cfg.name,
        scenario_fingerprint=cfg.roads_and_drivers_fingerprint(),
    )
    rng = np.random.default_rng(0)
    tree: dict[str, Any] = {"log_std": np.float32(0.0)}
    for name, shape in layout.array_shapes().items():
        if "/" in name:
            layer, leaf = name.split("/")
            tree.setdefault(layer, {})[leaf] = rng.normal(0.0, 0.1, shape)
    tree["accel_mean"]["bias"][:] = 10.0 * cfg.drivers.av.accel
    npz, _ = export_policy({"params": tree}, layout, folder / "standin_policy")
    return npz


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_load(
    participants: int,
    seconds: float,
    policy: Path | None = None,
    config: str = "milan",
    warmup_s: float = 120.0,
) -> dict[str, Any]:
    """Drive `participants` scripted rides at once against a fresh server.

    Returns:
        Plain data: the rides' outcomes, the server delay per step (median,
        p99, max, ms, over every step of every ride), the ride process's
        share of it per phase (SUMO step, policy, frame) and late steps.

    Raises:
        ValueError: a count or duration outside its bounds.
        RuntimeError: the server did not start.
    """
    if not 1 <= participants <= MAX_PARTICIPANTS_LIMIT:
        raise ValueError(
            f"participants: {participants}, expected 1-{MAX_PARTICIPANTS_LIMIT}"
        )
    if not 1.0 <= seconds <= MAX_SECONDS:
        raise ValueError(f"seconds: {seconds}, expected 1-{MAX_SECONDS:g}")
    cfg = load_config(config)
    with tempfile.TemporaryDirectory(prefix="jaxround-load-") as tmp:
        folder = Path(tmp)
        policy = policy or write_standin_policy(folder, cfg)
        db_path = folder / "load.sqlite"
        port = free_port()
        options = {
            "--policy": policy, "--config": config, "--db": db_path, "--port": port,
            "--max-participants": participants, "--ride-s": seconds,
            "--warmup-s": warmup_s,
        }  # fmt: skip
        command = [sys.executable, "-m", "jaxround", "study", "serve"]
        for option, value in options.items():
            command += [option, str(value)]
        log = (folder / "server.log").open("w")
        server = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        try:
            base = f"http://127.0.0.1:{port}"
            _wait_for(server, base, folder / "server.log")
            started = time.perf_counter()
            outcomes = ride_all(base, participants)
            wall = time.perf_counter() - started
        finally:
            server.terminate()
            server.wait(timeout=30)
            log.close()
        database = StudyDatabase(db_path)
        return _figures(outcomes, database, wall)


def _wait_for(server: subprocess.Popen, base: str, log: Path) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise RuntimeError(f"the server stopped: {log.read_text()}")
        try:
            if http_json("GET", f"{base}/api/study")[0] == 200:
                return
        except OSError:
            time.sleep(0.2)
    raise RuntimeError(f"the server did not answer within {START_TIMEOUT_S:g} s")


def _figures(
    outcomes: list[dict[str, Any]], database: StudyDatabase, wall_s: float
) -> dict[str, Any]:
    steps = database.rows("ride_steps")
    rides = database.rows("rides")
    delays = [s["delay_ms"] for s in steps if s["delay_ms"] is not None]
    phase = {
        k: [s[k] for s in steps if s[k] is not None]
        for k in ("sumo_ms", "policy_ms", "frame_ms")
    }
    policy_steps = [
        s["policy_ms"]
        for s in steps
        if s["policy_ms"] is not None and s["policy_ms"] > 0.02
    ]
    ok = ("arrived", "time_limit")
    return {
        "participants": len(outcomes),
        "wall_s": round(wall_s, 1),
        "rides": [
            {"status": o["status"], "frames": o["frames"], "error": o.get("error")}
            for o in outcomes
        ],
        "rides_dropped": sum(o["status"] not in ok for o in outcomes),
        "steps": len(delays),
        "frames_lost": sum(
            len(
                [
                    s
                    for s in steps
                    if s["ride_id"] == r["ride_id"] and s["delay_ms"] is None
                ]
            )
            for r in rides
        ),
        "late_steps": sum(r["late_steps"] or 0 for r in rides),
        "delay_ms": {
            "median": percentile(delays, 50),
            "p99": percentile(delays, 99),
            "max": max(delays, default=None),
        },
        "phase_median_ms": {k: percentile(v, 50) for k, v in phase.items()},
        "phase_p99_ms": {k: percentile(v, 99) for k, v in phase.items()},
        "policy_step_ms": {
            "median": percentile(policy_steps, 50),
            "p99": percentile(policy_steps, 99),
        },
        "latency_ms": latency_parts(
            [x for o in outcomes for x in o.get("latency", [])]
        ),
    }


def latency_parts(records: list[dict[str, float]]) -> dict[str, Any]:
    """Median and p99 of each part of the input-to-frame latency (ms) over
    the scripted riders' inputs, and how many there were."""
    names = (*SERVER_PARTS, "websocket", "total")
    return {
        "inputs": len(records),
        **{
            name: {
                "median": percentile(
                    [r[name] for r in records if r[name] is not None], 50
                ),
                "p99": percentile(
                    [r[name] for r in records if r[name] is not None], 99
                ),
            }
            for name in names
        },
    }


def format_figures(figures: dict[str, Any]) -> str:
    """The figures as a few lines of text."""
    delay = figures["delay_ms"]
    median, p99 = figures["phase_median_ms"], figures["phase_p99_ms"]
    policy = figures["policy_step_ms"]

    def ms(x: float | None) -> str:
        return "-" if x is None else f"{x:.2f} ms"

    def phase(name: str) -> str:
        return f"{ms(median[name])} / {ms(p99[name])}"

    outcomes = ", ".join(r["status"] for r in figures["rides"])
    latency = figures["latency_ms"]
    parts = ", ".join(
        f"{name} {ms(v['median'])} / {ms(v['p99'])}"
        for name, v in latency.items()
        if name != "inputs"
    )
    return "\n".join(
        [
            f"{figures['participants']} scripted rides at once, "
            f"{figures['steps']} steps ({figures['wall_s']} s)",
            f"server delay per step: median {ms(delay['median'])}, "
            f"p99 {ms(delay['p99'])}, max {ms(delay['max'])}",
            f"  in the ride process, median / p99: SUMO step {phase('sumo_ms')}, "
            f"policy {phase('policy_ms')}, frame {phase('frame_ms')}",
            f"  steps where the policy acted: median {ms(policy['median'])}, "
            f"p99 {ms(policy['p99'])}",
            f"input to frame over {latency['inputs']} inputs, median / p99: {parts}",
            f"late steps: {figures['late_steps']}; frames not handed out: "
            f"{figures['frames_lost']}; rides dropped: {figures['rides_dropped']} "
            f"({outcomes})",
        ]
    )
