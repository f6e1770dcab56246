"""Waits of the tests: limits for CPU-bound work, the seconds the work takes on an idle machine
stretched by the share of a core a process gets now (with L runnable tasks on C cores, each gets
C/L of one), so a busy machine makes a test slower, never failing; the same for a niced thread, whose
share is smaller by its scheduler weight; and polling for a condition."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

__all__ = ["cpu_bound", "niced_bound", "wait_until"]


def cpu_bound(idle_seconds: float) -> float:
    """``idle_seconds`` stretched by the machine's current load average per core (at least 1x).

    >>> cpu_bound(10.0) >= 10.0
    True
    """
    return idle_seconds * max(1.0, _load_per_core())


def niced_bound(idle_seconds: float, nice: int) -> float:
    """``idle_seconds`` of work on a thread at ``nice``, stretched by the load as Linux shares a core.

    The scheduler (CFS) shares a core in proportion to weights: 1024 at nice 0, about 1.25 times less
    per step (110 at nice 10). Beside ``l`` runnable tasks of nice 0 per core (the load average per
    core), a thread at ``nice`` gets ``w/(w + 1024 l)`` of a core, so its work takes ``1 + 1024 l/w``
    times as long as on an idle machine: about 28x at load 3 per core and nice 10, where a nice-0
    process gets a third.

    >>> round(niced_bound(1.0, 0) / cpu_bound(1.0), 6) >= 1.0
    True
    """
    return idle_seconds * (1.0 + _load_per_core() * 1.25**nice)


def _load_per_core() -> float:
    """The one-minute load average per core: runnable tasks sharing each core."""
    return os.getloadavg()[0] / (os.cpu_count() or 1)


def wait_until(cond: Callable[[], Any], timeout: float, what: str, every: float = 0.05) -> Any:
    """Poll ``cond`` until it is truthy; its value, or an AssertionError naming ``what``."""
    deadline = time.monotonic() + timeout
    while True:
        got = cond()
        if got:
            return got
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.1f} s waiting for {what}")
        time.sleep(every)
