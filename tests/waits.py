"""Limits for tests that wait on CPU-bound work: the seconds the work takes on an idle machine,
stretched by the share of a core a process gets now (with L runnable tasks on C cores, each gets
C/L of one), so a busy machine makes a test slower, never failing."""

from __future__ import annotations

import os

__all__ = ["cpu_bound"]


def cpu_bound(idle_seconds: float) -> float:
    """``idle_seconds`` stretched by the machine's current load average per core (at least 1x).

    >>> cpu_bound(10.0) >= 10.0
    True
    """
    return idle_seconds * max(1.0, os.getloadavg()[0] / (os.cpu_count() or 1))
