"""Structured log lines: one JSON object per line on stderr, so logs can be grepped and shipped as is.

Extra fields passed with ``extra={...}`` land as top-level keys. With ``json=False`` the lines are the
usual human format. Libraries that install handlers of their own (distributed when it is imported,
uvicorn when it starts) are taken back to the root handler, and Python warnings are logged, so that
every line of the service is in one format. The service's child processes (the embedded Dask cluster's
workers) log in the same format: :func:`child_log_env` is the environment that carries it, and
:func:`configure_child_logging` applies it in the child.

Example
-------
>>> import io, json, logging
>>> buf = io.StringIO()
>>> h = logging.StreamHandler(buf); h.setFormatter(JsonFormatter())
>>> log = logging.getLogger("demo"); log.addHandler(h); log.propagate = False
>>> log.warning("alert raised", extra={"robot": "ur5e-1", "kind": "imu_dead"})
>>> rec = json.loads(buf.getvalue())
>>> rec["msg"], rec["robot"], rec["level"]
('alert raised', 'ur5e-1', 'warning')
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from typing import Any

__all__ = ["CHILD_LOG_ENV", "JsonFormatter", "child_log_env", "configure_child_logging", "configure_logging"]

#: The environment variable that carries the service's log format to its child processes:
#: ``json:<level>`` or ``text:<level>`` (level as a number).
CHILD_LOG_ENV = "BODYHEALTH_CHILD_LOGS"

#: Loggers that get handlers of their own from their library (distributed's at import, uvicorn's at
#: start) and would otherwise print lines in that library's format beside ours.
ROUTED_LOGGERS: tuple[str, ...] = (
    "uvicorn",
    "uvicorn.error",
    "uvicorn.access",
    "distributed",
    "distributed.client",
    "distributed.gc",
    "tornado",
    "tornado.application",
    "bokeh",
    "py.warnings",
)

_configured: tuple[int, bool] | None = None

_STANDARD = set(vars(logging.LogRecord("", 0, "", 0, "", None, None))) | {"message", "asctime"}


class JsonFormatter(logging.Formatter):
    """``{"ts": ..., "level": ..., "logger": ..., "msg": ..., **extra}`` per record."""

    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "ts": round(record.created, 3),
            "time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
            + f".{int(record.msecs):03d}Z",
            "level": record.levelname.lower(),
            "logger": record.name,
            "msg": record.getMessage(),
        }
        for k, v in vars(record).items():
            if k not in _STANDARD and not k.startswith("_"):
                out[k] = v if isinstance(v, (str, int, float, bool, type(None), list, dict)) else str(v)
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


def configure_logging(level: int = logging.INFO, json_lines: bool = True) -> None:
    """Route the root logger (and uvicorn's, distributed's, warnings) to stderr in the chosen format;
    replaces earlier handlers."""
    global _configured
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(
        JsonFormatter() if json_lines else logging.Formatter("%(asctime)s %(levelname)s %(name)s %(message)s")
    )
    root = logging.getLogger()
    for h in list(root.handlers):
        root.removeHandler(h)
    root.addHandler(handler)
    root.setLevel(level)
    routed = set(ROUTED_LOGGERS) | {
        name for name in logging.root.manager.loggerDict if name.split(".")[0] in ("distributed", "uvicorn")
    }
    for name in sorted(routed):
        lg = logging.getLogger(name)
        lg.handlers = []
        lg.propagate = True
    logging.getLogger("uvicorn.access").setLevel(logging.WARNING)
    logging.captureWarnings(True)
    _configured = (level, json_lines)


def child_log_env() -> dict[str, str]:
    """The environment a child process needs to log as this one does (empty before
    :func:`configure_logging`: the child then keeps its libraries' defaults), e.g.
    ``{"BODYHEALTH_CHILD_LOGS": "json:20"}``."""
    if _configured is None:
        return {}
    level, json_lines = _configured
    return {CHILD_LOG_ENV: f"{'json' if json_lines else 'text'}:{level}"}


def configure_child_logging() -> bool:
    """In a child process: log as the parent that set :data:`CHILD_LOG_ENV` does; False when unset."""
    value = os.environ.get(CHILD_LOG_ENV, "")
    kind, _, level = value.partition(":")
    if kind not in ("json", "text"):
        return False
    configure_logging(int(level) if level.isdigit() else logging.INFO, json_lines=kind == "json")
    return True
