"""A ride's WebSocket: frames out to the browser, checked messages in.

The ride's end closes the socket; a browser that leaves, breaks the protocol
(`jaxround.study.protocol`) or can no longer be written to ends the ride.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import time
from typing import Any

from fastapi import WebSocket
from starlette.websockets import WebSocketDisconnect

from jaxround.study.protocol import MAX_MESSAGES_PER_S, BadMessageError, parse_message
from jaxround.study.rides import Ride, RideManager

#: WebSocket close codes: refused by the protocol, unknown ride, ride taken.
CLOSE_POLICY, CLOSE_UNKNOWN, CLOSE_TAKEN = 1008, 4404, 4409


async def relay(websocket: WebSocket, manager: RideManager, ride: Ride) -> None:
    """Frames to the browser, checked pedals to the ride, until either ends.

    The ride's end closes the socket; a browser that leaves, breaks the
    protocol or can no longer be written to ends the ride (`RideManager.stop`).
    """
    to_browser = asyncio.create_task(_frames_out(websocket, manager, ride))
    from_browser = asyncio.create_task(_messages_in(websocket, manager, ride))
    done, _ = await asyncio.wait(
        {to_browser, from_browser}, return_when=asyncio.FIRST_COMPLETED
    )
    from_browser.cancel()
    if to_browser in done and to_browser.exception() is None:  # told of the end
        with contextlib.suppress(Exception):
            await websocket.close(1000, "ride over")
        return
    to_browser.cancel()
    reason = "abandoned"
    if from_browser in done and from_browser.exception() is None:
        reason = from_browser.result()
    await manager.stop(ride, reason)


async def _frames_out(websocket: WebSocket, manager: RideManager, ride: Ride) -> None:
    while True:
        kind, item = await ride.queue.get()
        if kind == "frame":
            t0_ns, step, body = item
            await websocket.send_text(body.decode())
            manager.frame_sent(ride, t0_ns, step)
        elif kind == "timing":
            await websocket.send_json(_timing_message(ride, item))
        elif kind == "preparing":
            await websocket.send_json({"type": "preparing", **item})
        elif kind == "ready":
            await websocket.send_json(
                {
                    "type": "ready",
                    "label": ride.label,
                    "ride_s": ride.spec.ride_s,
                    "passes": ride.spec.passes,
                    **item,
                }
            )
        elif kind == "end":
            await websocket.send_json({"type": "end", **item})
            return


def _timing_message(ride: Ride, parts: dict[str, Any]) -> dict[str, Any]:
    """Where an input's time went on the server's side, ms (rounded to
    0.01): the ride process's parts and ``relay_out``, from the frame sent
    by the ride process to the frame handed to the WebSocket."""
    delay = ride.delays_ms.get(parts["step"])
    inside = parts["sumo"] + parts["frame"]
    relay_out = None if delay is None else max(delay - inside, 0.0)
    names = ("relay_in", "wait", "sumo", "frame")
    return {
        "type": "timing",
        "seq": parts["seq"],
        **{name: round(parts[name], 2) for name in names},
        "relay_out": None if relay_out is None else round(relay_out, 2),
    }


async def _messages_in(
    websocket: WebSocket, manager: RideManager, ride: Ride
) -> str | None:
    """Read the browser until it leaves ('abandoned') or errs ('bad_message').

    Pedals and latencies count only after the start; a browser that sends
    more than `MAX_MESSAGES_PER_S` in a second breaks the protocol.
    """
    recent: collections.deque[float] = collections.deque()
    while True:
        try:
            message = await websocket.receive()
        except (WebSocketDisconnect, RuntimeError):
            return "abandoned"
        received_ns = time.perf_counter_ns()
        if message["type"] == "websocket.disconnect":
            return "abandoned" if message.get("code") != 1009 else "bad_message"
        now = time.monotonic()
        recent.append(now)
        while recent[0] < now - 1.0:
            recent.popleft()
        text = message.get("text")
        try:
            if len(recent) > MAX_MESSAGES_PER_S:
                raise BadMessageError(
                    f"more than {MAX_MESSAGES_PER_S} messages a second"
                )
            if text is None:
                raise BadMessageError("binary messages are not part of the protocol")
            checked = parse_message(text)
        except BadMessageError as err:
            manager.log(ride, "bad_message", reason=str(err))
            with contextlib.suppress(Exception):
                await websocket.send_json({"type": "error", "message": str(err)})
                await websocket.close(CLOSE_POLICY, "bad message")
            return "bad_message"
        if checked["type"] == "start" and not ride.started:
            ride.started = True
            manager.send(ride, checked)
            manager.log(ride, "ride_started")
        elif checked["type"] in ("input", "lane") and ride.started:
            manager.send(ride, {**checked, "rx_ns": received_ns})
        elif checked["type"] == "latency" and ride.started:
            manager.add_latency(ride, checked["seq"], float(checked["ms"]))


async def refuse(websocket: WebSocket, code: int, reason: str) -> None:
    await websocket.send_json({"type": "error", "message": reason})
    await websocket.close(code, reason)
