"""Waits of the tests: limits for CPU-bound work, the seconds the work takes on an idle machine
stretched by the share of a core a process gets now (with L runnable tasks on C cores, each gets
C/L of one), so a busy machine makes a test slower, never failing; and polling for a condition."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

__all__ = ["cpu_bound", "wait_until"]


def cpu_bound(idle_seconds: float) -> float:
    """``idle_seconds`` stretched by the machine's current load average per core (at least 1x).

    >>> cpu_bound(10.0) >= 10.0
    True
    """
    return idle_seconds * max(1.0, os.getloadavg()[0] / (os.cpu_count() or 1))


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
