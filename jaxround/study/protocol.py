"""What a browser may send on a ride's WebSocket, checked before it is used.

Messages are JSON text of at most `MAX_MESSAGE_BYTES`:

- ``{"type": "start"}``: the participant is ready; the ride begins.
- ``{"type": "input", "seq": n, "throttle": t, "brake": b}``: pedal
  positions in [0, 1], ``seq`` counting up from 0.
- ``{"type": "lane", "direction": "left"}`` (or ``"right"``): the turn
  signal, asking for the lane beside on a two-lane road
  (`jaxround.study.ego_lanes`).
- ``{"type": "latency", "seq": n, "ms": x}``: the browser's time from input
  ``n`` to the first frame drawn that reflects it.

Anything else (not JSON, another type, a missing, extra or out-of-range
field, more than `MAX_MESSAGES_PER_S` messages in a second) is refused with
a message that names what is wrong; the server then ends the ride (status
``bad_message``).
"""

from __future__ import annotations

import json
import math
from typing import Any

#: Largest message a browser may send, bytes (the server closes the
#: connection with 1009 over it).
MAX_MESSAGE_BYTES = 1024
#: Most messages a browser may send in a second (a person's pedals need about
#: 20; the ride process must read them all).
MAX_MESSAGES_PER_S = 100
#: Largest input number.
MAX_SEQ = 2**31 - 1
#: Largest latency a browser may report, ms.
MAX_LATENCY_MS = 60_000.0
#: Fields of each message type.
FIELDS = {
    "start": {"type"},
    "input": {"type", "seq", "throttle", "brake"},
    "latency": {"type", "seq", "ms"},
    "lane": {"type", "direction"},
}
#: The turn signal's directions.
LANE_DIRECTIONS = ("left", "right")


class BadMessageError(ValueError):
    """A browser message that breaks the protocol; the text says how."""


def parse_message(text: str) -> dict[str, Any]:
    """The checked message, or BadMessageError naming what is wrong."""
    if len(text.encode()) > MAX_MESSAGE_BYTES:
        raise BadMessageError(
            f"message of {len(text.encode())} bytes, at most "
            f"{MAX_MESSAGE_BYTES} allowed"
        )
    try:
        message = json.loads(text)
    except json.JSONDecodeError as err:
        raise BadMessageError(f"not JSON ({err.msg} at character {err.pos})") from None
    if not isinstance(message, dict):
        raise BadMessageError("a message is a JSON object")
    kind = message.get("type")
    if kind not in FIELDS:
        raise BadMessageError(f"type {kind!r}, expected one of {sorted(FIELDS)}")
    fields = set(message)
    if fields != FIELDS[kind]:
        missing = sorted(FIELDS[kind] - fields)
        extra = sorted(fields - FIELDS[kind])
        raise BadMessageError(
            f"{kind}: missing fields {missing}, unknown fields {extra}"
        )
    if kind in ("input", "latency"):
        _integer(message, "seq", MAX_SEQ)
    if kind == "input":
        _number(message, "throttle", 1.0)
        _number(message, "brake", 1.0)
    if kind == "latency":
        _number(message, "ms", MAX_LATENCY_MS)
    if kind == "lane" and message["direction"] not in LANE_DIRECTIONS:
        raise BadMessageError(
            f"lane.direction: {message['direction']!r}, expected one of "
            f"{list(LANE_DIRECTIONS)}"
        )
    return message


def _integer(message: dict[str, Any], name: str, high: int) -> None:
    value = message[name]
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= high:
        raise BadMessageError(
            f"{message['type']}.{name}: {value!r}, expected an integer 0-{high}"
        )


def _number(message: dict[str, Any], name: str, high: float) -> None:
    value = message[name]
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if not ok or not math.isfinite(value) or not 0.0 <= value <= high:
        raise BadMessageError(
            f"{message['type']}.{name}: {value!r}, expected a number 0-{high:g}"
        )
