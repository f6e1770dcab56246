"""Rendered answers of the read routes, reused while nothing was written.

Dashboards and REST clients poll the same few reads many times a second, and each costs the store 10 to
30 SQL statements (the robot list: every robot's parts, newest topology, baseline and alerts), while
what they read changes about once a second: the ingest writer commits at most once per
``ingest_commit_interval_seconds`` and the worker every cycle. So the JSON of a read is kept, keyed by
route and arguments, and served again while the store's count of committed transactions
(:attr:`Store.generation <service.store.schema.StoreBase.generation>`) is unchanged and the entry is at
most ``api_cache_seconds`` old. A read therefore never misses a write this process committed before it
began; writers in other processes sharing a PostgreSQL database are seen within ``api_cache_seconds``.
Authentication runs before the cache (a route's dependencies), errors are never kept, and a hit runs
on the event loop without touching the database or a worker thread.

Written here rather than taken from an HTTP caching library: the validity rule is the store's commit
count, which no generic cache knows about.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any

from fastapi import Request
from fastapi.concurrency import run_in_threadpool
from fastapi.encoders import jsonable_encoder
from fastapi.responses import JSONResponse, Response

from service.store import Store

__all__ = ["ReadCache", "read_cache"]


@dataclass(frozen=True)
class _Entry:
    generation: int
    at: float
    body: bytes


class ReadCache:
    """JSON bodies of read routes for one store (see the module doc); ``max_age`` 0 disables it.

    >>> import asyncio
    >>> from service.store import open_store
    >>> cache = ReadCache(open_store("sqlite://"), max_age=1.0)
    >>> calls = []
    >>> def render():
    ...     calls.append(1)
    ...     return {"n": len(calls)}
    >>> [asyncio.run(cache.respond(("k",), render)).body for _ in range(2)], len(calls)
    ([b'{"n":1}', b'{"n":1}'], 1)
    """

    def __init__(
        self,
        store: Store,
        max_age: float,
        max_entries: int = 4096,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.store = store
        self.max_age = float(max_age)
        self.max_entries = int(max_entries)
        self.clock = clock
        self.hits = 0
        self.misses = 0
        self._entries: dict[Hashable, _Entry] = {}

    async def respond(self, key: Hashable, render: Callable[[], Any]) -> Response:
        """The kept body for ``key`` when still valid, else ``render()`` (on a worker thread: it reads
        the database) encoded as the route's JSON and kept."""
        generation, now = self.store.generation, self.clock()
        if self.max_age > 0:
            entry = self._entries.get(key)
            if entry is not None and entry.generation == generation and now - entry.at <= self.max_age:
                self.hits += 1
                return Response(entry.body, media_type="application/json")
        self.misses += 1
        body = JSONResponse(jsonable_encoder(await run_in_threadpool(render))).body
        if self.max_age > 0:
            if len(self._entries) >= self.max_entries:
                self._entries.clear()  # a bounded cache; clearing is cheap and refills on demand
            # the generation read before rendering: a write committed meanwhile invalidates the entry
            self._entries[key] = _Entry(generation, now, bytes(body))
        return Response(body, media_type="application/json")


def read_cache(request: Request) -> ReadCache:
    """The app's read cache (``app.state.read_cache``, set by :func:`service.api.create_app`)."""
    return request.app.state.read_cache
