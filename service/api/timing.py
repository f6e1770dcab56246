"""``Server-Timing`` on every answer: how long the app took, so a slow request can be told apart from
a slow network or a slow client, and how much of it the request's store writes waited for the store's
write lock, held it and committed (``store-wait``, ``store-held``, ``store-commit``, of the hold;
:data:`service.store.write_lock.LOCK_TIMES`).

A client's latency holds its own scheduling as well as the service's; on a loaded machine the two
are of the same size, and only the service's own clock separates them. The header (W3C Server
Timing) is shown by browsers' developer tools, and ``bodyhealth bench alerts`` keeps it beside each
approval's round trip. It counts from the request reaching the app (after the server parsed it) to
the response's start: the middlewares, the route and its wait for a worker thread. A slow write
that waited is queued behind another writer; one that held the lock long ran slowly itself, in its
statements or in its commit.

Example
-------
>>> from fastapi import FastAPI
>>> from fastapi.testclient import TestClient
>>> app = FastAPI()
>>> _ = app.get("/")(lambda: {})
>>> app.add_middleware(ServerTiming)
>>> TestClient(app).get("/").headers["server-timing"].startswith("app;dur=")
True
>>> server_timings("app;dur=12.5, store-wait;dur=0.0, store-held;dur=3.1")
{'app': 12.5, 'store-wait': 0.0, 'store-held': 3.1}
"""

from __future__ import annotations

import re
import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.store.write_lock import LOCK_TIMES

__all__ = ["ServerTiming", "server_timings"]

_DUR = re.compile(r"(?:^|,)\s*([A-Za-z0-9_-]+);dur=([0-9.]+)")


class ServerTiming:
    """Pure ASGI middleware: ``Server-Timing: app;dur=<ms>, store-wait;dur=<ms>, store-held;dur=<ms>,
    store-commit;dur=<ms>`` on each HTTP response."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        lock = [0.0, 0.0, 0.0]  # this request's store writes: seconds waited, held, committing
        token = LOCK_TIMES.set(lock)

        async def timed_send(msg: Message) -> None:
            if msg["type"] == "http.response.start":
                ms = (time.perf_counter() - start) * 1e3
                wait, held, commit = (1e3 * x for x in lock)
                value = (
                    f"app;dur={ms:.1f}, store-wait;dur={wait:.1f}, store-held;dur={held:.1f}, "
                    f"store-commit;dur={commit:.1f}"
                )
                msg = {**msg, "headers": [*(msg.get("headers") or []), (b"server-timing", value.encode())]}
            await send(msg)

        try:
            await self.app(scope, receive, timed_send)
        finally:
            LOCK_TIMES.reset(token)


def server_timings(header: str | None) -> dict[str, float]:
    """Every ``name;dur=ms`` of a ``Server-Timing`` header value (empty without one)."""
    return {m.group(1): float(m.group(2)) for m in _DUR.finditer(header or "")}
