"""Every line the service logs is in its one format: distributed's and uvicorn's loggers and Python
warnings go through the root handler, and a child process configured from :func:`child_log_env` logs
as its parent. Run in fresh interpreters: configuring logging here would replace pytest's handlers."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from service.log_config import CHILD_LOG_ENV

_PARENT = """
import distributed, logging, warnings  # distributed installs its own text handler when imported
from service.log_config import child_log_env, configure_logging
configure_logging(logging.INFO, json_lines=True)
logging.getLogger("distributed.nanny").warning("worker still alive")
logging.getLogger("uvicorn.error").info("shutting down")
warnings.warn("a library warning")
print(child_log_env()["BODYHEALTH_CHILD_LOGS"])
"""

_CHILD = """
import distributed, logging
from service.worker_logs import dask_setup
dask_setup(None)
logging.getLogger("distributed.worker.state_machine").warning("task cancelled")
"""


def _run(code: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120, env=env
    )


def test_library_loggers_and_warnings_come_out_as_json() -> None:
    out = _run(_PARENT)
    records = [json.loads(line) for line in out.stderr.splitlines()]
    assert [(r["logger"], r["level"]) for r in records] == [
        ("distributed.nanny", "warning"),
        ("uvicorn.error", "info"),
        ("py.warnings", "warning"),
    ]
    assert out.stdout.strip() == "json:20"


def test_a_dask_worker_process_logs_as_the_service_says() -> None:
    env = {k: v for k, v in os.environ.items() if k != CHILD_LOG_ENV}
    out = _run(_CHILD, {**env, CHILD_LOG_ENV: "json:20"})
    (record,) = [json.loads(line) for line in out.stderr.splitlines()]
    assert (record["logger"], record["msg"]) == ("distributed.worker.state_machine", "task cancelled")
    text = _run(_CHILD, {**env, CHILD_LOG_ENV: "text:20"}).stderr.strip()
    assert not text.startswith("{") and "WARNING distributed.worker.state_machine task cancelled" in text
    # without the variable (a worker started by hand) distributed keeps its own format
    plain = _run(_CHILD, env).stderr.strip()
    assert " - distributed.worker.state_machine - WARNING - task cancelled" in plain
