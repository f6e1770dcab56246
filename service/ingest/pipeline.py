"""The ingest pipeline: source threads -> one bounded queue -> one store writer thread.

Each :class:`~service.ingest.base.Source` gets its own reader thread calling ``read()``. Batches go on
one bounded queue: when the store falls behind, a full queue blocks the reader for at most
``put_timeout`` seconds (backpressure on the transport), after which the batch is dropped and counted
as ``dropped``. The writer thread takes whatever is queued (up to ``coalesce_max_samples``; while frames
stream, what arrives within ``commit_interval`` of its previous commit), writes it with
:meth:`Store.write_many` in one transaction, and counts ``stored``. A batch the store rejects is
counted ``malformed`` without losing the good batches written with it; a database that is briefly
unavailable is retried; nothing kills a thread. :meth:`Pipeline.stop` stops the readers, drains the
queue into the store and joins every thread.

Counters are per source (``source.counters``, in samples): ``received`` and ``malformed`` are kept by
the source's ``read()``, ``stored`` and ``dropped`` by the pipeline.

The store is the pipeline's alone: a source never touches it. When the pipeline starts, it registers
the robots a source declares simulated (:meth:`Source.simulated_robots`, the farm) and tells every
source the last stored frame of each robot (:meth:`Source.resume_after`: a replay resumes there). A
source may have an ``exhausted`` attribute (a finite source that has delivered everything; its reader
then ends).

The writer keeps the wall time of its last successful commit and of its last failed write (with the
reason), :meth:`Pipeline.write_health`: while the last attempt failed (disk full, database gone, the
SQLite file deleted) the service is not ready (``/readyz``), and the next successful commit makes it
ready again. The retention prune, every ``prune_interval`` seconds even when nothing arrives, also asks
the store whether its file is still the one it opened (:meth:`Store.storage_fault`), so a fault is
seen within one prune interval whether or not frames are flowing.

Frames pushed over the REST API take the same path: :meth:`Pipeline.submit` validates the batch,
queues it behind everything already read and waits for the writer's commit (counted under the
``api`` source). A pipeline that was never started writes the batch on the caller's thread through
the same commit step.

Run as a program it ingests sources into a database until they are exhausted or it is stopped::

    python -m service.ingest.pipeline --database-url sqlite:///var/x.db --commit-log var/commits.jsonl \\
        replay:data/run1.npz@max

Example
-------
>>> import numpy as np
>>> from service.ingest.base import Source
>>> from service.frames import FrameBatch
>>> from service.store import open_store
>>> class Three(Source):
...     exhausted = False
...     def _read_raw(self, timeout):
...         self.exhausted = True
...         return [FrameBatch("r", np.array([float(i)]), (), np.zeros((1, 0)), ("imu0",),
...                            np.zeros((1, 1, 3)), np.zeros((1, 1, 3))) for i in range(3)]
>>> store = open_store("sqlite://")
>>> src = Three("three")
>>> with Pipeline(store, [src]) as pipe:
...     pipe.wait_exhausted(timeout=10)
True
>>> src.counters.as_dict()
{'received': 3, 'stored': 3, 'dropped': 0, 'malformed': 0}
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from sqlalchemy.exc import SQLAlchemyError

from service.frames import FrameBatch, FrameError
from service.ingest.base import Counters, Source
from service.settings import Settings, get_settings, overridden
from service.store import RobotLimitReached, Store, open_store
from service.store.identity import DatabaseFileChanged

__all__ = [
    "CommitCallback",
    "CommitLog",
    "IngestUnavailable",
    "Pipeline",
    "PushSource",
    "WriteHealth",
    "main",
]

log = logging.getLogger(__name__)

#: Called by the writer after each commit with the batches that commit stored.
CommitCallback = Callable[[list[FrameBatch]], None]

_Item = tuple[Source, FrameBatch]


class IngestUnavailable(RuntimeError):
    """A submitted batch was not stored: the queue stayed full or the database stayed unavailable."""


class PushSource(Source):
    """Batches handed to :meth:`Pipeline.submit` (the REST API) rather than read from a transport. It
    has no reader thread: it exists for its name and counters."""

    def _read_raw(self, timeout: float) -> list[FrameBatch]:
        return []


@dataclass(frozen=True)
class WriteHealth:
    """The writer's last successful commit and last failure (wall times, ``time.time()``), so readiness
    can follow what actually happens to writes rather than whether a ``SELECT 1`` answers: a full disk
    or a read-only file answers pings and refuses every commit."""

    last_commit: float | None = None
    last_failure: float | None = None
    reason: str = ""

    @property
    def failing(self) -> bool:
        """True while the newest write attempt failed (nothing committed since)."""
        if self.last_failure is None:
            return False
        return self.last_commit is None or self.last_failure >= self.last_commit

    def as_dict(self, now: float | None = None) -> dict[str, object]:
        """Ages in seconds (None: never) and the reason, as ``/readyz`` shows them."""
        now = time.time() if now is None else now

        def age(t: float | None) -> float | None:
            return None if t is None else round(now - t, 3)

        return {
            "failing": self.failing,
            "last_commit_age_s": age(self.last_commit),
            "last_failure_age_s": age(self.last_failure),
            "reason": self.reason if self.failing else "",
        }


def _reason(err: BaseException) -> str:
    """One short line naming a database error: its class and the driver's first message line."""
    orig = getattr(err, "orig", None) or err
    text = (str(orig).strip().splitlines() or [""])[0]
    return f"{err.__class__.__name__}: {text}"[:300]


@dataclass
class _Waiter:
    """How a submitted batch ended: ``stored``, ``malformed`` (with the store's reason) or ``dropped``."""

    done: threading.Event = field(default_factory=threading.Event)
    outcome: str = ""
    reason: str = ""


class Pipeline:
    """Ingest ``sources`` into ``store`` on background threads (see the module docstring).

    Parameters default to the settings: ``queue_max_batches`` and ``put_timeout``
    (``queue_put_timeout_seconds``), ``commit_interval`` (``ingest_commit_interval_seconds``, the
    writer's linger, see :meth:`_gather`), ``prune_interval`` (``prune_interval_seconds``, wall time
    between retention prunes; 0 disables). ``write_retry_seconds`` bounds how long one commit is retried while
    the database is unavailable before its batches are dropped.
    """

    def __init__(
        self,
        store: Store,
        sources: Sequence[Source],
        *,
        settings: Settings | None = None,
        queue_max_batches: int | None = None,
        put_timeout: float | None = None,
        read_timeout: float = 0.1,
        coalesce_max_samples: int = 5000,
        commit_interval: float | None = None,
        prune_interval: float | None = None,
        write_retry_seconds: float = 10.0,
        on_commit: CommitCallback | None = None,
    ) -> None:
        s = settings or get_settings()
        self.store = store
        self.sources = list(sources)
        names = [src.name for src in self.sources]
        if len(set(names)) != len(names):
            raise ValueError(f"source names must be unique, got {names}")
        self.queue_max_batches = int(overridden(s, "queue_max_batches", queue_max_batches))
        self.put_timeout = float(s.queue_put_timeout_seconds if put_timeout is None else put_timeout)
        self.read_timeout = float(read_timeout)
        self.coalesce_max_samples = int(coalesce_max_samples)
        self.commit_interval = float(
            s.ingest_commit_interval_seconds if commit_interval is None else commit_interval
        )
        self._last_commit = -math.inf  # monotonic time the writer last took a transaction's batches
        self.prune_interval = float(s.prune_interval_seconds if prune_interval is None else prune_interval)
        self.write_retry_seconds = float(write_retry_seconds)
        self.on_commit = on_commit
        #: Pipeline-wide counts: ``transactions``, ``write_errors``, ``retries``, ``pruned``.
        self.stats = Counters()
        self._queue: queue.Queue[_Item] = queue.Queue(maxsize=self.queue_max_batches)
        self._stop = threading.Event()
        self._readers_done = threading.Event()
        self._readers: list[threading.Thread] = []
        self._writer: threading.Thread | None = None
        self._finished: set[str] = set()
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._pending = 0  # batches handed to the queue and not yet written (or dropped)
        #: Counters of the batches pushed through :meth:`submit`.
        self.push_source = PushSource("api")
        self._waiters: dict[int, _Waiter] = {}  # id(batch) -> its submitter, while in flight
        self._health = WriteHealth()
        self.max_joints = int(s.max_joints_per_robot)
        self.max_imus = int(s.max_imus_per_robot)
        #: robot -> (joints, IMUs) stored so far, as the writer saw them (read from the store once)
        self._parts: dict[str, tuple[frozenset[str], frozenset[str]]] = {}

    # ------------------------------------------------------------------------------ control
    def start(self) -> Pipeline:
        """Attach sources to the store and start the threads."""
        if self._writer is not None:
            raise RuntimeError("pipeline already started")
        self._prepare_sources()
        self._writer = threading.Thread(target=self._write_loop, name="ingest-writer", daemon=True)
        self._writer.start()
        for src in self.sources:
            th = threading.Thread(target=self._read_loop, args=(src,), name=f"ingest-{src.name}", daemon=True)
            self._readers.append(th)
            th.start()
        return self

    def _prepare_sources(self) -> None:
        """Register the robots the sources simulate; tell every source where the store ends."""
        for src in self.sources:
            for name, model in src.simulated_robots().items():
                try:
                    self.store.mark_simulated(name, model)
                except RobotLimitReached as err:  # its frames will be counted malformed, the rest runs
                    log.warning("source %s: %s", src.name, err)
        last = {r.name: r.last_frame_t for r in self.store.robots() if r.last_frame_t is not None}
        for src in self.sources:
            src.resume_after(last)

    def submit(self, batch: FrameBatch, timeout: float | None = None) -> int:
        """Store ``batch`` the way every source's batches are stored; returns the samples stored.

        Raises :class:`FrameError` for a batch that breaks the contract (nothing of it is stored) and
        :class:`IngestUnavailable` when it could not be stored in time (queue full, database down).
        Waits at most ``timeout`` seconds (default: the queue's put timeout plus the write retries).
        """
        src, n = self.push_source, batch.n_samples
        src.counters.add("received", n)
        try:
            batch.validate()
        except FrameError:
            src.counters.add("malformed", n)
            raise
        waiter = _Waiter()
        with self._lock:
            self._waiters[id(batch)] = waiter
        try:
            if self.running:
                self._put(src, batch)
                limit = self.put_timeout + self.write_retry_seconds + 5.0 if timeout is None else timeout
                if not waiter.done.wait(limit):
                    raise IngestUnavailable(f"batch not stored within {limit:.1f} s")
            else:
                self._commit([(src, batch)])
        finally:
            with self._lock:
                self._waiters.pop(id(batch), None)
        if waiter.outcome == "malformed":
            raise FrameError(waiter.reason or "rejected by the store")
        if waiter.outcome != "stored":
            raise IngestUnavailable(waiter.reason or "batch dropped")
        return n

    def _settle(self, items: list[_Item], outcome: str, reason: str = "") -> None:
        """Tell the submitters of ``items`` (if any) how their batches ended."""
        with self._lock:
            waiters = [self._waiters.get(id(b)) for _, b in items]
        for w in waiters:
            if w is not None and not w.done.is_set():
                w.outcome, w.reason = outcome, reason
                w.done.set()

    def stop(self, timeout: float = 30.0) -> None:
        """Stop reading, write everything already queued, join the threads (idempotent)."""
        self._stop.set()
        deadline = time.monotonic() + timeout
        for th in self._readers:
            th.join(max(deadline - time.monotonic(), 0.0))
        self._readers_done.set()
        if self._writer is not None:
            self._writer.join(max(deadline - time.monotonic(), 0.0))
            if self._writer.is_alive():
                log.error("ingest writer did not finish within %.1f s", timeout)

    @property
    def running(self) -> bool:
        return self._writer is not None and self._writer.is_alive() and not self._stop.is_set()

    def wait_exhausted(self, timeout: float | None = None) -> bool:
        """Wait until every source is exhausted and all its batches are written; False on timeout.
        (With an endless source, e.g. the farm, this only returns on timeout.)"""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._idle:
            while not (len(self._finished) == len(self.sources) and self._pending == 0):
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return False
                self._idle.wait(0.05 if left is None else min(left, 0.05))
        return True

    def counters(self) -> dict[str, dict[str, int]]:
        """Counters of each source by name (``api``: the batches pushed through :meth:`submit`, once
        there were any)."""
        out = {src.name: src.counters.as_dict() for src in self.sources}
        if self.push_source.counters.received:
            out[self.push_source.name] = self.push_source.counters.as_dict()
        return out

    def totals(self) -> dict[str, int]:
        """Counters summed over sources, plus the pipeline's own stats and the queue depth."""
        out: dict[str, int] = {}
        for c in self.counters().values():
            for k, v in c.items():
                out[k] = out.get(k, 0) + v
        out.update(self.stats.extra)
        out["queue_depth"] = self._queue.qsize()
        out["write_failing"] = int(self._health.failing)
        return out

    def write_health(self) -> WriteHealth:
        """When the writer last committed and last failed, and why (see :class:`WriteHealth`)."""
        return self._health

    def _record_commit(self) -> None:
        if self._health.failing:
            log.warning("ingest writer: writes succeed again (failing since: %s)", self._health.reason)
        self._health = WriteHealth(time.time(), self._health.last_failure, self._health.reason)

    def _record_failure(self, reason: str) -> None:
        if not self._health.failing:
            log.error("ingest writer: writes failing: %s", reason)
        self._health = WriteHealth(self._health.last_commit, time.time(), reason)

    def __enter__(self) -> Pipeline:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------------------ readers
    def _read_loop(self, src: Source) -> None:
        try:
            while not self._stop.is_set():
                if getattr(src, "exhausted", False):
                    break
                try:
                    batches = src.read(self.read_timeout)
                except Exception:  # a transport error must not end ingest for good
                    log.exception("source %s: read failed", src.name)
                    src.counters.add("read_errors")
                    self._stop.wait(0.5)
                    continue
                for b in batches:
                    self._put(src, b)
        finally:
            with self._idle:
                self._finished.add(src.name)
                self._idle.notify_all()

    def _put(self, src: Source, b: FrameBatch) -> None:
        with self._lock:
            self._pending += 1
        try:
            self._queue.put((src, b), timeout=self.put_timeout)
        except queue.Full:
            self._done(1)
            src.counters.add("dropped", b.n_samples)
            self.stats.add("dropped_queue_full", b.n_samples)
            self._settle([(src, b)], "dropped", f"ingest queue full for {self.put_timeout:.2f} s")
            log.warning(
                "source %s: queue full for %.2f s, dropped %d samples",
                src.name,
                self.put_timeout,
                b.n_samples,
            )

    # ------------------------------------------------------------------------------- writer
    def _write_loop(self) -> None:
        last_prune = time.monotonic()
        while True:
            try:
                first = self._queue.get(timeout=0.1)
            except queue.Empty:
                if self._readers_done.is_set():
                    break
                with self._idle:
                    self._idle.notify_all()
                if self.prune_interval > 0 and time.monotonic() - last_prune >= self.prune_interval:
                    self._prune()
                    last_prune = time.monotonic()
                continue
            items = self._gather(first)
            try:
                self._commit(items)
            except Exception as err:  # never let the writer die: count and go on
                log.exception("ingest writer: unexpected error; %d batches dropped", len(items))
                self._record_failure(_reason(err))
                for src, b in items:
                    src.counters.add("dropped", b.n_samples)
                self._settle(items, "dropped", "ingest writer error")
            finally:
                self._done(len(items))
            if self.prune_interval > 0 and time.monotonic() - last_prune >= self.prune_interval:
                self._prune()
                last_prune = time.monotonic()

    def _gather(self, first: _Item) -> list[_Item]:
        """``first`` and what else goes into its transaction: everything queued, up to
        ``coalesce_max_samples``, and, while frames stream, what arrives until ``commit_interval`` has
        passed since the previous commit. Each commit rewrites whole database pages (16 KiB on SQLite)
        and index entries, so a transaction of a few samples writes far more than it stores; lingering
        makes chunks big enough that the bytes written stay within 2x of the frames' own bytes
        (docs/bench/writes.md). A batch someone waits for (:meth:`submit`) and a stopping pipeline end
        the linger at once, and a lone batch after a quiet spell is committed at once."""
        items, n = [first], first[1].n_samples
        deadline = self._last_commit + self.commit_interval
        waited_for = id(first[1]) in self._waiters
        while n < self.coalesce_max_samples:
            left = deadline - time.monotonic()
            linger = left > 0 and not waited_for and not self._stop.is_set()
            try:
                # lingering polls, so a stop or a pushed batch ends it within 50 ms
                item = self._queue.get(timeout=min(left, 0.05)) if linger else self._queue.get_nowait()
            except queue.Empty:
                if linger:
                    continue
                break
            items.append(item)
            n += item[1].n_samples
            waited_for = waited_for or id(item[1]) in self._waiters
        self._last_commit = time.monotonic()
        return items

    def _done(self, n: int) -> None:
        with self._idle:
            self._pending -= n
            self._idle.notify_all()

    def _prune(self) -> None:
        """Drop frames past retention, and look at the store's file on the way: the one periodic
        check that runs while nothing is being written."""
        fault = self.store.storage_fault()
        if fault is not None:
            self._record_failure(fault)
            return
        try:
            self.stats.add("pruned", self.store.prune())
        except SQLAlchemyError as err:
            log.warning("retention prune failed: %s", _reason(err))
            self._record_failure(_reason(err))

    def _known_parts(self, robot: str) -> tuple[frozenset[str], frozenset[str]]:
        """The joints and IMUs ``robot`` has in the store (none for a new robot)."""
        got = self._parts.get(robot)
        if got is None:
            try:
                info = self.store.robot(robot)
            except SQLAlchemyError:  # the write that follows meets the same fault and is retried
                return frozenset(), frozenset()
            got = (frozenset(info.joints), frozenset(info.imus)) if info else (frozenset(), frozenset())
            self._parts[robot] = got
        return got

    def _within_part_caps(self, items: list[_Item]) -> list[_Item]:
        """``items`` without the batches that would give their robot more than ``max_joints_per_robot``
        joints or ``max_imus_per_robot`` IMUs (in the batch, or with the parts stored before it):
        those are rejected, counted malformed. Every part costs rows and estimator time forever, so
        a stream of made-up names must not grow a robot without limit."""
        kept: list[_Item] = []
        seen: dict[str, tuple[frozenset[str], frozenset[str]]] = {}
        for src, b in items:
            joints, imus = seen.get(b.robot) or self._known_parts(b.robot)
            joints, imus = joints | set(b.joint_names), imus | set(b.imu_names)
            over = [
                f"{len(parts)} {what} (at most {cap}, {setting})"
                for parts, what, cap, setting in (
                    (joints, "joints", self.max_joints, "max_joints_per_robot"),
                    (imus, "IMUs", self.max_imus, "max_imus_per_robot"),
                )
                if len(parts) > cap
            ]
            if over:
                self._reject(src, b, FrameError(f"robot {b.robot!r} would have {' and '.join(over)}"))
                continue
            seen[b.robot] = (joints, imus)
            kept.append((src, b))
        return kept

    def _commit(self, items: list[_Item]) -> None:
        items = self._within_part_caps(items)
        if not items:
            return
        try:
            stored = self._write_retrying(items)
        except FrameError as err:  # a lone batch is the bad one; else write one by one, keep the good
            stored = []
            if len(items) == 1:
                self._reject(*items[0], err)
            else:
                for src, b in items:
                    try:
                        stored.extend(self._write_retrying([(src, b)]))
                    except FrameError as bad:
                        self._reject(src, b, bad)
        for src, b in stored:
            src.counters.add("stored", b.n_samples)
            joints, imus = self._known_parts(b.robot)
            self._parts[b.robot] = (joints | set(b.joint_names), imus | set(b.imu_names))
        self._settle(stored, "stored")
        if stored and self.on_commit is not None:
            try:
                self.on_commit([b for _, b in stored])
            except Exception:
                log.exception("on_commit callback failed")

    def _reject(self, src: Source, batch: FrameBatch, err: FrameError) -> None:
        """Count a batch the store refused, then tell its submitter: in that order, so a count read
        right after the answer (POST /frames' 422) includes it."""
        log.warning("ingest writer: rejected batch from %s: %s", src.name, err)
        src.counters.add("malformed", batch.n_samples)
        self._settle([(src, batch)], "malformed", str(err))

    def _write_retrying(self, items: list[_Item]) -> list[_Item]:
        """Write in one transaction, retrying while the database is unavailable. Returns the items
        written, [] when the retries ran out (counted dropped); raises :class:`FrameError` when the
        store rejected a batch (nothing of the transaction is stored)."""
        deadline = time.monotonic() + self.write_retry_seconds
        delay = 0.05
        while True:
            try:
                self.store.write_many([b for _, b in items])
                self.stats.add("transactions")
                self._record_commit()
                return items
            except SQLAlchemyError as err:
                self.stats.add("write_errors")
                self._record_failure(_reason(err))
                # A swapped SQLite file stays swapped: retrying only holds up the queue and the shutdown.
                if isinstance(err, DatabaseFileChanged) or time.monotonic() + delay > deadline:
                    log.error(
                        "ingest writer: giving up on %d batches after %.1f s: %s",
                        len(items),
                        self.write_retry_seconds,
                        err,
                    )
                    for src, b in items:
                        src.counters.add("dropped", b.n_samples)
                        self.stats.add("dropped_write_failed", b.n_samples)
                    self._settle(items, "dropped", f"database unavailable: {err.__class__.__name__}")
                    return []
                log.warning(
                    "ingest writer: write failed (%s); retrying in %.2f s", err.__class__.__name__, delay
                )
                self.stats.add("retries")
                time.sleep(delay)
                delay = min(delay * 2, 1.0)


# ------------------------------------------------------------------------------------------ program
class CommitLog:
    """Appends one JSON line per commit: ``{"robot": .., "t_end": .., "samples": ..}`` per robot, with
    ``samples`` the running total stored for that robot by this process. Flushed after every line so a
    killed process leaves every line it reported."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = path.open("a", encoding="utf-8")
        self._totals: dict[str, int] = {}

    def __call__(self, batches: list[FrameBatch]) -> None:
        ends: dict[str, float] = {}
        for b in batches:
            self._totals[b.robot] = self._totals.get(b.robot, 0) + b.n_samples
            ends[b.robot] = max(ends.get(b.robot, float("-inf")), float(b.t[-1]))
        for robot, t_end in ends.items():
            self._fh.write(
                json.dumps({"robot": robot, "t_end": t_end, "samples": self._totals[robot]}) + "\n"
            )
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()


def main(argv: Sequence[str] | None = None) -> int:
    """Ingest the given source specs into a database until they are exhausted, SIGTERM or SIGINT."""
    from service.ingest.spec import open_source

    p = argparse.ArgumentParser(prog="python -m service.ingest.pipeline", description=main.__doc__)
    p.add_argument("specs", nargs="+", help="source specs, e.g. replay:PATH@SPEED or farm:ur5e@1")
    p.add_argument("--database-url", help="default: the settings' database_url")
    p.add_argument("--commit-log", type=Path, help="append one JSON line per commit here")
    p.add_argument("--seconds", type=float, default=None, help="stop after this many wall seconds")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s %(message)s")
    settings = get_settings()
    store = open_store(args.database_url or settings.database_url, settings=settings)  # a program, like serve
    sources = [open_source(spec, settings) for spec in args.specs]
    commit_log = CommitLog(args.commit_log) if args.commit_log else None
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    pipe = Pipeline(store, sources, settings=settings, on_commit=commit_log).start()
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    try:
        while not stop.is_set():
            if pipe.wait_exhausted(timeout=0.2):
                break
            if deadline is not None and time.monotonic() > deadline:
                break
    finally:
        pipe.stop()
        for src in sources:
            src.close()
        if commit_log is not None:
            commit_log.close()
        store.close()
    print(json.dumps(pipe.counters()), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
