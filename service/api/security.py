"""Who may call the API, and how: bearer tokens, requests from other sites, one ``Host``, JSON bodies of a
bounded depth (docs/security.md).

A browser on the operator's machine sends requests to a service on ``localhost`` for any page it
shows, and a body-less POST or an HTML form needs no CORS preflight. These checks keep such requests
from changing anything, with or without a token:

* :class:`WriteGuard`, ASGI middleware on every mutating request (POST, PUT, PATCH, DELETE) that a
  route of the app serves, before the route runs: 403 when ``Origin`` names another origin than the
  service's own (or ``null``) and is not one of ``allowed_origins``, or when ``Sec-Fetch-Site`` is
  ``cross-site`` or ``same-site`` (on ``localhost`` every port is the same site) and the origin is not
  an allowed one; 415 for a body that is not JSON; 403 for a request that sends neither
  ``Content-Type: application/json`` nor ``X-Requested-With: bodyhealth``. A page of another site
  can send neither without a preflight, which fails: there is no CORS.
* :func:`authorize`, a dependency on every ``/api/v1`` route: with a write token configured, every
  mutating request must carry ``Authorization: Bearer <token>``; reads of robot data need the read or
  the write token when ``read_token_required`` (by default whenever a token is set). Tokens are
  compared in constant time.
* :class:`SingleHost` refuses a request with more than one ``Host`` header (400), and Starlette's
  ``TrustedHostMiddleware`` (set up in :func:`service.api.create_app`) ``Host`` headers outside
  ``allowed_hosts``, so a DNS name rebound to 127.0.0.1 does not reach the API.
* :func:`json_depth` bounds how deeply a JSON body may nest (:data:`MAX_JSON_DEPTH`) before the parser
  sees it, so a deeply nested body gets its own answer rather than a parser's recursion error.

:func:`document_security` makes the OpenAPI document say what each operation needs: its ``security``
(the bearer scheme, or empty for an open operation), the ``X-Requested-With`` header of a body-less
mutating operation and the 403 of every mutating operation.
"""

from __future__ import annotations

import hmac
from collections.abc import Callable, Iterable, Sequence
from typing import Any
from urllib.parse import urlsplit

import numpy as np
from fastapi import FastAPI, HTTPException, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.datastructures import Headers
from starlette.responses import JSONResponse
from starlette.routing import compile_path
from starlette.types import ASGIApp, Receive, Scope, Send

__all__ = [
    "API_PREFIX",
    "BEARER_SCHEME",
    "INTENT_HEADER",
    "INTENT_VALUE",
    "MAX_JSON_DEPTH",
    "MUTATING_METHODS",
    "Origin",
    "SingleHost",
    "WriteGuard",
    "authorize",
    "bearer",
    "document_security",
    "json_depth",
    "mutating_routes",
    "needs_token",
    "parse_origins",
]

#: Methods that change state: they need the write token, a same-origin request and a JSON body or none.
MUTATING_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: Name of the security scheme in the OpenAPI document.
BEARER_SCHEME = "bearer"
#: The routes that serve robot data (and need a token when one is configured).
API_PREFIX = "/api/v1"
#: The header a body-less mutating request sends to say it was not made by a form or a plain link.
INTENT_HEADER = "X-Requested-With"
INTENT_VALUE = "bodyhealth"
#: How deeply a JSON body may nest: a frames body nests 4 levels (object, T, K, axis); 32 leaves room
#: for any body of this API and keeps far from the parser's recursion limit (about 1000).
MAX_JSON_DEPTH = 32

# auto_error=False: a missing header reaches authorize() (which decides whether one is needed) instead
# of failing every request, and the answer keeps this API's 401 shape.
bearer = HTTPBearer(
    auto_error=False,
    scheme_name=BEARER_SCHEME,
    description="BODYHEALTH_API_TOKEN for every request that changes something; for reads of robot data "
    "(read_token_required, on by default with a token) BODYHEALTH_API_READ_TOKEN or the write token",
)


def _unauthorized(detail: str) -> HTTPException:
    return HTTPException(status_code=401, detail=detail, headers={"WWW-Authenticate": "Bearer"})


def _same(given: str, token: str | None) -> bool:
    """Constant-time equality (bytes: compare_digest refuses non-ASCII str)."""
    return token is not None and hmac.compare_digest(given.encode("utf-8"), token.encode("utf-8"))


def needs_token(method: str, path: str, *, write_token: bool, reads_need_token: bool) -> bool:
    """Whether a request of ``method`` to ``path`` needs a bearer token: mutating requests under
    :data:`API_PREFIX` when a write token is set, reads there when ``reads_need_token``. Probes,
    metrics, the dashboard and the API document never do.

    >>> needs_token("GET", "/api/v1/robots", write_token=True, reads_need_token=True)
    True
    >>> needs_token("GET", "/readyz", write_token=True, reads_need_token=True)
    False
    """
    if not path.startswith(API_PREFIX):
        return False
    return write_token if method.upper() in MUTATING_METHODS else reads_need_token


async def authorize(
    request: Request, credentials: HTTPAuthorizationCredentials | None = Security(bearer)
) -> None:
    """Let the request through when it needs no token or carries a right one; else 401.

    Mutating methods need the write token (``app.state.api_token``); reads need the read token
    (``app.state.api_read_token``) or the write token when ``app.state.reads_need_token``. ``async``:
    it only compares strings, so it runs on the event loop rather than a worker thread."""
    state = request.app.state
    write: str | None = state.api_token
    read: str | None = state.api_read_token
    mutating = request.method in MUTATING_METHODS
    if not (write is not None if mutating else state.reads_need_token):
        return
    if credentials is None:
        raise _unauthorized("this request needs a bearer token: send 'Authorization: Bearer <token>'")
    given = credentials.credentials
    if _same(given, write) or (not mutating and _same(given, read)):
        return
    if mutating and _same(given, read):
        raise _unauthorized("the read token cannot change anything: use the write token")
    raise _unauthorized("invalid bearer token")


# ---------------------------------------------------------------------------------- other sites
_DEFAULT_PORT = {"http": 80, "https": 443}
#: An origin as (scheme, host, port).
Origin = tuple[str, str, int]


def _origin(value: str) -> Origin | None:
    """``scheme://host[:port]`` as (scheme, host, port), the port defaulted; None for ``null`` and for
    anything that is not an origin."""
    try:
        parts = urlsplit(value.strip())
        scheme, host, port = parts.scheme.lower(), parts.hostname, parts.port
    except ValueError:  # a port out of range, a bad IPv6 literal
        return None
    if scheme not in _DEFAULT_PORT or not host or parts.path not in ("", "/") or parts.query:
        return None
    return scheme, host.lower(), port if port is not None else _DEFAULT_PORT[scheme]


def _own_origin(scope: Scope, headers: Headers) -> Origin | None:
    """The origin the request was sent to: its scheme (behind a proxy, what ``X-Forwarded-Proto``
    told the server) and its ``Host``."""
    host = headers.get("host")
    return None if host is None else _origin(f"{scope.get('scheme', 'http')}://{host}")


def _media(headers: Headers) -> str | None:
    ctype = headers.get("content-type")
    return ctype.split(";", 1)[0].strip().lower() if ctype is not None else None


def parse_origins(values: Iterable[str]) -> frozenset[Origin]:
    """The ``allowed_origins`` setting as origins; ``ValueError`` for one that is not an origin.

    >>> sorted(parse_origins(["https://Robots.example.org", "http://10.0.0.5:8000"]))
    [('http', '10.0.0.5', 8000), ('https', 'robots.example.org', 443)]
    """
    out = set()
    for value in values:
        o = _origin(value)
        if o is None:
            raise ValueError(f"allowed origin {value!r} is not scheme://host[:port]")
        out.add(o)
    return frozenset(out)


def _cross_site(scope: Scope, headers: Headers, allowed: frozenset[Origin]) -> str | None:
    """Why a mutating request counts as sent by another site, or None. See the module doc."""
    origins = headers.getlist("origin")
    if len(origins) > 1:
        return "cross-site request refused: more than one Origin header"
    origin = _origin(origins[0]) if origins else None
    listed = origin is not None and origin in allowed
    if origins and not listed and (origin is None or origin != _own_origin(scope, headers)):
        return (
            "cross-site request refused: the Origin header names another site than this service; "
            "a page served elsewhere must be listed in BODYHEALTH_ALLOWED_ORIGINS"
        )
    for site in headers.getlist("sec-fetch-site"):
        if site.strip().lower() not in ("same-origin", "none") and not listed:
            return (
                f"cross-site request refused: Sec-Fetch-Site is {site.strip()[:20]!r}; only same-origin "
                "requests (or origins in BODYHEALTH_ALLOWED_ORIGINS) may change anything"
            )
    return None


def _body_problem(headers: Headers) -> str | None:
    """Why a mutating request's body is refused, or None. A body must be JSON; a request without a
    body may say it is JSON or say nothing."""
    media = _media(headers)
    if media == "application/json":
        return None
    if media is not None:
        return f"content type {media!r} is not accepted: send application/json"
    has_body = headers.get("content-length", "0").strip() != "0" or "transfer-encoding" in headers
    return "a request body must be sent as application/json" if has_body else None


def _intent_problem(headers: Headers) -> str | None:
    """None when the request sent something no HTML form or plain link can: a JSON content type or
    ``X-Requested-With: bodyhealth``."""
    if _media(headers) == "application/json":
        return None
    if (headers.get(INTENT_HEADER) or "").strip().lower() == INTENT_VALUE:
        return None
    return (
        f"a request that changes something must send 'Content-Type: application/json' or "
        f"'{INTENT_HEADER}: {INTENT_VALUE}' (a request without a body sends the header)"
    )


RouteTable = Sequence[tuple[Any, frozenset[str]]]


def mutating_routes(app: FastAPI) -> RouteTable:
    """(compiled path, mutating methods) of every route ``app`` serves that changes something."""
    try:
        from fastapi.routing import iter_route_contexts
    except ImportError:  # older FastAPI: app.routes is flat
        pairs: Iterable[tuple[str | None, set[str] | None]] = [
            (getattr(r, "path", None), getattr(r, "methods", None)) for r in app.routes
        ]
    else:
        pairs = [(c.path, c.methods) for c in iter_route_contexts(app.routes)]
    out = []
    for path, methods in pairs:
        changing = frozenset(methods or ()) & MUTATING_METHODS
        if path and changing:
            out.append((compile_path(path)[0], changing))
    return out


class WriteGuard:
    """Pure ASGI middleware: refuse a mutating request from another site (403), with a body that is not
    JSON (415) or without a JSON type or the intent header (403), before its route runs (see the
    module doc). Only headers are read. A request no route serves goes on to the router's 404 or 405.

    ``routes`` gives the app's mutating routes (read on the first request: the app is complete then);
    ``allowed`` the origins besides the service's own that may send them (:func:`parse_origins`)."""

    def __init__(
        self, app: ASGIApp, routes: Callable[[], RouteTable], allowed: frozenset[Origin] = frozenset()
    ) -> None:
        self.app = app
        self._routes_of = routes
        self._routes: RouteTable | None = None
        self.allowed = allowed

    def _served(self, scope: Scope) -> bool:
        if self._routes is None:
            self._routes = self._routes_of()
        path = scope["path"]
        root = scope.get("root_path", "")
        if root and path.startswith(root):
            path = path[len(root) :] or "/"
        method = scope["method"]
        return any(method in methods and regex.match(path) for regex, methods in self._routes)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] in MUTATING_METHODS and self._served(scope):
            headers = Headers(scope=scope)
            status, problem = 403, _cross_site(scope, headers, self.allowed)
            if problem is None:
                status, problem = 415, _body_problem(headers)
            if problem is None:
                status, problem = 403, _intent_problem(headers)
            if problem is not None:
                await JSONResponse({"detail": problem}, status_code=status)(scope, receive, send)
                return
        await self.app(scope, receive, send)


class SingleHost:
    """Pure ASGI middleware: 400 for a request with more than one ``Host`` header. Servers and proxies
    disagree on which one counts, so a request that carries two could be checked against one and
    routed by the other."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and sum(k == b"host" for k, _ in scope.get("headers") or ()) > 1:
            await JSONResponse({"detail": "more than one Host header"}, status_code=400)(scope, receive, send)
            return
        await self.app(scope, receive, send)


# ---------------------------------------------------------------------------------- JSON depth
def json_depth(body: bytes) -> int:
    """How deeply the arrays and objects of JSON text ``body`` nest, in linear time (no parsing, so no
    recursion): string contents are left out (escaped backslashes, then escaped quotes, then what lies
    between quotes), and the brackets that remain are counted: about a tenth of the time parsing the
    body takes (26 ms and 220 ms for a 1.7 MB frames body, measured on a loaded 2-core machine).

    >>> json_depth(b'{"t": [[1, 2]], "s": "[[[\\\\"[["}'), json_depth(b"1"), json_depth(b"[" * 5000)
    (3, 0, 5000)
    """
    if b"[" not in body and b"{" not in body:
        return 0
    if b"\\" in body:
        body = body.replace(b"\\\\", b"").replace(b'\\"', b"")
    if b'"' in body:
        body = b"".join(body.split(b'"')[0::2])
    a = np.frombuffer(body, dtype=np.uint8)
    opens = (a == ord("[")) | (a == ord("{"))
    at = np.flatnonzero(opens | (a == ord("]")) | (a == ord("}")))
    steps = np.where(opens[at], 1, -1)
    return int(np.cumsum(steps).max(initial=0))


# ---------------------------------------------------------------------------------- OpenAPI
def _security_of(spec: dict[str, Any], write: bool, reads: bool) -> None:
    components = spec.setdefault("components", {}).setdefault("schemas", {})
    if "ErrorOut" not in components:
        from service.api.errors import ErrorOut

        components["ErrorOut"] = ErrorOut.model_json_schema()
    for path, item in spec.get("paths", {}).items():
        for method, op in item.items():
            if not isinstance(op, dict) or method.upper() not in {"GET", "HEAD", *MUTATING_METHODS}:
                continue
            need = needs_token(method, path, write_token=write, reads_need_token=reads)
            op["security"] = [{BEARER_SCHEME: []}] if need else []
            if method.upper() not in MUTATING_METHODS:
                continue
            op.setdefault("responses", {})["403"] = {
                "description": "sent by another site (Origin, Sec-Fetch-Site), or without "
                f"'Content-Type: application/json' or '{INTENT_HEADER}: {INTENT_VALUE}'",
                "content": {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorOut"}}},
            }
            if "requestBody" not in op:
                op.setdefault("parameters", []).append(
                    {
                        "name": INTENT_HEADER,
                        "in": "header",
                        "required": True,
                        "description": "says the request comes from a client of this API, not from a "
                        "form or link of another site (a request with a JSON body need not send it)",
                        "schema": {"type": "string", "enum": [INTENT_VALUE]},
                    }
                )


def document_security(app: FastAPI, *, write_token: bool, reads_need_token: bool) -> None:
    """Make ``app``'s OpenAPI document say per operation what it needs (see the module doc): the bearer
    scheme where :func:`needs_token`, an empty ``security`` elsewhere, so a client (or a generated
    one, or a conformance test) knows which requests are refused without a token."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            spec = build()
            _security_of(spec, write_token, reads_need_token)
            app.openapi_schema = spec
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
