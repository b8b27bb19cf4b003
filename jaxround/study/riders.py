"""Scripted participants for `jaxround study load`: each gives consent and
drives one ride over its own WebSocket, like a browser, timing its inputs.

The riders stand in for the participants' browsers, which in a lab run on
other machines; `ride_all` runs them in a process of their own at nice
`RIDER_NICE`, so that on the server's machine they yield the cores to the
server and the rides whose delay is measured.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import time
import urllib.error
import urllib.request
from typing import Any

from jaxround.sumo_files.processes import cpu_process_pool

#: The scripted driver's target speed, m/s.
TARGET_SPEED_MPS = 6.0
#: The scripted driver looks at every this many frames (0.5 s, about a
#: person's reaction time): pedals changed at every frame would keep the
#: ride's steps started early (`jaxround.study.worker`) and measure that.
DECIDE_EVERY = 5
#: The riders' nice value (a lower priority than the server's and the rides').
RIDER_NICE = 10


def ride_all(base: str, participants: int) -> list[dict[str, Any]]:
    """`participants` scripted rides at once, in a process at `RIDER_NICE`."""
    with cpu_process_pool(1, initializer=os.nice, initargs=(RIDER_NICE,)) as pool:
        return pool.submit(_ride_all, base, participants).result()


def _ride_all(base: str, participants: int) -> list[dict[str, Any]]:
    return asyncio.run(_all_rides(base, participants))


async def _all_rides(base: str, participants: int) -> list[dict[str, Any]]:
    return list(
        await asyncio.gather(*(scripted_ride(base) for _ in range(participants)))
    )


def http_json(method: str, url: str, body: dict | None = None) -> tuple[int, dict]:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(
        url, data=data, method=method, headers={"Content-Type": "application/json"}
    )
    try:
        with urllib.request.urlopen(request, timeout=30) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read() or b"{}")


async def scripted_ride(base: str, kind: str = "first") -> dict[str, Any]:
    """One participant: consent, one ride driven at `TARGET_SPEED_MPS`.

    Returns:
        ``{"status", "frames", "error"}``; status is the ride's own, or
        'busy' / 'refused' / 'lost' when the server did not let it finish.
    """
    import websockets

    status, body = await asyncio.to_thread(
        http_json, "POST", f"{base}/api/participants", {"consent": True}
    )
    if status != 201:
        return {"status": "refused", "frames": 0, "error": body}
    pid = body["participant_id"]
    status, ride = await asyncio.to_thread(
        http_json, "POST", f"{base}/api/rides", {"participant_id": pid, "kind": kind}
    )
    if status != 201:
        return {
            "status": "busy" if status == 503 else "refused",
            "frames": 0,
            "error": ride,
        }
    url = (
        base.replace("http", "ws")
        + f"/ws/rides/{ride['ride_id']}?token={ride['token']}"
    )
    frames, seq, sent = 0, -1, (None, None)
    probes: dict[int, dict[str, Any]] = {}  # input number -> its times
    latency: list[dict[str, float]] = []
    try:
        # no keepalive pings of our own, as a browser sends none: a rider
        # starved of CPU for 20 s would otherwise close its own ride
        async with websockets.connect(url, open_timeout=30, ping_interval=None) as ws:
            async for text in ws:
                now = time.perf_counter()
                message = json.loads(text)
                if message["type"] == "ready":
                    await ws.send(json.dumps({"type": "start"}))
                elif message["type"] == "frame":
                    frames += 1
                    for probe in probes.values():
                        if message["seq"] >= probe["seq"]:
                            probe.setdefault("received", now)
                    latency += _measured(probes)
                    speed = message["ego"][3] if message["ego"] else 0.0
                    pedals = _pedals(speed) if frames % DECIDE_EVERY == 0 else sent
                    if pedals != sent:
                        seq += 1
                        sent = pedals
                        probes[seq] = {"seq": seq, "sent": time.perf_counter()}
                        await _send_unless_over(
                            ws,
                            {
                                "type": "input",
                                "seq": seq,
                                "throttle": pedals[0],
                                "brake": pedals[1],
                            },
                        )
                elif message["type"] == "timing" and message["seq"] in probes:
                    probes[message["seq"]]["server"] = message
                    latency += _measured(probes)
                elif message["type"] == "end":
                    return {
                        "status": message["status"],
                        "frames": frames,
                        "error": message.get("error"),
                        "latency": latency,
                    }
    except (OSError, websockets.exceptions.WebSocketException) as err:
        return {"status": "lost", "frames": frames, "error": repr(err)}
    return {"status": "lost", "frames": frames, "error": "closed without an end"}


async def _send_unless_over(ws: Any, message: dict[str, Any]) -> None:
    """Send a rider's message; a ride the server has just ended (closed
    normally, its ``end`` message still to be read) takes no more input, as
    a browser's pedal press after the end goes nowhere."""
    import websockets

    with contextlib.suppress(websockets.exceptions.ConnectionClosedOK):
        await ws.send(json.dumps(message))


#: The server's parts of an input's way to the frame (the ``timing`` message).
SERVER_PARTS = ("relay_in", "wait", "sumo", "frame", "relay_out")


def _measured(probes: dict[int, dict[str, Any]]) -> list[dict[str, float]]:
    """The inputs whose frame came and whose timing the server sent, part by
    part (ms), taken out of `probes`: the server's parts, the WebSocket both
    ways (``websocket``: what is left of the round trip) and ``total``."""
    done = [n for n, p in probes.items() if "received" in p and "server" in p]
    out = []
    for n in done:
        probe = probes.pop(n)
        total = (probe["received"] - probe["sent"]) * 1e3
        parts = {k: probe["server"][k] for k in SERVER_PARTS}
        inside = sum(v for v in parts.values() if v is not None)
        out.append({**parts, "websocket": total - inside, "total": total})
    return out


def _pedals(speed: float) -> tuple[float, float]:
    """A driver who holds about `TARGET_SPEED_MPS` (pedals in steps of 0.25)."""
    error = TARGET_SPEED_MPS - speed
    throttle = round(min(max(error / 3.0, 0.0), 1.0) * 4) / 4
    brake = round(min(max(-error / 6.0, 0.0), 1.0) * 4) / 4
    return throttle, brake
