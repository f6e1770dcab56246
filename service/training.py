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
   on the robot's newest window (named by its end and device clock epoch, :mod:`service.retrain_task`).

At most one retrain per (robot, method) is in flight; a want for one already in flight is answered by
that one. A job whose key (robot, method, epoch, window end) is the one stored last for that robot and
method is not submitted again: that window was learned already. While there is no client (scheduler
unreachable, embedded cluster still starting) wants wait, and nothing else is held up.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bodyschema.topology import Topology
from service.cluster import TrainingCluster
from service.metrics import Metrics
from service.retrain_task import RetrainJob, RetrainResult, job_key, run_retrain, shareable_url
from service.store import Store, UnknownRobot

if TYPE_CHECKING:
    from distributed import Future

__all__ = ["RemoteRetrains", "TrainingOptions"]

log = logging.getLogger(__name__)

#: The longest a cycle waits for a finished task's result to arrive from its worker.
FETCH_TIMEOUT_SECONDS = 5.0


@dataclass(frozen=True)
class TrainingOptions:
    """How the networks train on the cluster: ``seed``, and extra estimator keyword arguments as
    (name, value) pairs (e.g. ``(("epochs", 5),)``; none: train to convergence)."""

    seed: int = 0
    estimator_options: tuple[tuple[str, Any], ...] = ()
    #: start the sensor networks from the robot's stored weights (:mod:`service.store.weights`)
    warm_start: bool = True
    #: nice value of the training thread (:func:`service.retrain_task.lower_priority`; 0: as it is)
    nice: int = 0
    #: the training thread in Linux's idle scheduling class (:func:`service.retrain_task.lower_priority`)
    idle: bool = False


@dataclass(frozen=True)
class _InFlight:
    job: RetrainJob
    key: str
    future: Future


class RemoteRetrains:
    """The retrains of one worker on one :class:`~service.cluster.TrainingCluster` (module doc)."""

    def __init__(
        self,
        cluster: TrainingCluster,
        store: Store,
        window_seconds: float,
        options: TrainingOptions | None = None,
        metrics: Metrics | None = None,
        min_samples: int = 50,
    ) -> None:
        self.cluster = cluster
        self.store = store
        self.window_seconds = float(window_seconds)
        self.options = options or TrainingOptions()
        self.metrics = metrics or Metrics()
        self.min_samples = min_samples
        url = shareable_url(store.url)
        if url is None:
            raise ValueError("an in-memory database cannot be read by the cluster's worker processes")
        self.database_url = url
        self._wanted: set[tuple[str, str]] = set()
        self._in_flight: dict[tuple[str, str], _InFlight] = {}
        self._stored: dict[tuple[str, str], str] = {}
        #: The newest collected results (where and at what cost each ran), for logs and tests.
        self.results: deque[RetrainResult] = deque(maxlen=64)
        self._lock = threading.Lock()

    @property
    def fault(self) -> str | None:
        """Why retrains cannot run now, naming the cluster; None when they can."""
        return self.cluster.fault

    def want(self, robot: str, method: str) -> None:
        """Ask for a retrain of ``robot`` with ``method`` on its newest window."""
        with self._lock:
            self._wanted.add((robot, method))

    def in_flight(self) -> dict[tuple[str, str], str]:
        """(robot, method) → the key of the task in flight for it."""
        with self._lock:
            return {k: v.key for k, v in self._in_flight.items()}

    def wanted(self) -> set[tuple[str, str]]:
        with self._lock:
            return set(self._wanted)

    def submit_wanted(self) -> list[str]:
        """Submit every wanted retrain that can go now; returns the keys submitted."""
        submitted: list[str] = []
        for robot, method in sorted(self.wanted()):
            with self._lock:
                if (robot, method) in self._in_flight:
                    self._wanted.discard((robot, method))  # the one in flight answers it
                    continue
            job = self._job(robot, method)
            if job is None:
                continue  # no window yet: wait
            key = job_key(job)
            if self._stored.get((robot, method)) == key:
                with self._lock:
                    self._wanted.discard((robot, method))
                log.info("retrain skipped: window already learned", extra={"robot": robot, "method": method})
                continue
            future = self.cluster.submit(run_retrain, job, key=key)
            if future is None:
                return submitted  # no cluster now: everything waits
            with self._lock:
                self._wanted.discard((robot, method))
                self._in_flight[(robot, method)] = _InFlight(job, key, future)
            submitted.append(key)
            log.info("retrain submitted", extra={"robot": robot, "method": method, "key": key})
        self.metrics.retrains_in_flight.set(len(self._in_flight))
        return submitted

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
                    # and the cycle must not wait for that; the future stays in flight
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
            f.future.release()
        self.metrics.retrains_in_flight.set(len(self._in_flight))
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

    def _lag_hint(self, robot: str) -> float:
        """The lag of the robot's newest fast topology (s) when it lies more than half the lag search's
        range from zero, as the worker centres its own estimates (:meth:`service.worker.Worker._lag_hint`);
        else 0."""
        from bodyschema.fast import FastOptions
        from bodyschema.timing import lag_search_centre

        return lag_search_centre(self.store.last_lag(robot), FastOptions.max_lag)

    def _job(self, robot: str, method: str) -> RetrainJob | None:
        try:
            info = self.store.robot(robot)
        except UnknownRobot:
            info = None
        if info is None:
            with self._lock:
                self._wanted.discard((robot, method))
            return None
        if info.last_frame_t is None:
            return None
        base = self.store.baseline(robot) if self.options.warm_start else None
        return RetrainJob(
            lag_hint=self._lag_hint(robot),
            database_url=self.database_url,
            robot=robot,
            method=method,
            window_end=float(info.last_frame_t),
            window_seconds=self.window_seconds,
            epoch=int(info.epoch),
            seed=self.options.seed,
            options=self.options.estimator_options,
            min_samples=self.min_samples,
            baseline_id=base.id if base is not None else None,
            warm_start=self.options.warm_start,
            nice=self.options.nice,
            idle=self.options.idle,
        )
