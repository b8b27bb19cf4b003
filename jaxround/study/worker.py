"""The process that runs one ride in real time (libsumo: one ride per process).

It talks to the server over a `multiprocessing` pipe, in bytes:

- to the server: ``P`` + JSON ``{"done": share}`` during the warm-up; ``R``
  + JSON when the warm-up is done (the ego's lanes); ``F`` + the step's
  start (``perf_counter_ns``, 8 bytes, big-endian) + the step number (4
  bytes) + the frame's JSON, once per step; ``T`` + JSON after the frame of
  a step that applied a new input: where that input's time went in this
  process (`input_timing`); ``S`` + JSON ``{"priority"}`` when driving
  starts (what `jaxround.study.priority` got); ``E`` + JSON, the ride's record for
  `jaxround.study.storage.StudyDatabase.save_ride`, last;
- from the server: JSON ``{"type": "start"}``, ``{"type": "input", "seq",
  "throttle", "brake", "rx_ns"}`` (checked by the server, which adds when it
  received it), ``{"type": "lane", "direction", "rx_ns"}`` (the turn signal,
  given to the ride at its next step) and ``{"type": "stop", "reason"}``.

A step is: the latest pedals, SUMO's step, the frame sent, then the
policy's turn every ``dt_s / step_s`` steps (its commands take effect in the
next step, so it need not delay the frame). Steps start on a fixed
real-time grid; a step that starts more than a step late moves the grid and
is counted in ``late_steps``. A pedal pressed or released (from 0 or to 0)
starts the next step at once instead of at its time on the grid, or, when
that step was started early already, as soon as the one after it is due
within a step: the grid stays, so the simulated time never runs more than
one step ahead of the wall clock, and a press does not wait for the grid's
next step (up to 0.1 s, 50 ms on average). Once the warm-up is over the
process asks for a higher scheduling priority (`jaxround.study.priority`).
The ride ends after the ego's last pass, at its time limit, when the server
says stop, or when the server is gone (the pipe closes), and the process
then exits.
"""

from __future__ import annotations

import json
import os
import struct
import tempfile
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from jaxround.study.frames import frame_bytes, ride_frame
from jaxround.study.priority import RIDE_RT_PRIORITY, raise_priority
from jaxround.study.sim import RideSimulation, RideSpec
from jaxround.study.storage import utc_now
from jaxround.study.telemetry import hard_brakings, summarize
from jaxround.sumo_files.processes import pin_jax_to_cpu

#: Header of a frame message: step start (ns) and step number.
FRAME_HEADER = struct.Struct(">qI")
#: What `_wait_until` returns when a pedal press should start the step now.
PULL_STEP = "pull"


class ServerGoneError(Exception):
    """The pipe to the server closed."""


def ride_process(conn: Connection, spec: RideSpec, connect_timeout_s: float) -> None:
    """The ride process's entry point: warm up, wait for start, drive, report."""
    pin_jax_to_cpu()  # before the controller's JAX starts a backend
    started = utc_now()
    record: dict[str, Any] = {"status": "error", "error": None, "summary": {}}
    sim = None
    try:
        with tempfile.TemporaryDirectory(prefix="jaxround-ride-") as tmp:
            try:
                if spec.share is not None:
                    _prepare_jax()
                sim = RideSimulation(spec, Path(tmp))
                sim.warm_up(
                    lambda done: conn.send_bytes(
                        b"P" + json.dumps({"done": round(done, 3)}).encode()
                    )
                )
            except Exception as err:  # a ride that cannot start says why
                record["error"] = f"the ride could not start: {err!r}"
            else:
                conn.send_bytes(
                    b"R" + json.dumps({"ego_lanes": sim.ego_lanes()}).encode()
                )
                record = drive(conn, sim, spec, connect_timeout_s)
            conn.send_bytes(
                b"E" + json.dumps(ride_record(spec, sim, record, started)).encode()
            )
    except (ServerGoneError, EOFError, OSError):
        pass  # nobody left to tell
    finally:
        if sim is not None:
            sim.close()
        conn.close()


def drive(
    conn: Connection, sim: RideSimulation, spec: RideSpec, connect_timeout_s: float
) -> dict[str, Any]:
    """Wait for the browser's start, then step in real time until the ride ends.

    Returns:
        ``{"status", "error", "late_steps"}``.
    """
    deadline = time.monotonic() + connect_timeout_s
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0 or not conn.poll(remaining):
            return {
                "status": "not_started",
                "error": "the browser did not start it",
                "late_steps": 0,
            }
        message = _receive(conn)
        if message["type"] == "start":
            break
        if message["type"] == "stop":
            return {
                "status": message.get("reason", "abandoned"),
                "error": None,
                "late_steps": 0,
            }
    priority = raise_priority(RIDE_RT_PRIORITY)
    conn.send_bytes(b"S" + json.dumps({"priority": priority}).encode())
    pedals: dict[str, Any] = {"throttle": 0.0, "brake": 0.0, "seq": -1}
    period_ns = round(spec.step_s * 1e9)
    n_steps = round(spec.ride_s / spec.step_s)
    late = 0
    applied_seq = -1
    next_ns = time.perf_counter_ns()
    for step in range(n_steps):
        stop = _wait_until(conn, next_ns, pedals, period_ns)
        if stop not in (None, PULL_STEP):
            return {"status": stop, "error": None, "late_steps": late}
        t0 = time.perf_counter_ns()
        if t0 - next_ns > period_ns:
            late += 1
            next_ns = t0
        if "lane" in pedals:
            sim.ask_lane(pedals.pop("lane"))
        sumo_ns = sim.step(pedals["throttle"], pedals["brake"])
        frame = frame_bytes(ride_frame(sim, step, pedals["seq"]))
        conn.send_bytes(b"F" + FRAME_HEADER.pack(t0, step) + frame)
        frame_ns = time.perf_counter_ns() - t0 - sumo_ns
        if pedals["seq"] != applied_seq:
            applied_seq = pedals["seq"]
            timing = input_timing(pedals, step, t0, sumo_ns, frame_ns)
            conn.send_bytes(b"T" + json.dumps(timing).encode())
        policy_ns = sim.act()  # off the frame's path: it acts on the next step
        sim.trace[-1].update(
            step=step,
            sumo_ms=sumo_ns / 1e6,
            policy_ms=policy_ns / 1e6,
            frame_ms=frame_ns / 1e6,
        )
        if sim.ego_arrived_s is not None:
            return {"status": "arrived", "error": None, "late_steps": late}
        next_ns += period_ns
    return {"status": "time_limit", "error": None, "late_steps": late}


def input_timing(
    pedals: dict[str, Any], step: int, t0_ns: int, sumo_ns: int, frame_ns: int
) -> dict[str, Any]:
    """Where an input's time went in this process, ms: from the server's
    receipt to this process (``relay_in``: the pipe, and the policy if it was
    acting), waiting for the step (``wait``), the SUMO step, reading the
    vehicles and sending the frame. The policy acts after the frame."""
    return {
        "seq": pedals["seq"],
        "step": step,
        "relay_in": (pedals["got_ns"] - pedals["rx_ns"]) / 1e6,
        "wait": (t0_ns - pedals["got_ns"]) / 1e6,
        "sumo": sumo_ns / 1e6,
        "frame": frame_ns / 1e6,
    }


def _wait_until(
    conn: Connection, until_ns: int, pedals: dict[str, Any], period_ns: int
) -> str | None:
    """Take the server's messages until the step due at `until_ns`.

    A pedal pressed or released starts that step early: at once when it is
    due within a period, else (the step before was started early) as soon as
    it is.

    Returns:
        a stop's reason; `PULL_STEP` for a step started early; else None
        (at `until_ns`).
    """
    pressed = False
    earliest_ns = until_ns - period_ns
    while True:
        now = time.perf_counter_ns()
        if pressed and now >= earliest_ns:
            return PULL_STEP
        deadline = earliest_ns if pressed else until_ns
        if not conn.poll(max(deadline - now, 0) / 1e9):
            if not pressed:
                return None
            continue
        message = _receive(conn)
        if message["type"] == "input":
            before = (pedals["throttle"] > 0, pedals["brake"] > 0)
            pedals.update(
                throttle=min(max(float(message["throttle"]), 0.0), 1.0),
                brake=min(max(float(message["brake"]), 0.0), 1.0),
                seq=int(message["seq"]),
                rx_ns=int(message.get("rx_ns", 0)),
                got_ns=time.perf_counter_ns(),
            )
            now_pressed = (pedals["throttle"] > 0, pedals["brake"] > 0)
            pressed = pressed or before != now_pressed
        elif message["type"] == "lane":
            pedals["lane"] = str(message["direction"])
        elif message["type"] == "stop":
            return str(message.get("reason", "abandoned"))


def _receive(conn: Connection) -> dict[str, Any]:
    try:
        return json.loads(conn.recv_bytes())
    except EOFError:
        raise ServerGoneError() from None


def ride_record(
    spec: RideSpec,
    sim: RideSimulation | None,
    outcome: dict[str, Any],
    started_utc: str,
) -> dict[str, Any]:
    """The record the server stores (`StudyDatabase.save_ride` without the
    server's own figures)."""
    ride = {
        "ride_id": spec.ride_id,
        "share": spec.share or 0.0,
        "seed": spec.seed,
        "warmup_s": spec.warmup_s,
        "step_s": spec.step_s,
        "status": outcome["status"],
        "error": outcome.get("error"),
        "started_utc": started_utc,
        "ended_utc": utc_now(),
    }
    if sim is None:
        return {"ride": ride, "steps": [], "events": []}
    steps = [row for row in sim.trace if "step" in row]
    events = sorted(sim.events + hard_brakings(steps), key=lambda e: e["time_s"])
    ride.update(
        summarize(
            steps,
            events,
            sim.ego_entered_s,
            sim.crossings,
            outcome.get("late_steps", 0),
        )
    )
    return {
        "ride": ride,
        "steps": steps,
        "events": events,
        "passes": len(sim.crossings),
    }


def _prepare_jax() -> None:
    """JAX on the calling thread, compiled programs kept between rides.

    The controller's observer is compiled in every ride process; the
    persistent cache (``$XDG_CACHE_HOME/jaxround/xla``, the folder the CLI
    uses) turns a ride's start from seconds of compiling into loading.
    """
    import jax

    from sumo_export.traffic import synchronous_cpu_dispatch

    synchronous_cpu_dispatch()
    if not jax.config.jax_compilation_cache_dir:
        cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
        jax.config.update("jax_compilation_cache_dir", str(cache / "jaxround" / "xla"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
