"""``Server-Timing`` on every answer: how long the app took, so a slow request can be told apart from
a slow network or a slow client.

A client's latency holds its own scheduling as well as the service's; on a loaded machine the two
are of the same size, and only the service's own clock separates them. The header (W3C Server
Timing) is shown by browsers' developer tools, and ``bodyhealth bench alerts`` keeps it beside each
approval's round trip. It counts from the request reaching the app (after the server parsed it) to
the response's start: the middlewares, the route and its wait for a worker thread.

Example
-------
>>> from fastapi import FastAPI
>>> from fastapi.testclient import TestClient
>>> app = FastAPI()
>>> _ = app.get("/")(lambda: {})
>>> app.add_middleware(ServerTiming)
>>> TestClient(app).get("/").headers["server-timing"].startswith("app;dur=")
True
>>> server_ms("app;dur=12.5"), server_ms(None)
(12.5, None)
"""

from __future__ import annotations

import re
import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["ServerTiming", "server_ms"]

_DUR = re.compile(r"(?:^|,)\s*app;dur=([0-9.]+)")


class ServerTiming:
    """Pure ASGI middleware: ``Server-Timing: app;dur=<ms>`` on each HTTP response."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()

        async def timed_send(msg: Message) -> None:
            if msg["type"] == "http.response.start":
                ms = (time.perf_counter() - start) * 1e3
                headers = list(msg.get("headers") or [])
                headers.append((b"server-timing", f"app;dur={ms:.1f}".encode()))
                msg = {**msg, "headers": headers}
            await send(msg)

        await self.app(scope, receive, timed_send)


def server_ms(header: str | None) -> float | None:
    """The app's milliseconds from a ``Server-Timing`` header value; None when it has none."""
    m = _DUR.search(header or "")
    return float(m.group(1)) if m else None
