"""Sensor-network retrains on the Dask cluster, as the monitoring worker drives them.

The worker never waits on a retrain. Each cycle it

1. **collects** the futures that finished since the last cycle (:meth:`RemoteRetrains.collect`): a
   result becomes one stored topology (wall time of collection, the job's window end) and, for the
   sensor networks, a new version of the robot's weights (:mod:`service.store.weights`), which the
   next retrain of the robot starts from while the baseline stays the same; a task that
   raised is logged and counted (``bodyhealth_retrain_failures_total{method}``); a task cancelled
   because the client lost its scheduler is wanted again, so it runs once the cluster is back;
2. marks the network methods the cycle asked for as **wanted** (:meth:`RemoteRetrains.want`);
3. **submits** what is wanted (:meth:`RemoteRetrains.submit_wanted`) as one task per robot and method,
   on the robot's newest window (named by its end and device clock epoch, :mod:`service.retrain.task`).

At most one retrain per (robot, method) is in flight; a want for one already in flight is answered by
that one. A job whose key (robot, method, epoch, window end) is the one stored last for that robot and
method is not submitted again: that window was learned already. While there is no client (scheduler
unreachable, embedded cluster still starting) wants wait, and nothing else is held up.

**Admission.** At most :meth:`RemoteRetrains.capacity` retrains are in flight (submitted: training
or queued on the cluster), by default twice the cluster's worker threads (:class:`RetrainLimits`).
The rest wait here, where they hold nothing: a waiting want names no window yet and takes the robot's
newest when it is admitted. Wants are admitted oldest first, round-robin over robots (a robot with
fewer retrains in flight goes first), so neither one robot's methods nor one client's many robots
starve the others. The retrain route asks :meth:`RemoteRetrains.admit` and answers 429 with the
expected wait (:meth:`RemoteRetrains.retry_after`) when the queue is full.

**Window pins.** A submitted job's window is pinned in the store (:mod:`service.store.pins`) from
submission until its result is collected, or it failed or was cancelled: retention keeps those frames
however long the job waits on the cluster, at any farm speed. A pin lapses after
``(capacity + 1) * max_wall_seconds`` (:meth:`RetrainLimits.pin_seconds`): the job waits behind at
most ``capacity - 1`` others on at least one thread, then trains, each within ``max_wall_seconds``;
the extra one covers the cycle that collects it. So a lost future pins nothing forever.

**Queue status.** :meth:`RemoteRetrains.queue_status` lists every retrain in flight or waiting, in
the order they are expected to run, with the expected wall seconds to finish from the recent wall
times of the same method (a list schedule over the cluster's threads, :func:`_schedule`).
"""

from __future__ import annotations

import heapq
import itertools
import logging
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bodyschema.timing import LagHint
from bodyschema.topology import Topology
from service.cluster import TrainingCluster, embedded_workers
from service.metrics import Metrics
from service.retrain.options import RetrainLimits, TrainingOptions
from service.retrain.task import RetrainJob, RetrainResult, job_key, run_retrain, shareable_url
from service.store import Store, UnknownRobot
from service.store.pins import WindowPin

if TYPE_CHECKING:
    from distributed import Future

__all__ = ["RemoteRetrains", "RetrainQueueEntry"]

log = logging.getLogger(__name__)

#: The longest a cycle waits for a finished task's result to arrive from its worker.
FETCH_TIMEOUT_SECONDS = 5.0

#: Wall seconds one retrain is assumed to take before any of its method finished here (the schedule
#: behind ``Retry-After`` needs a number): one robot's network retrain measured 107 CPU s on a busy
#: 2-core machine, rounded up.
ASSUMED_RETRAIN_SECONDS = 120.0

#: The least ``Retry-After`` of a full queue, s: the header's unit. A retrain past its expected wall
#: time is expected "now" by the schedule, but its slot is only free once a cycle collected it.
MIN_RETRY_SECONDS = 1.0

#: Recent wall times kept per method; their median is the expected wall time of the next one.
RECENT_WALLS = 16


@dataclass(frozen=True)
class RetrainQueueEntry:
    """One retrain in flight or waiting, as the status page shows it.

    ``state``: "running" (submitted and, by the cluster's first-in first-out order over its threads,
    training) or "waiting" (wanted, or submitted behind the training ones); ``position``: 0 runs
    first, the running ones before the rest; ``since``: wall time it was wanted (waiting) or submitted
    (in flight); ``expected_seconds``: wall seconds until it finishes, from the recent wall times of
    its method (None before one finished here); ``cpu_seconds``: CPU spent so far where known;
    ``window_end``: the device time its window ends (None until it is submitted: it takes the newest).
    """

    robot: str
    method: str
    state: str
    position: int
    since: float
    expected_seconds: float | None
    cpu_seconds: float | None
    window_end: float | None

    def to_json(self) -> dict[str, Any]:
        """The entry as plain JSON types (rounded to the millisecond)."""
        return {
            "robot": self.robot,
            "method": self.method,
            "state": self.state,
            "position": self.position,
            "since": self.since,
            "expected_seconds": None if self.expected_seconds is None else round(self.expected_seconds, 3),
            "cpu_seconds": None if self.cpu_seconds is None else round(self.cpu_seconds, 3),
            "window_end": self.window_end,
        }


@dataclass(frozen=True)
class _Want:
    seq: int
    since: float


@dataclass(frozen=True)
class _InFlight:
    job: RetrainJob
    key: str
    future: Future
    seq: int
    #: wall time (the retrains' clock) and monotonic time of submission
    since: float
    submitted: float


def _fair_order(
    waiting: dict[tuple[str, str], _Want], in_flight: Iterable[tuple[str, str]]
) -> list[tuple[str, str]]:
    """The order waiting wants are admitted in: repeatedly the oldest want of the robots with the fewest
    retrains in flight or admitted before it (round-robin over robots, oldest first within a round).

    >>> w = {("a", "m1"): _Want(0, 0.0), ("a", "m2"): _Want(1, 0.0), ("b", "m1"): _Want(2, 0.0)}
    >>> _fair_order(w, [])
    [('a', 'm1'), ('b', 'm1'), ('a', 'm2')]
    >>> _fair_order(w, [("a", "m3")])
    [('b', 'm1'), ('a', 'm1'), ('a', 'm2')]
    """
    count: dict[str, int] = {}
    for robot, _ in in_flight:
        count[robot] = count.get(robot, 0) + 1
    heap = [(count.get(k[0], 0), w.seq, k) for k, w in waiting.items()]
    heapq.heapify(heap)
    out: list[tuple[str, str]] = []
    while heap:
        n, seq, key = heapq.heappop(heap)
        now_n = count.get(key[0], 0)
        if now_n != n:  # the robot had one admitted since this was pushed: its round is later
            heapq.heappush(heap, (now_n, seq, key))
            continue
        out.append(key)
        count[key[0]] = now_n + 1
    return out


def _schedule(durations: list[float], elapsed: list[float], threads: int) -> list[float]:
    """Expected seconds from now until each retrain finishes when they run in this order on ``threads``
    threads, each taking ``durations[i]``; the first ones (as many as ``elapsed`` holds, at most
    ``threads``) are training since ``elapsed[i]`` seconds (a list schedule).

    >>> _schedule([10.0, 10.0, 10.0], [4.0], threads=2)
    [6.0, 10.0, 16.0]
    """
    free = [0.0] * max(1, threads)
    out: list[float] = []
    for i, d in enumerate(durations):
        start = heapq.heappop(free)
        end = max(d - elapsed[i], 0.0) if i < len(elapsed) else start + d
        heapq.heappush(free, end)
        out.append(end)
    return out


class RemoteRetrains:
    """The retrains of one worker on one :class:`~service.cluster.TrainingCluster` (module doc).

    ``clock`` is the wall clock of ``since`` in :meth:`queue_status`; waits are measured on the
    monotonic clock.
    """

    def __init__(
        self,
        cluster: TrainingCluster,
        store: Store,
        window_seconds: float,
        options: TrainingOptions | None = None,
        metrics: Metrics | None = None,
        min_samples: int = 50,
        *,
        limits: RetrainLimits | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.cluster = cluster
        self.store = store
        self.window_seconds = float(window_seconds)
        self.options = options or TrainingOptions()
        self.metrics = metrics or Metrics()
        self.min_samples = min_samples
        self.limits = limits or RetrainLimits()
        self.clock = clock
        url = shareable_url(store.url)
        if url is None:
            raise ValueError("an in-memory database cannot be read by the cluster's worker processes")
        self.database_url = url
        self._wanted: dict[tuple[str, str], _Want] = {}
        self._in_flight: dict[tuple[str, str], _InFlight] = {}
        self._stored: dict[tuple[str, str], str] = {}
        self._seq = itertools.count()
        #: worker threads of the cluster, as its scheduler last said (before that: the embedded count)
        o = cluster.options
        self._threads = 1 if o.scheduler else (o.workers or embedded_workers())
        self._walls: dict[str, deque[float]] = {}
        #: The newest collected results (where and at what cost each ran), for logs and tests.
        self.results: deque[RetrainResult] = deque(maxlen=64)
        self._lock = threading.Lock()

    @property
    def fault(self) -> str | None:
        """Why retrains cannot run now, naming the cluster; None when they can."""
        return self.cluster.fault

    # ------------------------------------------------------------------------------- wanting
    def want(self, robot: str, method: str) -> None:
        """Ask for a retrain of ``robot`` with ``method`` on its newest window (one in flight answers
        it; one already waiting keeps its place)."""
        with self._lock:
            self._want(robot, method)
        self._gauges()

    def _want(self, robot: str, method: str) -> None:
        key = (robot, method)
        if key not in self._in_flight and key not in self._wanted:
            self._wanted[key] = _Want(next(self._seq), self.clock())

    def admit(self, robot: str, method: str) -> float:
        """Take a retrain request: 0 when it is wanted now (or answered by one waiting or in flight),
        else the seconds until the queue has room for it (nothing is wanted then)."""
        with self._lock:
            key = (robot, method)
            if key in self._in_flight or key in self._wanted:
                return 0.0
            if len(self._in_flight) + len(self._wanted) >= self.capacity():
                return self._retry_after()
            self._want(robot, method)
        self._gauges()
        return 0.0

    def capacity(self) -> int:
        """Retrains in flight at most (:meth:`RetrainLimits.capacity` on the cluster's threads)."""
        return self.limits.capacity(self._threads)

    def retry_after(self) -> float:
        """Expected seconds until one more want fits in the queue (0: it fits now)."""
        with self._lock:
            if len(self._in_flight) + len(self._wanted) < self.capacity():
                return 0.0
            return self._retry_after()

    def _retry_after(self) -> float:
        """Seconds until a full queue has room: never under ``MIN_RETRY_SECONDS``, since a retrain that
        ran past its expected wall time, or finished but is not collected yet, still holds its slot."""
        ends = sorted(e for _, e in self._expected())
        excess = len(self._in_flight) + len(self._wanted) - self.capacity() + 1
        return max(ends[min(excess, len(ends)) - 1] if ends and excess > 0 else 0.0, MIN_RETRY_SECONDS)

    def in_flight(self) -> dict[tuple[str, str], str]:
        """(robot, method) → the key of the task in flight for it."""
        with self._lock:
            return {k: v.key for k, v in self._in_flight.items()}

    def wanted(self) -> set[tuple[str, str]]:
        with self._lock:
            return set(self._wanted)

    # ----------------------------------------------------------------------------- the queue
    def expected_wall(self, method: str) -> float | None:
        """The median wall seconds of the recent retrains of ``method`` here; None before the first."""
        with self._lock:
            walls = self._walls.get(method)
            return statistics.median(walls) if walls else None

    def _expected(self) -> list[tuple[tuple[str, str], float]]:
        """Every retrain in flight (submission order) then waiting (admission order), with the expected
        seconds until it finishes (:func:`_schedule`); called under the lock."""
        flying = sorted(self._in_flight.items(), key=lambda kv: kv[1].seq)
        order = [k for k, _ in flying] + _fair_order(self._wanted, self._in_flight)
        now = time.monotonic()
        running = flying[: max(1, self._threads)]
        elapsed = [0.0 if f.future.done() else now - f.submitted for _, f in running]
        durations = [
            0.0 if k in self._in_flight and self._in_flight[k].future.done() else self._wall(k[1])
            for k in order
        ]
        return list(zip(order, _schedule(durations, elapsed, self._threads), strict=True))

    def _wall(self, method: str) -> float:
        walls = self._walls.get(method)
        if walls:
            return statistics.median(walls)
        known = [statistics.median(w) for w in self._walls.values() if w]
        return max(known) if known else ASSUMED_RETRAIN_SECONDS

    def queue_status(self) -> list[RetrainQueueEntry]:
        """Every retrain in flight or waiting, in the order they run (:class:`RetrainQueueEntry`)."""
        with self._lock:
            expected = self._expected()
            out: list[RetrainQueueEntry] = []
            for pos, ((robot, method), seconds) in enumerate(expected):
                f = self._in_flight.get((robot, method))
                known = bool(self._walls.get(method)) or (f is not None and f.future.done())
                if f is not None:
                    state = "running" if pos < self._threads else "waiting"
                    since, end = f.since, f.job.window_end
                else:
                    state, since, end = "waiting", self._wanted[(robot, method)].since, None
                out.append(
                    RetrainQueueEntry(
                        robot=robot,
                        method=method,
                        state=state,
                        position=pos,
                        since=since,
                        expected_seconds=seconds if known else None,
                        cpu_seconds=None,  # the cluster reports a task's CPU with its result only
                        window_end=end,
                    )
                )
        return out

    def _gauges(self) -> None:
        with self._lock:
            flying, waiting = len(self._in_flight), len(self._wanted)
        self.metrics.retrains_in_flight.set(flying)
        self.metrics.retrains_waiting.set(waiting)

    # ---------------------------------------------------------------------------- submitting
    def submit_wanted(self) -> list[str]:
        """Submit wanted retrains, in the fair order, while the queue has room; returns the keys."""
        with self._lock:
            if not self._wanted:
                return []
        self._refresh_threads()
        with self._lock:
            order = _fair_order(self._wanted, self._in_flight)
        submitted: list[str] = []
        for robot, method in order:
            if len(self._in_flight) >= self.capacity():
                break
            job = self._job(robot, method)
            if job is None:
                continue  # no window yet: wait
            key = job_key(job)
            if self._stored.get((robot, method)) == key:
                with self._lock:
                    self._wanted.pop((robot, method), None)
                log.info("retrain skipped: window already learned", extra={"robot": robot, "method": method})
                continue
            if not self._submit(job, key):
                break  # no cluster now: everything waits
            submitted.append(key)
        self._gauges()
        return submitted

    def _submit(self, job: RetrainJob, key: str) -> bool:
        """Pin the job's window, then submit it; False (and unpinned) without a cluster."""
        pins = self.store.window_pins
        window = WindowPin(job.robot, job.epoch, job.window_end - job.window_seconds, job.window_end)
        pins.pin(key, window, ttl=self.limits.pin_seconds(self.capacity()))
        try:
            future = self.cluster.submit(run_retrain, job, key=key)
        except BaseException:
            pins.unpin(key)
            raise
        if future is None:
            pins.unpin(key)
            return False
        with self._lock:
            want = self._wanted.pop((job.robot, job.method), None)
            seq = want.seq if want is not None else next(self._seq)
            self._in_flight[(job.robot, job.method)] = _InFlight(
                job, key, future, seq=seq, since=self.clock(), submitted=time.monotonic()
            )
        log.info("retrain submitted", extra={"robot": job.robot, "method": job.method, "key": key})
        return True

    def _refresh_threads(self) -> None:
        """The cluster's worker threads, from its scheduler (kept as they were when it cannot say)."""
        client = self.cluster.client
        if client is None or client.status != "running":
            return
        try:
            n = int(client.scheduler_info(n_workers=0).get("total_threads") or 0)
        except Exception as err:  # the scheduler went away meanwhile: the next cycle asks again
            log.debug("cluster threads unknown: %s", err)
            return
        if n > 0:
            self._threads = n

    # ---------------------------------------------------------------------------- collecting
    def collect(self, clock: Callable[[], float]) -> list[RetrainResult]:
        """Store the results of finished tasks (stamped ``clock()``); returns them."""
        with self._lock:
            done = [(k, f) for k, f in self._in_flight.items() if f.future.done()]
            for k, _ in done:
                del self._in_flight[k]
        results: list[RetrainResult] = []
        for (robot, method), f in done:
            status = f.future.status
            if status == "finished":
                try:
                    # the result lives on a worker: if that worker died since, Dask computes it again,
                    # and the cycle must not wait for that; the future stays in flight (and pinned)
                    res = f.future.result(timeout=FETCH_TIMEOUT_SECONDS)
                except TimeoutError:
                    with self._lock:
                        self._in_flight[(robot, method)] = f
                    continue
                try:
                    self._store(res, clock())
                except Exception as err:
                    self._failed(robot, method, f.key, f"storing the result failed: {type(err).__name__}")
                else:
                    self._stored[(robot, method)] = f.key
                    with self._lock:
                        self._walls.setdefault(method, deque(maxlen=RECENT_WALLS)).append(res.wall_seconds)
                    results.append(res)
                    self.results.append(res)
            elif status == "cancelled":  # the client lost its scheduler: run it again when back
                self.want(robot, method)
                self._failed(robot, method, f.key, "cancelled (training cluster lost); resubmitted when back")
            else:
                try:
                    err = f.future.exception(timeout=FETCH_TIMEOUT_SECONDS)
                    why = f"{type(err).__name__}: {err}"
                except Exception as lost:  # the scheduler went away meanwhile
                    why = f"{status}; its error could not be fetched ({type(lost).__name__})"
                self._failed(robot, method, f.key, why)
            self.store.window_pins.unpin(f.key)
            f.future.release()
        self._gauges()
        return results

    def _store(self, res: RetrainResult, now: float) -> None:
        topo = Topology.from_json(res.topology)
        self.store.save_topology(res.robot, topo, now, res.window_end)
        version = None
        if res.weights is not None:
            version = self.store.save_network_weights(
                res.robot,
                res.method,
                res.weights,
                res.imus,
                res.joints,
                baseline_id=res.baseline_id,
                wall_time=now,
                window_end_t=res.window_end,
            )
        self.metrics.retrain_seconds.labels(method=res.method).observe(res.cpu_seconds)
        start = "warm" if res.warm_from is not None else "cold"
        self.metrics.retrains.labels(method=res.method, start=start).inc()
        log.info(
            "retrain stored",
            extra={
                "robot": res.robot,
                "method": res.method,
                "key": res.key,
                "cpu_seconds": round(res.cpu_seconds, 3),
                "wall_seconds": round(res.wall_seconds, 3),
                "epochs": res.epochs,
                "converged": res.converged,
                "warm_from": res.warm_from,
                "weights_version": version,
                "pid": res.pid,
                "host": res.host,
            },
        )

    def _failed(self, robot: str, method: str, key: str, why: str) -> None:
        self.metrics.retrain_failures.labels(method=method).inc()
        log.warning("retrain failed: %s", why, extra={"robot": robot, "method": method, "key": key})

    def _job(self, robot: str, method: str) -> RetrainJob | None:
        try:
            info = self.store.robot(robot)
        except UnknownRobot:
            info = None
        if info is None:
            with self._lock:
                self._wanted.pop((robot, method), None)
            return None
        if info.last_frame_t is None:
            return None
        base = self.store.baseline(robot) if self.options.warm_start else None
        return RetrainJob(
            # the search centred as the worker centres its own (bodyschema.timing.LagHint)
            lag_hint=LagHint.centre(self.store.last_lag(robot)).seconds,
            database_url=self.database_url,
            robot=robot,
            method=method,
            window_end=float(info.last_frame_t),
            window_seconds=self.window_seconds,
            epoch=int(info.epoch),
            network=self.options.network,
            imu_delay=self.options.imu_delay,
            min_samples=self.min_samples,
            baseline_id=base.id if base is not None else None,
            warm_start=self.options.warm_start,
            nice=self.options.nice,
            idle=self.options.idle,
            heldout_check=self.options.heldout_check is not False,  # None: the default, on
        )
