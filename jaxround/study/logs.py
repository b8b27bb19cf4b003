"""What the server says on stderr: one JSON line per event, no personal data.

Two kinds of line, both written by the ``jaxround.study`` logger:

- an event of a participant or a ride: ``{"time": ..., "event":
  "ride_ended", "participant": "...", "ride": "...", "status": "arrived",
  ...}`` (`log_event`);
- an access line per HTTP request and WebSocket: ``{"time": ..., "event":
  "http", "method": "POST", "route": "/api/participants/{participant_id}/answers",
  "status": 201, "ms": 3.1}`` (`AccessLog`). The route is the app's pattern,
  never the query string (the admin token may be in it) and never the
  client's address.

Participant ids are the random ones of the database; answers, demographics
and addresses are never logged (an answer's line names the question only).
`jaxround study serve` sends the lines to stderr (`log_to_stderr`); tests
read them through the logger.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from datetime import UTC, datetime
from typing import Any

LOGGER = logging.getLogger("jaxround.study")
#: Longest path written for a request that matched no route.
MAX_LOGGED_PATH = 80


class JsonLines(logging.Formatter):
    """A record's fields as one JSON object per line."""

    def format(self, record: logging.LogRecord) -> str:
        fields = getattr(record, "fields", None) or {"message": record.getMessage()}
        when = datetime.fromtimestamp(record.created, UTC)
        return json.dumps(
            {"time": when.isoformat(timespec="milliseconds"), **fields},
            separators=(",", ":"),
            default=str,
        )


def log_to_stderr() -> None:
    """Send the study's lines to stderr, one JSON object each."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonLines())
    LOGGER.addHandler(handler)
    LOGGER.setLevel(logging.INFO)
    LOGGER.propagate = False


def log_event(event: str, **fields: Any) -> None:
    """One line for a participant's or a ride's event."""
    LOGGER.info(event, extra={"fields": {"event": event, **fields}})


class AccessLog:
    """ASGI middleware: one line per HTTP request and WebSocket connection."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()
        status: dict[str, int | None] = {"code": None}

        async def watched_send(message: dict) -> None:
            if message["type"] == "http.response.start":
                status["code"] = message["status"]
            elif message["type"] == "websocket.close" and status["code"] is None:
                status["code"] = message.get("code", 1000)
            await send(message)

        try:
            await self.app(scope, receive, watched_send)
        finally:
            route = scope.get("route")
            path = getattr(route, "path", None) or scope["path"][:MAX_LOGGED_PATH]
            log_event(
                "http" if scope["type"] == "http" else "websocket",
                method=scope.get("method", "GET"),
                route=path,
                status=status["code"],
                ms=round((time.perf_counter() - started) * 1e3, 1),
            )
