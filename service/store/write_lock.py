"""The store's write lock, which says who held it when another writer waited long.

Writers of one process queue on it (:meth:`service.store.schema.StoreBase._writing`): the next wakes
the moment the last commits, where SQLite's own busy handler would sleep in steps of up to 100 ms. An
operator's request that waits here waits behind a frame commit, a worker's write, a prune or a WAL
checkpoint; which one is what a slow approval needs explained. So a wait longer than ``slow_s`` is
logged (INFO, ``store write waited``) with the holder (its thread and the store method it was in) and
how long it had held the lock when the wait began, and counted (:attr:`WriteLock.slow_waits`,
:attr:`WriteLock.longest_wait_s`).

A writer that holds the lock longer than ``slow_s`` is logged too (INFO, ``store write held``), with
what tells its causes apart: how much of the hold was its commits (the store reports each,
:meth:`WriteLock.committed`), how much CPU its thread spent (little CPU in a long hold: it waited, for
the disk or for the interpreter lock), how much the whole process spent meanwhile (much: its other
threads had the interpreter; little: the machine ran other processes) and the size of the SQLite WAL
when it committed (SQLite runs a checkpoint inside the commit that finds the WAL past
``wal_autocheckpoint`` pages).

A unit of work that wants its own share (an API request: :mod:`service.api.timing`) sets
:data:`LOCK_TIMES` to a fresh ``[0.0, 0.0, 0.0]``; each outermost write in its context then adds the
seconds it waited for the lock, the seconds it held it and the seconds of those it spent committing.

Example
-------
>>> lock = WriteLock(slow_s=0.1)
>>> with lock:
...     with lock:  # re-entrant, as the store's methods nest
...         lock.holder is not None
True
>>> lock.holder is None, lock.slow_waits, lock.slow_holds
(True, 0, 0)
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
from contextvars import ContextVar
from types import FrameType, TracebackType

__all__ = ["LOCK_TIMES", "SLOW_WAIT_S", "WriteLock"]

log = logging.getLogger(__name__)

#: A wait for the write lock longer than this is logged with its holder: the approval latency target
#: is 200 ms, so a wait of half of it is worth naming.
SLOW_WAIT_S = 0.1

#: [seconds waited for the lock, seconds held, seconds of those committing] added up over the writes of
#: the context that set it (a list, so that the threads a request's context is copied into add to the
#: same one); None: not kept.
LOCK_TIMES: ContextVar[list[float] | None] = ContextVar("store_write_lock_times", default=None)

#: Frames of these names are the lock's own plumbing, not the writer to name.
_PLUMBING = frozenset({"_writing", "__enter__"})


def _writer(frame: FrameType | None) -> str:
    """The first function up the stack that is not the lock's plumbing (``contextlib``, ``_writing``)."""
    while frame is not None and (
        frame.f_code.co_name in _PLUMBING or frame.f_code.co_filename == contextlib.__file__
    ):
        frame = frame.f_back
    return "?" if frame is None else frame.f_code.co_qualname


class WriteLock:
    """A re-entrant lock that remembers its holder, and logs and counts waits and holds over ``slow_s``
    seconds."""

    def __init__(self, slow_s: float = SLOW_WAIT_S) -> None:
        self._lock = threading.RLock()
        self._depth = 0  # touched by the owner only
        self.slow_s = slow_s
        #: Who holds it now ("thread: method"), and since when (monotonic s); read without the lock,
        #: for the log only.
        self.holder: str | None = None
        self._since = 0.0
        # The hold now (owner only): its thread's and its process's CPU clocks when taken, its commits'
        # seconds, the largest WAL (bytes) a commit of it began with.
        self._cpu_since = self._process_cpu_since = 0.0
        self._commit_s = 0.0
        self._wal_bytes = 0
        self.slow_waits = 0
        self.longest_wait_s = 0.0
        self.slow_holds = 0
        self.longest_hold_s = 0.0

    def __enter__(self) -> WriteLock:
        if self._lock.acquire(blocking=False):
            self._taken(sys._getframe(1), 0.0)
            return self
        t0 = time.monotonic()
        holder, held = self.holder, t0 - self._since
        self._lock.acquire()
        waited = time.monotonic() - t0
        self._taken(sys._getframe(1), waited)
        self.longest_wait_s = max(self.longest_wait_s, waited)
        if waited > self.slow_s:
            self.slow_waits += 1
            log.info(
                "store write waited %.0f ms behind %s",
                1e3 * waited,
                holder,
                extra={
                    "writer": self.holder,
                    "waited_ms": round(1e3 * waited, 1),
                    "held_ms": round(1e3 * held, 1),
                },
            )
        return self

    def _taken(self, frame: FrameType, waited: float) -> None:
        if self._depth == 0:
            self.holder = f"{threading.current_thread().name}: {_writer(frame)}"
            self._since = time.monotonic()
            self._cpu_since, self._process_cpu_since = time.thread_time(), time.process_time()
            self._commit_s, self._wal_bytes = 0.0, 0
            times = LOCK_TIMES.get()
            if times is not None:
                times[0] += waited
        self._depth += 1

    def committed(self, seconds: float, wal_bytes: int = 0) -> None:
        """Called by the holder after each commit: how long it took and the WAL's size when it began."""
        self._commit_s += seconds
        self._wal_bytes = max(self._wal_bytes, wal_bytes)

    def __exit__(
        self, kind: type[BaseException] | None, err: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._depth -= 1
        if self._depth == 0:
            held = time.monotonic() - self._since
            times = LOCK_TIMES.get()
            if times is not None:
                times[1] += held
                times[2] += self._commit_s
            self.longest_hold_s = max(self.longest_hold_s, held)
            if held > self.slow_s:
                self._log_hold(held)
            self.holder = None
        self._lock.release()

    def _log_hold(self, held: float) -> None:
        self.slow_holds += 1
        cpu = time.thread_time() - self._cpu_since
        process_cpu = time.process_time() - self._process_cpu_since
        log.info(
            "store write held the lock %.0f ms in %s (commit %.0f ms, CPU %.0f ms, the process's %.0f ms)",
            1e3 * held,
            self.holder,
            1e3 * self._commit_s,
            1e3 * cpu,
            1e3 * process_cpu,
            extra={
                "writer": self.holder,
                "held_ms": round(1e3 * held, 1),
                "commit_ms": round(1e3 * self._commit_s, 1),
                "cpu_ms": round(1e3 * cpu, 1),
                "process_cpu_ms": round(1e3 * process_cpu, 1),
                "wal_bytes": self._wal_bytes,
            },
        )
