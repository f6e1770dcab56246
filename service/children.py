"""Child processes of the service: how they start and how they end with it.

The service starts children for CPU-bound work that must not hold its interpreter lock (the worker's
estimates, :mod:`service.estimation`; the simulated farm, :class:`service.ingest.farm.FarmProcess`).
They start with ``spawn``: the service has threads by then, which ``fork`` would copy half-way. A
SIGKILL of the service tells a child nothing (it is reparented and keeps running), so each child
watches its parent and ends within a poll of it going.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from multiprocessing.context import SpawnContext

__all__ = ["SPAWN", "exit_with_parent"]

#: The start method of every child of the service (module doc).
SPAWN: SpawnContext = multiprocessing.get_context("spawn")


def exit_with_parent(parent: int, poll: float = 1.0) -> None:
    """In a child: end the process (``os._exit(0)``) once ``parent`` is no longer its parent."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll)
        os._exit(0)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
