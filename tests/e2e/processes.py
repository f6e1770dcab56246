"""Command lines of the processes the end-to-end tests start: the service and the device emulators."""

from __future__ import annotations

import socket
import sys
from pathlib import Path

__all__ = ["emulator_command", "free_port", "serve_command"]


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
