"""The REST API (FastAPI; OpenAPI document at ``/docs``) and the dashboard at ``/``.

:func:`create_app` builds one app around a store (and, in the daemon, the ingest pipeline that pushed
frames go through, the worker, the metrics and the farm's damage control for simulated robots; the
last two as the protocols of :mod:`service.control`). One router per resource: robots, status,
topology, kinematics, alerts, simulate, health. Bad input never reaches a 500: unknown robots and
alerts are 404, malformed bodies 422, bodies over ``max_request_bytes`` 413, damage on a real robot
409, frames the pipeline could not store in time 503, and a database that fails under a route 503
with ``Retry-After``.

Security (:mod:`service.api.security`, docs/security.md): two ``Host`` headers, or one outside
``allowed_hosts``, are 400; a mutating request from another site, or without a JSON content type or
``X-Requested-With: bodyhealth``, is 403 and one with a non-JSON body 415; a JSON body nested deeper
than ``MAX_JSON_DEPTH`` is 422; with a token configured every ``/api/v1`` route checks the bearer
token (401; reads too unless ``read_token_required`` is off). ``/livez``, ``/readyz`` and
``/metrics`` stay open; no CORS.

Example
-------
>>> from fastapi.testclient import TestClient
>>> from service.store import open_store
>>> client = TestClient(create_app(open_store("sqlite://")))
>>> client.get("/api/v1/robots").json(), client.get("/api/v1/robots/nope").status_code
([], 404)
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request, Security
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api import (
    alerts,
    diagnostics,
    excitation,
    health,
    kinematics,
    robots,
    simulate,
    status,
    topology,
)
from service.api.cache import ClearOnWrite, ReadCache
from service.api.errors import DATABASE_ERRORS, database_unavailable, invalid_request, unparsable_body
from service.api.security import (
    MAX_JSON_DEPTH,
    SingleHost,
    WriteGuard,
    authorize,
    document_security,
    json_depth,
    mutating_routes,
    parse_origins,
)
from service.api.timing import ServerTiming
from service.control import DamageControl, MonitorControl
from service.ingest.pipeline import Pipeline
from service.metrics import Metrics
from service.settings import Settings, get_settings
from service.store import Store, UnknownAlert, UnknownRobot

__all__ = ["API_ROUTERS", "DASHBOARD_DIR", "BodySizeLimit", "create_app"]

log = logging.getLogger(__name__)

DASHBOARD_DIR = Path(__file__).resolve().parent.parent / "dashboard"
#: The ``/api/v1`` routers: every route on them goes through :func:`~service.api.security.authorize`.
API_ROUTERS = (
    robots.router,
    status.router,
    diagnostics.router,
    topology.router,
    kinematics.router,
    alerts.router,
    simulate.router,
    excitation.router,
)


class BodySizeLimit:
    """Pure ASGI middleware: answer 413 to a request body over ``max_bytes``, and 422 to a JSON body
    nested deeper than :data:`~service.api.security.MAX_JSON_DEPTH`.

    Checks ``Content-Length`` first and then counts the streamed body, so a chunked upload without a
    length cannot get past it either; nothing of an oversized request reaches a route. The depth is
    counted before the parser sees the body, which would otherwise fail on its own recursion limit.
    """

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = int(max_bytes)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or [])
        length = headers.get(b"content-length")
        if length is not None:
            try:
                too_big = int(length) > self.max_bytes
            except ValueError:
                too_big = False
            if too_big:
                await self._reject(send)
                return
        # Read the whole body (bounded) before the app sees it, so an oversized chunked body is refused
        # before any route runs.
        body = bytearray()
        more = True
        while more:
            msg = await receive()
            if msg["type"] != "http.request":
                break
            body.extend(msg.get("body", b""))
            if len(body) > self.max_bytes:
                await self._reject(send)
                return
            more = bool(msg.get("more_body"))
        if body and _json_typed(headers) and json_depth(bytes(body)) > MAX_JSON_DEPTH:
            await _too_deep(scope, receive, send)
            return
        done = False

        async def replay() -> Message:
            nonlocal done
            if not done:
                done = True
                return {"type": "http.request", "body": bytes(body), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)

    async def _reject(self, send: Send) -> None:
        detail = f'{{"detail":"request body larger than {self.max_bytes} bytes"}}'.encode()
        await send(
            {
                "type": "http.response.start",
                "status": 413,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(detail)).encode()),
                ],
            }
        )
        await send({"type": "http.response.body", "body": detail})


def _json_typed(headers: dict[bytes, bytes]) -> bool:
    """A body the app would parse as JSON: typed so, or untyped."""
    ctype = headers.get(b"content-type")
    return ctype is None or ctype.split(b";", 1)[0].strip().lower() == b"application/json"


async def _too_deep(scope: Scope, receive: Receive, send: Send) -> None:
    msg = f"JSON nested deeper than {MAX_JSON_DEPTH} levels"
    detail = [{"loc": ["body"], "msg": msg, "type": "json_invalid"}]
    await JSONResponse({"detail": detail}, status_code=422)(scope, receive, send)


def create_app(
    store: Store,
    *,
    settings: Settings | None = None,
    pipeline: Pipeline | None = None,
    worker: MonitorControl | None = None,
    metrics: Metrics | None = None,
    damage: DamageControl | None = None,
    extra_state: dict[str, Any] | None = None,
) -> FastAPI:
    """The API + dashboard app over ``store``; everything else is optional. Pushed frames go through
    ``pipeline`` (default: one without sources, never started, which writes on the request's thread
    through the same commit step)."""
    settings = settings or get_settings()
    app = FastAPI(
        title="bodyhealth",
        version="0.1.0",
        description="Robot body-health monitoring: learned body schemas, baselines and damage alerts.",
    )
    app.state.store = store
    app.state.settings = settings
    app.state.pipeline = pipeline if pipeline is not None else Pipeline(store, [], settings=settings)
    app.state.worker = worker
    app.state.metrics = metrics or getattr(worker, "metrics", None) or Metrics()
    app.state.damage = damage
    app.state.api_token = settings.write_token()
    app.state.api_read_token = settings.read_token()
    app.state.reads_need_token = settings.reads_need_token()
    app.state.read_cache = ReadCache(store, settings.api_cache_seconds)
    for k, v in (extra_state or {}).items():
        setattr(app.state, k, v)

    for router in API_ROUTERS:
        app.include_router(router, dependencies=[Security(authorize)])
    document_security(
        app, write_token=app.state.api_token is not None, reads_need_token=app.state.reads_need_token
    )
    app.include_router(health.router)  # probes and metrics stay open: they change nothing

    @app.exception_handler(UnknownRobot)
    async def _unknown_robot(request: Request, exc: UnknownRobot) -> JSONResponse:
        return JSONResponse({"detail": f"unknown robot {exc.args[0]!r}"}, status_code=404)

    app.add_exception_handler(RequestValidationError, invalid_request)
    app.add_exception_handler(StarletteHTTPException, unparsable_body)
    for error in DATABASE_ERRORS:  # a database that fails under a route: 503 + Retry-After, never a 500
        app.add_exception_handler(error, database_unavailable)

    @app.exception_handler(UnknownAlert)
    async def _unknown_alert(request: Request, exc: UnknownAlert) -> JSONResponse:
        return JSONResponse({"detail": f"unknown alert {exc.args[0]!r}"}, status_code=404)

    if DASHBOARD_DIR.is_dir():
        app.mount("/static", StaticFiles(directory=DASHBOARD_DIR), name="static")

        @app.get("/", include_in_schema=False)
        def dashboard() -> FileResponse:
            return FileResponse(DASHBOARD_DIR / "index.html")

    # The last added runs first: the app's time (the Server-Timing header), one Host, a trusted one,
    # then where a write comes from and its body's type (headers only), then the body's size and
    # depth; a write that succeeds empties the read cache before its answer goes out.
    app.add_middleware(ClearOnWrite, cache=app.state.read_cache)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_request_bytes)
    origins = parse_origins(settings.allowed_origins or ())  # a bad one stops the app here
    app.add_middleware(WriteGuard, routes=lambda: mutating_routes(app), allowed=origins)
    app.add_middleware(TrustedHostMiddleware, allowed_hosts=settings.trusted_hosts(), www_redirect=False)
    app.add_middleware(SingleHost)
    app.add_middleware(ServerTiming)
    return app
