"""Who may call the API, and how: bearer tokens, JSON-only mutating requests (docs/security.md).

A browser on the operator's machine can be made to send requests to a service on ``localhost`` by any
page it visits. Three checks keep such requests from changing anything:

* :func:`authorize`, a dependency on every ``/api/v1`` route: with a write token configured, every
  mutating request (POST, PUT, PATCH, DELETE) must carry ``Authorization: Bearer <token>``; with a read
  token configured too, every read must carry one of the two. Tokens are compared in constant time.
* :class:`JsonOnly`, ASGI middleware: a mutating request whose body is anything but JSON is refused
  (415) before a route runs, so a plain HTML form (urlencoded, multipart, text/plain: the only bodies
  a cross-site page can send without a CORS preflight) cannot reach a route.
* Starlette's ``TrustedHostMiddleware`` (set up in :func:`service.api.create_app`) refuses ``Host``
  headers outside ``allowed_hosts``, so a DNS name rebound to 127.0.0.1 does not reach the API.

There is deliberately no CORS middleware: no other origin may read the API's answers.
"""

from __future__ import annotations

import hmac

from fastapi import HTTPException, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.datastructures import Headers
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

__all__ = ["BEARER_SCHEME", "MUTATING_METHODS", "JsonOnly", "authorize", "bearer"]

#: Methods that change state: they need the write token and a JSON body (or none).
MUTATING_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: Name of the security scheme in the OpenAPI document.
BEARER_SCHEME = "bearer"

# auto_error=False: a missing header reaches authorize() (which decides whether one is needed) instead
# of failing every request, and the answer keeps this API's 401 shape.
bearer = HTTPBearer(
    auto_error=False,
    scheme_name=BEARER_SCHEME,
    description="BODYHEALTH_API_TOKEN for every request that changes something; "
    "BODYHEALTH_API_READ_TOKEN (or the write token) for reads when that is set",
)


def _unauthorized(detail: str) -> HTTPException:
    return HTTPException(status_code=401, detail=detail, headers={"WWW-Authenticate": "Bearer"})


def _same(given: str, token: str | None) -> bool:
    """Constant-time equality (bytes: compare_digest refuses non-ASCII str)."""
    return token is not None and hmac.compare_digest(given.encode("utf-8"), token.encode("utf-8"))


async def authorize(
    request: Request, credentials: HTTPAuthorizationCredentials | None = Security(bearer)
) -> None:
    """Let the request through when it needs no token or carries a right one; else 401.

    Mutating methods need the write token (``app.state.api_token``); other methods need the read or
    the write token when a read token (``app.state.api_read_token``) is configured. ``async``: it only
    compares strings, so it runs on the event loop rather than a worker thread."""
    write: str | None = request.app.state.api_token
    read: str | None = request.app.state.api_read_token
    mutating = request.method in MUTATING_METHODS
    if (write if mutating else read) is None:
        return
    if credentials is None:
        raise _unauthorized("this request needs a bearer token: send 'Authorization: Bearer <token>'")
    given = credentials.credentials
    if _same(given, write) or (not mutating and _same(given, read)):
        return
    if mutating and _same(given, read):
        raise _unauthorized("the read token cannot change anything: use the write token")
    raise _unauthorized("invalid bearer token")


def _body_problem(headers: Headers) -> str | None:
    """Why a mutating request's body is refused, or None. A body must be JSON; a request without a
    body may say it is JSON or say nothing (what ``fetch`` sends for a body-less POST)."""
    ctype = headers.get("content-type")
    media = ctype.split(";", 1)[0].strip().lower() if ctype is not None else None
    if media == "application/json":
        return None
    if media is not None:
        return f"content type {media!r} is not accepted: send application/json"
    has_body = headers.get("content-length", "0").strip() != "0" or "transfer-encoding" in headers
    return "a request body must be sent as application/json" if has_body else None


class JsonOnly:
    """Pure ASGI middleware: answer 415 to a mutating request whose body is not JSON (see the module
    doc). Only headers are read, so it runs before the body is."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] in MUTATING_METHODS:
            problem = _body_problem(Headers(scope=scope))
            if problem is not None:
                await JSONResponse({"detail": problem}, status_code=415)(scope, receive, send)
                return
        await self.app(scope, receive, send)
