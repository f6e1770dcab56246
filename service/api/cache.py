"""Rendered answers of the read routes, reused while nothing was written, refreshed off the request path.

Dashboards and REST clients poll the same few reads many times a second, and each costs the store 10 to
30 SQL statements (the robot list: every robot's parts, newest topology, baseline and alerts), while
what they read changes about once a second: the ingest writer commits at most once per
``ingest_commit_interval_seconds`` and the worker every cycle. So the JSON of a read is kept, keyed by
route and arguments, with the store's count of committed transactions
(:attr:`Store.generation <service.store.schema.StoreBase.generation>`) when its rendering began.

An entry is served while it is at most ``api_cache_seconds`` old. When the store has committed since
it was rendered, or it is past half that age, the request that finds it still gets it, and one
rendering for that key starts on the cache's own threads (never two for one key); the next requests
get the new answer once it is there (stale-while-revalidate, as HTTP's RFC 5861). Only a request that
finds no entry young enough waits for a rendering, and it shares one in flight. Rendering on the
request path was what made the tail: under the ingest and the worker, every commit sent the next
requests of each key into a rendering of tens to hundreds of milliseconds (docs/bench/load.md).

A rendering reuses what it shares with others: a robot's status (:meth:`ReadCache.memo`; the robot
list asks every robot's) is kept while the store committed nothing but frames
(:attr:`Store.analysis_generation <service.store.schema.StoreBase.analysis_generation>`: the ingest
writer commits every second, the worker and the trainers far less often) and for at most
``api_cache_seconds``, like an answer.

So a read reflects every commit made at least ``api_cache_seconds`` (plus one rendering) before it;
writers in other processes sharing a PostgreSQL database are seen the same way. Writes made through
this API are seen by the next read at once: a mutating request that succeeds empties the cache
(:func:`service.api.create_app`). Authentication runs before the cache (a route's dependencies),
errors are never kept, and a hit runs on the event loop without touching the database or a thread.

Written here rather than taken from an HTTP caching library: the validity rule is the store's commit
count, which no generic cache knows about.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Hashable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from fastapi import Request
from fastapi.encoders import jsonable_encoder
from fastapi.responses import JSONResponse, Response
from pydantic_core import PydanticSerializationError, to_jsonable_python
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.status import RobotStatus, robot_status
from service.store import Store, StoredFloating

__all__ = ["FLEET_STATUSES", "ClearOnWrite", "ReadCache", "cached_floating", "cached_status", "read_cache"]


@dataclass(frozen=True)
class _Entry:
    generation: int
    at: float
    body: bytes


@dataclass(frozen=True)
class _Memo:
    generation: int  # the store's analysis generation before computing
    at: float
    value: Any


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
        threads: int = 2,
    ) -> None:
        self.store = store
        self.max_age = float(max_age)
        self.max_entries = int(max_entries)
        self.clock = clock
        self.hits = 0
        self.misses = 0
        #: Hits served while a newer answer was being rendered (the store had committed since).
        self.stale_hits = 0
        self._entries: dict[Hashable, _Entry] = {}
        self._memos: dict[Hashable, _Memo] = {}
        #: Each robot's answer with what it was judged from (:func:`service.status.robot_statuses`):
        #: after a retrain the fleet's statuses are read again, and only the robot that changed is judged.
        self.judged: dict[str, tuple[Any, RobotStatus]] = {}
        self._floor = 0  # entries rendered from an older generation are not served (see clear)
        self._inflight: dict[Hashable, tuple[int, Future[bytes], object]] = {}
        self._lock = threading.Lock()
        self._threads = int(threads)
        self._pool: ThreadPoolExecutor | None = None

    async def respond(self, key: Hashable, render: Callable[[], Any]) -> Response:
        """The kept body for ``key`` while young enough (refreshed in the background when the store
        committed since), else ``render()`` (on a thread: it reads the database) encoded as the route's
        JSON and kept."""
        generation, now = self.store.generation, self.clock()
        if self.max_age <= 0:
            self.misses += 1
            return _json(await asyncio.wrap_future(self._executor().submit(lambda: _encode(render()))))
        entry = self._entries.get(key)
        if entry is not None and entry.generation >= self._floor and now - entry.at <= self.max_age:
            self.hits += 1
            if entry.generation != generation or now - entry.at > self.max_age / 2:
                self.stale_hits += entry.generation != generation
                self._start(key, render, generation, now)  # its errors are dropped: not kept
            return _json(entry.body)
        self.misses += 1
        return _json(await asyncio.wrap_future(self._start(key, render, generation, now)))

    def memo(
        self, key: Hashable, compute: Callable[[], Any], usable: Callable[[Any], bool] | None = None
    ) -> Any:
        """``compute()``, or the value it gave for ``key`` while the store has committed nothing but
        frames since and it is at most ``max_age`` old (module doc), and ``usable(value)`` says it still
        answers (the fleet's statuses: every robot listed now is in them). For parts of answers that
        depend on what is learned, not on the frames: a robot's status. Errors are not kept."""
        kept = self.kept(key)
        if kept is not None and (usable is None or usable(kept)):
            return kept
        generation, now = self.store.analysis_generation, self.clock()
        value = compute()
        with self._lock:
            if len(self._memos) >= self.max_entries and key not in self._memos:
                self._memos.clear()
            self._memos[key] = _Memo(generation, now, value)
        return value

    def kept(self, key: Hashable) -> Any | None:
        """The value :meth:`memo` keeps for ``key`` while it is valid, else None; computes nothing."""
        kept = self._memos.get(key) if self.max_age > 0 else None
        if kept is None or kept.generation != self.store.analysis_generation:
            return None
        return kept.value if self.clock() - kept.at <= self.max_age else None

    def clear(self) -> None:
        """Forget every kept answer and value, and any rendered before now that is still in flight (a
        write through the API: its next read must see it)."""
        with self._lock:
            self._entries.clear()
            self._memos.clear()
            self._floor = self.store.generation

    def _executor(self) -> ThreadPoolExecutor:
        with self._lock:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self._threads, thread_name_prefix="read-cache")
            return self._pool

    def _start(self, key: Hashable, render: Callable[[], Any], generation: int, at: float) -> Future[bytes]:
        """The rendering of ``key`` in flight (unless it began before the last :meth:`clear`), or a
        new one."""
        pool = self._executor()
        with self._lock:
            flight = self._inflight.get(key)
            if flight is not None and flight[0] >= self._floor:
                return flight[1]
            token = object()
            fut = pool.submit(self._render, key, render, generation, at, token)
            self._inflight[key] = (generation, fut, token)
            return fut

    def _render(
        self, key: Hashable, render: Callable[[], Any], generation: int, at: float, token: object
    ) -> bytes:
        try:
            body = _encode(render())
            with self._lock:
                if len(self._entries) >= self.max_entries and key not in self._entries:
                    self._entries.clear()  # a bounded cache; clearing is cheap and refills on demand
                # the generation read before rendering: a write committed meanwhile leaves it stale;
                # a rendering that began earlier and ends later does not replace a newer one
                kept = self._entries.get(key)
                if kept is None or kept.generation <= generation:
                    self._entries[key] = _Entry(generation, at, body)
            return body
        finally:
            with self._lock:
                flight = self._inflight.get(key)
                if flight is not None and flight[2] is token:
                    del self._inflight[key]


def _encode(value: Any) -> bytes:
    """``value`` as the body FastAPI would send for it, byte for byte: pydantic's own serializer turns
    the models into JSON types (what :func:`fastapi.encoders.jsonable_encoder` does in Python, about
    ten times slower: 15 ms for a hundred robots' list, holding the interpreter lock the event loop
    needs), then :class:`JSONResponse` writes them as it always does (a NaN still fails). A value
    pydantic cannot serialize goes the generic way."""
    try:
        plain = to_jsonable_python(value, by_alias=True)
    except PydanticSerializationError:
        plain = jsonable_encoder(value)
    return bytes(JSONResponse(plain).body)


def _json(body: bytes) -> Response:
    return Response(body, media_type="application/json")


class ClearOnWrite:
    """ASGI middleware: a mutating request (not GET, HEAD or OPTIONS) that succeeds empties ``cache``
    before its answer goes out, so the client's next read sees its write (module doc)."""

    def __init__(self, app: ASGIApp, cache: ReadCache) -> None:
        self.app = app
        self.cache = cache

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] in ("GET", "HEAD", "OPTIONS"):
            await self.app(scope, receive, send)
            return

        async def send_clearing(message: Message) -> None:
            if message["type"] == "http.response.start" and message["status"] < 400:
                self.cache.clear()
            await send(message)

        await self.app(scope, receive, send_clearing)


def read_cache(request: Request) -> ReadCache:
    """The app's read cache (``app.state.read_cache``, set by :func:`service.api.create_app`)."""
    return request.app.state.read_cache


#: The memo key of every robot's status (the default method), read for the whole fleet at once by the
#: robot list (:func:`service.status.robot_statuses`).
FLEET_STATUSES: tuple[str] = ("statuses",)


def cached_status(request: Request, store: Store, robot: str, method: str | None = None) -> RobotStatus:
    """:func:`service.status.robot_status`, kept by the read cache while only frames were committed
    (:meth:`ReadCache.memo`): the robot list, a robot's details, its status and its diagnostics all
    ask it, and it costs five reads of the store. While the fleet's statuses the robot list read are
    valid (:data:`FLEET_STATUSES`, same rule), a robot's is taken from them: after each retrain every
    robot's status is judged again, once for the fleet rather than once more per robot asked."""
    cache = read_cache(request)
    if method is None:
        fleet = cache.kept(FLEET_STATUSES)
        if fleet is not None and robot in fleet:
            return fleet[robot]
    return cache.memo(("status", robot, method), lambda: robot_status(store, robot, method))


def cached_floating(request: Request, store: Store) -> dict[str, StoredFloating]:
    """Every robot's floating baseline (:meth:`~service.store.Store.floating_baselines`, one query,
    without the data), kept by the read cache like a status: the robot list, a robot's details and
    its status say from it whether a floating-base robot has a baseline."""
    got: dict[str, StoredFloating] = read_cache(request).memo(("floating",), store.floating_baselines)
    return got
