"""Command lines of the processes the end-to-end tests start: the service and the device emulators."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["emulator_command", "free_port", "serve_command", "wait_answering"]


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def serve_command(port: int, database_url: str, *args: str) -> list[str]:
    """``bodyhealth serve`` on ``port`` with ``database_url`` and further ``args``."""
    return [
        sys.executable,
        "-m",
        "cli",
        "serve",
        "--port",
        str(port),
        "--database-url",
        database_url,
        *args,
    ]


def wait_answering(
    proc: subprocess.Popen[Any], client: Any, err: Path, path: str = "/livez", timeout: float = 60.0
) -> None:
    """Wait until ``client`` (an httpx client on the service) gets 200 from ``path``; fail with the tail
    of the service's stderr file ``err`` when the process died, or after ``timeout`` seconds."""
    import httpx

    deadline = time.monotonic() + timeout
    while True:
        assert proc.poll() is None, err.read_text()[-3000:]
        try:
            if client.get(path).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        assert time.monotonic() < deadline, f"{path} did not answer 200 within {timeout:g} s"
        time.sleep(0.2)


def emulator_command(kind: str, recording: Path, robot: str, config_out: Path) -> list[str]:
    """A CAN or serial device emulator replaying ``recording`` as fast as it can, then lingering."""
    return [
        sys.executable,
        "-m",
        "emulators",
        kind,
        "--recording",
        str(recording),
        "--robot",
        robot,
        "--speed",
        "0",
        "--linger",
        "120",
        "--config-out",
        str(config_out),
    ]


@contextmanager
def serve_in_thread(app: Any) -> Iterator[str]:
    """Serve the ASGI ``app`` with uvicorn on a free loopback port in a daemon thread; yields its base
    URL once the server has started, and stops it on exit (the browser tests need a real socket)."""
    import uvicorn

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_config=None, lifespan="off"))
    th = threading.Thread(target=server.run, daemon=True)
    th.start()
    deadline = time.monotonic() + 20
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        th.join(10)
