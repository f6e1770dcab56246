"""Error answers of the API: their bodies, the validation-error handler, and the ``responses=`` each
route declares so the OpenAPI document lists every status a client must handle.

Every error is ``{"detail": ...}``: a sentence, or for invalid input a list of ``{loc, msg, type}``
(where in the request, what is wrong, pydantic's error type). Nothing else is echoed back: not the
input (it may hold NaN, which JSON cannot carry, or a token) and not the code that found the problem.

A database that fails under a route (gone, restarting, disk full, its SQLite file deleted) is a 503
with a ``Retry-After`` header (:func:`database_unavailable`, registered for :data:`DATABASE_ERRORS`):
the client's request was fine and may succeed later, so it must not read as a bug (500). The body
names the error class and nothing of the SQL or its parameters.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.responses import Response

from service.store.identity import DatabaseFileChanged

__all__ = [
    "DATABASE_ERRORS",
    "RETRY_AFTER_SECONDS",
    "ErrorOut",
    "FieldError",
    "ValidationErrorOut",
    "database_unavailable",
    "invalid_request",
    "responses",
    "unparsable_body",
]

log = logging.getLogger(__name__)

#: Errors that say the database could not do its part right now (each gets :func:`database_unavailable`).
#: ``DBAPIError`` covers every driver error; the subclasses are listed so the intent reads here.
DATABASE_ERRORS: tuple[type[Exception], ...] = (
    OperationalError,
    InterfaceError,
    DBAPIError,
    PoolTimeout,
    DatabaseFileChanged,
)
#: ``Retry-After`` of a 503 for a database error: about the time a restarting database takes.
RETRY_AFTER_SECONDS = 5


class ErrorOut(BaseModel):
    detail: str = Field(description="what went wrong, in one sentence")


class FieldError(BaseModel):
    loc: list[str | int] = Field(description="where: 'path', 'query' or 'body', then the field")
    msg: str
    type: str = Field(description="error type, e.g. missing, string_pattern_mismatch, less_than_equal")


class ValidationErrorOut(BaseModel):
    detail: list[FieldError] | str = Field(
        description="the fields that are wrong, or a sentence when the frames break the recording contract"
    )


#: What each status means on this API, and the body it comes with.
_STATUS: dict[int, tuple[str, type[BaseModel]]] = {
    401: (
        "bearer token missing or wrong (only when tokens are configured); WWW-Authenticate: Bearer",
        ErrorOut,
    ),
    404: ("unknown robot or alert", ErrorOut),
    409: ("conflicts with the service's state", ErrorOut),
    413: ("request body larger than max_request_bytes", ErrorOut),
    415: ("request body not sent as application/json", ErrorOut),
    422: ("invalid path, query or body: field locations and messages", ValidationErrorOut),
    429: ("too many requests; Retry-After says in how many seconds one is accepted", ErrorOut),
    503: ("not available right now; retry later", ErrorOut),
}


def responses(*codes: int, **notes: str) -> dict[int | str, dict[str, Any]]:
    """``responses=`` for a route: each of ``codes`` with its meaning and body model. ``notes`` say
    what a status means on this route (``responses(404, 409, s409="no topology learned yet")``)."""
    out: dict[int | str, dict[str, Any]] = {}
    for code in codes:
        text, model = _STATUS[code]
        out[code] = {"description": notes.get(f"s{code}", text), "model": model}
    return out


async def invalid_request(request: Request, exc: Exception) -> JSONResponse:
    """422 naming each invalid field: location, message and error type only."""
    errors = exc.errors() if isinstance(exc, RequestValidationError) else []
    detail = [
        {"loc": list(e.get("loc", ())), "msg": str(e.get("msg", "")), "type": str(e.get("type", ""))}
        for e in errors
    ]
    return JSONResponse({"detail": detail}, status_code=422)


async def unparsable_body(request: Request, exc: Exception) -> Response:
    """A JSON body FastAPI could not even decode (not UTF-8, nested past the parser's depth) is a 422
    like every other malformed body, not FastAPI's undeclared 400, and says which of the two it was;
    other HTTP errors pass unchanged. (The app refuses bodies nested deeper than its own bound before
    they are parsed: :class:`service.api.BodySizeLimit`.)"""
    if (
        isinstance(exc, StarletteHTTPException)
        and exc.status_code == 400
        and isinstance(exc.__cause__, ValueError | RecursionError)
    ):
        msg = (
            "JSON nested too deeply to parse"
            if isinstance(exc.__cause__, RecursionError)
            else "body is not valid UTF-8"
        )
        detail = [{"loc": ["body"], "msg": msg, "type": "json_invalid"}]
        return JSONResponse({"detail": detail}, status_code=422)
    assert isinstance(exc, StarletteHTTPException)
    return await http_exception_handler(request, exc)


async def database_unavailable(request: Request, exc: Exception) -> JSONResponse:
    """503 with ``Retry-After`` for a database error under a route, logged once per request at WARNING
    (the error class and the driver's first line; the readiness probe carries the lasting state)."""
    orig = getattr(exc, "orig", None) or exc
    first = (str(orig).strip().splitlines() or [""])[0]
    where = f"{request.method} {request.url.path}"
    log.warning("%s: database error %s: %s", where, type(exc).__name__, first)
    detail = f"database unavailable ({type(exc).__name__}); retry later"
    return JSONResponse(
        {"detail": detail}, status_code=503, headers={"Retry-After": str(RETRY_AFTER_SECONDS)}
    )
