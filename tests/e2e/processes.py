"""Command lines of the processes the end-to-end tests start: the service and the device emulators."""

from __future__ import annotations

import re
import select
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = [
    "announced_url",
    "emulator_command",
    "serve_command",
    "start_service",
    "wait_answering",
]


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


def announced_url(proc: subprocess.Popen[Any], err: Path, timeout: float = 90.0) -> str:
    """The base URL ``bodyhealth serve`` prints on stdout once its socket is bound (``proc`` must have
    ``stdout=PIPE``, text mode). Fails with the tail of ``err`` if the process ends first.

    Tests start the service on ``--port 0`` and read the port from here: a port picked by the test and
    handed over can be taken by any other process (an outgoing connection's ephemeral port, a parallel
    test) before the service binds it."""
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.5)
        if ready:
            line = proc.stdout.readline()
            m = re.search(r"(http://\S+?:\d+)/", line)
            assert m, f"service ended or printed no URL ({line!r}):\n{err.read_text()[-3000:]}"
            return m.group(1)
        assert proc.poll() is None, f"service died before binding:\n{err.read_text()[-3000:]}"
    raise AssertionError(f"service announced no URL within {timeout:g} s:\n{err.read_text()[-3000:]}")


def start_service(
    database_url: str, *args: str, err: Path, env: dict[str, str] | None = None, cwd: Path | None = None
) -> tuple[subprocess.Popen[str], str]:
    """``bodyhealth serve`` on a port the system picks, with ``database_url`` and ``args``; stderr goes
    to the file ``err``. Returns the process and its base URL once the socket is bound."""
    with err.open("w") as err_file:
        proc = subprocess.Popen(
            serve_command(0, database_url, *args),
            cwd=cwd,
            env=env,
            stdout=subprocess.PIPE,
            stderr=err_file,
            text=True,
        )
    try:
        return proc, announced_url(proc, err)
    except BaseException:
        proc.kill()
        proc.wait(30)
        raise


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

    config = uvicorn.Config(app, host="127.0.0.1", port=0, log_config=None, lifespan="off")
    sock = config.bind_socket()  # the system's free port, held from here on
    port = sock.getsockname()[1]
    server = uvicorn.Server(config)
    th = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    th.start()
    deadline = time.monotonic() + 20
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        th.join(10)
        sock.close()
