"""Limits on what a request may send, with short errors that echo nothing.

- A body over `MAX_BODY_BYTES` is refused with 413 before it is read whole:
  at once when its Content-Length says so, else as soon as the bytes read
  pass the limit (`BodyLimit`).
- A body that fails its check gets 422 naming the fields at fault, without
  the input itself (FastAPI's default echoes it whole; `validation_error`).
"""

from __future__ import annotations

import json
from typing import Any

from fastapi import Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

#: Largest request body, bytes. The largest the pages send (demographics)
#: is under 100.
MAX_BODY_BYTES = 4096
#: Longest message of one validation error.
MAX_ERROR_CHARS = 200


def too_large_detail() -> str:
    return f"request body over {MAX_BODY_BYTES} bytes"


class BodyLimit:
    """ASGI middleware refusing HTTP bodies over `MAX_BODY_BYTES` with 413."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = dict(scope["headers"]).get(b"content-length")
        declared = None if length is None else int(length) if length.isdigit() else -1
        if declared is not None and not 0 <= declared <= MAX_BODY_BYTES:
            await _refuse(send)
            return
        received = 0
        refused = False

        async def limited_receive() -> dict:
            nonlocal received, refused
            if refused:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > MAX_BODY_BYTES:  # answered here; the app sees a
                    refused = True  # client that left and its reply is dropped
                    await _refuse(send)
                    return {"type": "http.disconnect"}
            return message

        async def guarded_send(message: dict) -> None:
            if not refused:
                await send(message)

        await self.app(scope, limited_receive, guarded_send)


async def _refuse(send: Any) -> None:
    body = json.dumps({"detail": too_large_detail()}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": 413,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


async def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """422 naming each field at fault and what was expected, not its value."""
    errors = exc.errors() if isinstance(exc, RequestValidationError) else []
    detail = [
        {
            "loc": [str(part)[:40] for part in error.get("loc", ())][:6],
            "msg": str(error.get("msg", ""))[:MAX_ERROR_CHARS],
            "type": error.get("type"),
        }
        for error in errors[:10]
    ]
    return JSONResponse({"detail": detail}, status_code=422)
