"""The server's side of the rides: one process each, the participant limit,
frames relayed to the browser, records stored, processes reaped.

Everything here runs on the server's event loop; a ride process's pipe is
watched with ``loop.add_reader``, so frames go out as soon as they come in.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import secrets
import time
from dataclasses import dataclass, field
from typing import Any

from jaxround.study.logs import log_event
from jaxround.study.settings import StudySettings
from jaxround.study.sim import RideSpec
from jaxround.study.storage import StudyDatabase, utc_now
from jaxround.study.telemetry import server_figures
from jaxround.study.worker import FRAME_HEADER, ride_process
from jaxround.sumo_files.processes import cpu_spawn_context

#: Frames waiting for a slow browser; older ones are dropped (and counted).
MAX_QUEUED_FRAMES = 20
#: Browser latency samples kept per ride.
MAX_LATENCY_SAMPLES = 20_000
#: Seconds a ride process gets to send its record after a stop.
STOP_GRACE_S = 10.0


class BusyError(Exception):
    """Every place is taken; the message says how many there are."""


@dataclass(eq=False)
class Ride:
    """A ride in progress (server side)."""

    spec: RideSpec
    participant_id: str
    kind: str
    label: str
    token: str
    process: Any
    conn: Any
    queue: asyncio.Queue = field(default_factory=asyncio.Queue)
    connected: bool = False
    started: bool = False
    ended: bool = False
    stop_reason: str | None = None
    delays_ms: dict[int, float] = field(default_factory=dict)
    latency: list[dict[str, float]] = field(default_factory=list)
    frames_dropped: int = 0
    requested_at: float = field(default_factory=time.monotonic)
    done: asyncio.Event = field(default_factory=asyncio.Event)

    @property
    def ride_id(self) -> str:
        return self.spec.ride_id


class RideManager:
    """Starts, relays and reaps the rides of one server.

    Args:
        settings: the study's settings.
        database: where finished rides are stored.
        policy: the policy's path as the ride processes read it.
    """

    def __init__(
        self, settings: StudySettings, database: StudyDatabase, policy: str
    ) -> None:
        self.settings = settings
        self.database = database
        self.policy = policy
        self.rides: dict[str, Ride] = {}
        self._context = cpu_spawn_context()  # rides keep JAX off the GPU
        self._tasks: set[asyncio.Task] = set()

    @property
    def places_free(self) -> int:
        return self.settings.max_participants - len(self.rides)

    async def start(
        self, spec: RideSpec, participant_id: str, kind: str, label: str
    ) -> Ride:
        """Start a ride's process; BusyError when every place is taken."""
        if self.places_free <= 0:
            n = self.settings.max_participants
            taken = (
                "The study's driving place is taken"
                if n == 1
                else f"All {n} driving places are taken"
            )
            raise BusyError(
                f"{taken}. Please try again in a few minutes: your answers so "
                "far are kept."
            )
        parent, child = self._context.Pipe()
        process = self._context.Process(
            target=ride_process,
            args=(child, spec, self.settings.connect_timeout_s),
            name=f"jaxround-ride-{spec.ride_id}",
            daemon=True,
        )
        ride = Ride(
            spec,
            participant_id,
            kind,
            label,
            secrets.token_urlsafe(16),
            process,
            parent,
        )
        self.rides[spec.ride_id] = ride  # the place is taken before any await
        try:
            await asyncio.to_thread(process.start)
        except Exception:
            del self.rides[spec.ride_id]
            raise
        child.close()
        asyncio.get_running_loop().add_reader(parent.fileno(), self._on_message, ride)
        self.log(ride, "ride_requested", share=spec.share)
        return ride

    @staticmethod
    def log(ride: Ride, event: str, **fields: Any) -> None:
        """A log line of this ride (`jaxround.study.logs`)."""
        log_event(
            event,
            participant=ride.participant_id,
            ride=ride.ride_id,
            kind=ride.kind,
            **fields,
        )

    @staticmethod
    def _blocking(ride: Ride) -> None:
        """Reads and writes of whole messages block: uvloop's ``add_reader``
        makes the descriptor non-blocking (libuv's uv_poll_init), and a
        record larger than the socket's buffer would then be cut short."""
        os.set_blocking(ride.conn.fileno(), True)

    # ------------------------------------------------------------ from a ride

    def _on_message(self, ride: Ride) -> None:
        try:
            self._blocking(ride)
            data = ride.conn.recv_bytes()
        except (EOFError, OSError):
            self._unwatch(ride)
            if not ride.ended:
                code = ride.process.exitcode
                self._spawn(
                    self._finish(
                        ride, None, f"the ride's process ended (exit code {code})"
                    )
                )
            return
        tag, body = data[:1], data[1:]
        if tag == b"F":
            t0, step = FRAME_HEADER.unpack_from(body)
            if ride.queue.qsize() >= MAX_QUEUED_FRAMES:
                ride.queue.get_nowait()
                ride.frames_dropped += 1
            ride.queue.put_nowait(("frame", (t0, step, body[FRAME_HEADER.size :])))
        elif tag == b"T":
            ride.queue.put_nowait(("timing", json.loads(body)))
        elif tag == b"S":
            self.log(ride, "ride_priority", **json.loads(body))
        elif tag == b"P":
            ride.queue.put_nowait(("preparing", json.loads(body)))
        elif tag == b"R":
            ride.queue.put_nowait(("ready", json.loads(body)))
            waited = time.monotonic() - ride.requested_at
            self.log(ride, "ride_ready", warmup_wall_s=round(waited, 1))
        elif tag == b"E":
            self._unwatch(ride)
            self._spawn(self._finish(ride, json.loads(body), None))

    def _unwatch(self, ride: Ride) -> None:
        with contextlib.suppress(ValueError, OSError):
            asyncio.get_running_loop().remove_reader(ride.conn.fileno())

    def _spawn(self, coroutine: Any) -> None:
        task = asyncio.get_running_loop().create_task(coroutine)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _finish(
        self, ride: Ride, record: dict[str, Any] | None, error: str | None
    ) -> None:
        """Store the ride, tell the browser, reap the process, free the place."""
        if ride.ended:
            return
        ride.ended = True
        if record is None:
            record = {
                "ride": {
                    "ride_id": ride.ride_id,
                    "status": "error",
                    "error": error,
                    "ended_utc": utc_now(),
                },
                "steps": [],
                "events": [],
            }
        row = record["ride"]
        if ride.stop_reason is not None and row["status"] in ("abandoned", "error"):
            row["status"] = ride.stop_reason
        row["passes"] = record.get("passes", 0)
        row.update(
            participant_id=ride.participant_id,
            kind=ride.kind,
            label=ride.label,
            share=ride.spec.share or 0.0,
        )
        for step in record["steps"]:
            step["delay_ms"] = ride.delays_ms.get(step["step"])
        row.update(
            server_figures(
                list(ride.delays_ms.values()),
                [x["latency_ms"] for x in ride.latency],
                ride.frames_dropped,
            )
        )
        record["latency"] = ride.latency
        self.log(
            ride,
            "ride_ended",
            status=row["status"],
            error=row.get("error"),
            steps=row.get("steps"),
            passes=row["passes"],
            crossing_time_s=row.get("crossing_time_s"),
            delay_p99_ms=_rounded(row.get("delay_p99_ms")),
        )
        summary = _summary(row)
        del row["passes"]  # not a column: the log line and the page have it
        try:
            await asyncio.to_thread(self.database.save_ride, record)
        finally:
            ride.queue.put_nowait(("end", summary))
            await self._reap(ride)
            self.rides.pop(ride.ride_id, None)
            ride.done.set()

    async def _reap(self, ride: Ride) -> None:
        process = ride.process
        await asyncio.to_thread(process.join, 5.0)
        if process.is_alive():
            process.kill()
            await asyncio.to_thread(process.join, 5.0)
        ride.conn.close()

    # ------------------------------------------------------------ to a ride

    def send(self, ride: Ride, message: dict[str, Any]) -> None:
        """Pass a checked message to the ride's process (ignored once it ended)."""
        if ride.ended:
            return
        with contextlib.suppress(OSError, ValueError):
            self._blocking(ride)
            ride.conn.send_bytes(json.dumps(message).encode())

    async def stop(self, ride: Ride, reason: str) -> None:
        """End a ride early (`reason` becomes its status) and wait till it is
        stored and its process reaped; a process that does not answer within
        `STOP_GRACE_S` is killed."""
        if ride.ended:
            await ride.done.wait()
            return
        ride.stop_reason = reason
        self.send(ride, {"type": "stop", "reason": reason})
        try:
            await asyncio.wait_for(ride.done.wait(), STOP_GRACE_S)
        except TimeoutError:
            ride.process.kill()
            await asyncio.wait_for(ride.done.wait(), STOP_GRACE_S)

    def frame_sent(self, ride: Ride, t0_ns: int, step: int) -> None:
        """Record the server delay of a step whose frame was just handed out."""
        ride.delays_ms[step] = (time.perf_counter_ns() - t0_ns) / 1e6

    def add_latency(self, ride: Ride, seq: int, latency_ms: float) -> None:
        if len(ride.latency) < MAX_LATENCY_SAMPLES:
            ride.latency.append({"seq": seq, "latency_ms": latency_ms})

    async def shutdown(self) -> None:
        """Stop every ride (status 'server_stopped') and reap its process."""
        await asyncio.gather(
            *(self.stop(r, "server_stopped") for r in list(self.rides.values())),
            return_exceptions=True,
        )


def _rounded(x: float | None) -> float | None:
    return None if x is None else round(x, 2)


def _summary(row: dict[str, Any]) -> dict[str, Any]:
    """What the browser shows at a ride's end."""
    keys = (
        "status",
        "error",
        "passes",
        "crossing_time_s",
        "collisions",
        "hard_brakings",
        "min_ttc_s",
    )
    return {k: row.get(k) for k in keys}
