"""Window pins: frames a queued retrain will read are kept by retention until it has read them.

A retrain is submitted naming its window by robot, device clock epoch and end
(:mod:`service.retrain.task`); it may wait on the cluster for longer than the retention keeps frames,
above all when the robots' clocks run faster than the wall clock (a farm at ``--speed 10``). The
retrain's owner pins the window on submission and unpins it when the result is collected (or the task
failed or was cancelled); :meth:`service.store.retention.RetentionMixin.prune` keeps every chunk that
overlaps a pinned window.

Every pin expires ``ttl`` seconds of monotonic wall time after it was made, so a task whose future is
lost (its owner crashed between submit and collect) cannot keep frames forever; the owner derives the
bound from its settings (:class:`service.retrain.RetrainLimits`). Pins live in the process that
prunes (the service's ingest writer and the worker share one :class:`~service.store.Store`); they are
not stored in the database.

>>> now = [100.0]
>>> pins = WindowPins(clock=lambda: now[0])
>>> pins.pin("k", WindowPin("arm", 0, 10.0, 40.0), ttl=60.0)
>>> [p.robot for p in pins.active()]
['arm']
>>> now[0] = 160.0  # the bound passed: the pin lapses
>>> pins.active()
[]
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["WindowPin", "WindowPins"]


@dataclass(frozen=True)
class WindowPin:
    """The device-time span ``start < t <= end`` of ``robot``'s clock epoch ``epoch`` (a window)."""

    robot: str
    epoch: int
    start: float
    end: float


class WindowPins:
    """Pins by key (one per queued job), each with a wall-time expiry; thread-safe."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self._pins: dict[str, tuple[WindowPin, float]] = {}
        self._lock = threading.Lock()

    def pin(self, key: str, window: WindowPin, ttl: float) -> None:
        """Keep ``window`` for at most ``ttl`` seconds from now (again under a known key: renewed)."""
        if not ttl > 0:
            raise ValueError(f"a pin's ttl must be positive, got {ttl}")
        with self._lock:
            self._pins[key] = (window, self.clock() + float(ttl))

    def unpin(self, key: str) -> bool:
        """Release the pin ``key``; False when there was none (never pinned, or expired and dropped)."""
        with self._lock:
            return self._pins.pop(key, None) is not None

    def active(self) -> list[WindowPin]:
        """The pins not yet expired; expired ones are dropped."""
        now = self.clock()
        with self._lock:
            for key in [k for k, (_, until) in self._pins.items() if until <= now]:
                del self._pins[key]
            return [w for w, _ in self._pins.values()]

    def __len__(self) -> int:
        return len(self.active())
