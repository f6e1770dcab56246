"""Ports for the servers the tests start on an address fixed in advance (a PostgreSQL cluster, a Dask
scheduler started again at the same address).

A port the system hands out (``bind(..., 0)``) comes from the ephemeral range, from which every
outgoing connection of the suite (the database clients, the HTTP clients, Dask's comms) takes its own
local port too: between the test closing the probe socket and its server binding the port, one of them
can take it ("address already in use"). Ports below that range are handed out to nobody, so one that
is free now stays free but for another test drawing the same number at random in the same seconds.
The service itself is started on port 0 and says which port it bound (tests/e2e/processes.py).

>>> p = free_port()
>>> 1024 < p < ephemeral_range()[0]
True
"""

from __future__ import annotations

import random
import socket
from pathlib import Path

__all__ = ["ephemeral_range", "free_port"]

#: The lowest port drawn from (below it: the well-known and often registered ones).
LOW = 20_000


def ephemeral_range() -> tuple[int, int]:
    """The system's range of ports for outgoing connections and ``bind(..., 0)`` (Linux's default
    where it cannot be read)."""
    try:
        lo, hi = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
        return int(lo), int(hi)
    except (OSError, ValueError):
        return 32768, 60999


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port on ``host`` that nothing listens on now, below the ephemeral range (module doc)."""
    top = ephemeral_range()[0]
    lo = LOW if top > LOW + 1000 else 1025
    rng = random.SystemRandom()
    for _ in range(200):
        port = rng.randrange(lo, top)
        with socket.socket() as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
            return port
    raise RuntimeError(f"no free port between {lo} and {top} on {host}")
