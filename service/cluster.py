"""The connection to the Dask cluster the sensor-network retrains run on.

A retrain trains networks for tens of CPU seconds; inside the service process it competes with ingest
and the API for the interpreter. The service therefore hands it to Dask distributed
(:mod:`service.retrain.task`) and only collects the result. Two ways to have a cluster:

* **embedded** (default): a :class:`distributed.LocalCluster` of worker *processes* (one thread
  each: torch trains on one thread, :func:`bodyschema.threads.set_torch_threads`), ``workers`` of them
  (default: CPU count - 1, at least 1), no dashboard. Started on the first retrain, not with the
  service: startup never waits for it, and a service with ``network_interval_cycles`` 0 that is
  never asked for a retrain never starts one.
* **external**: ``scheduler`` names an existing scheduler (``tcp://host:port``); connected at start.

Connecting never blocks the caller: it happens on a background thread, retried every
``retry_seconds`` while it fails, and :attr:`TrainingCluster.fault` says why there is no client
(``/readyz`` reports it as a degraded reason). A client whose scheduler went away reconnects on its
own for ``connect_timeout`` seconds and then closes; :attr:`TrainingCluster.client` notices the closed
client and starts connecting again, so retrains resume when the scheduler is back.

Closing (at the service's stop) drops the retrains in flight: their windows are trained again after a
restart. An embedded cluster's workers are told to stop and given
:attr:`ClusterOptions.worker_stop_seconds` to end on their own, then killed: a worker in the middle of a
training step reads its stop message only when the step returns, which can take minutes, and Dask's
own close would wait 4 s for each before killing it.
"""

from __future__ import annotations

import logging
import os
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from service.log_config import child_log_env
from service.settings import Settings

if TYPE_CHECKING:
    from distributed import Client, Future, LocalCluster

__all__ = [
    "WORKER_LOGS",
    "WORKER_PRELOAD",
    "ClusterOptions",
    "TrainingCluster",
    "embedded_workers",
    "local_cluster",
    "stop_workers",
]

log = logging.getLogger(__name__)

#: The module every worker process of the embedded cluster imports as it starts
#: (:mod:`service.worker_preload`), named rather than imported: the service process itself never
#: trains, and need not load torch.
WORKER_PRELOAD = "service.worker_preload"

#: The preload that makes the embedded cluster's worker processes log as the service does
#: (:mod:`service.worker_logs`).
WORKER_LOGS = "service.worker_logs"


def embedded_workers(cpus: int | None = None) -> int:
    """Worker processes of the embedded cluster: every CPU but one (for ingest and the API), at least 1.

    >>> embedded_workers(8), embedded_workers(2), embedded_workers(1)
    (7, 1, 1)
    """
    n = cpus if cpus is not None else (os.cpu_count() or 1)
    return max(1, n - 1)


def local_cluster(workers: int) -> LocalCluster:
    """The embedded cluster: ``workers`` worker processes of one thread, each preloading the training
    code (:data:`WORKER_PRELOAD`) and the service's log format (:data:`WORKER_LOGS`), listening on
    loopback only, without a dashboard."""
    from distributed import LocalCluster

    return LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        preload=[WORKER_PRELOAD, WORKER_LOGS],
        env=child_log_env(),
        host="127.0.0.1",  # the scheduler and workers listen on loopback only
        # no dashboard; the scheduler's plain HTTP routes (health, metrics) on a free loopback port
        # rather than 8787, which another cluster on the machine may hold
        scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
    )


def stop_workers(cluster: LocalCluster, seconds: float) -> None:
    """Tell every worker of ``cluster`` to stop, and kill those still running after ``seconds``.

    Dask's nanny waits 80 % of its close timeout for the worker process before it kills it, then up to
    the whole timeout for the killed process to be reaped."""
    import asyncio

    nannies = list(cluster.workers.values())

    async def stop() -> None:
        await asyncio.gather(
            *(n.close(timeout=seconds / 0.8, reason="service-stop") for n in nannies), return_exceptions=True
        )

    if nannies:
        cluster.sync(stop)


@dataclass(frozen=True)
class ClusterOptions:
    """Where the retrains run: ``scheduler`` None starts an embedded cluster of ``workers`` processes.

    ``worker_stop_seconds``: how long an embedded worker is given to end on its own at a stop before it
    is killed. An idle worker ends within a few tenths of a second; one in a training step would not
    end before the step returns, and its retrain is dropped either way.
    """

    scheduler: str | None = None
    workers: int | None = None
    connect_timeout: float = 5.0
    retry_seconds: float = 2.0
    worker_stop_seconds: float = 1.0

    @classmethod
    def from_settings(cls, settings: Settings) -> ClusterOptions:
        return cls(
            scheduler=settings.dask_scheduler,
            workers=settings.dask_workers,
            connect_timeout=settings.dask_connect_timeout_seconds,
        )

    @property
    def where(self) -> str:
        """The cluster as a reason names it."""
        return f"Dask scheduler {self.scheduler}" if self.scheduler else "embedded Dask cluster"


class TrainingCluster:
    """A Dask client made on a background thread, remade when it is lost, closed with the service."""

    def __init__(self, options: ClusterOptions | None = None) -> None:
        self.options = options or ClusterOptions()
        self._client: Client | None = None
        self._cluster: LocalCluster | None = None
        self._fault: str | None = "not connected yet"
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------------------ state
    def start(self) -> None:
        """Begin connecting (or starting the embedded cluster) on a background thread; returns at once."""
        with self._lock:
            if self._closed.is_set() or (self._thread is not None and self._thread.is_alive()):
                return
            if self._client is not None:
                return
            if self._fault == "not connected yet":
                self._fault = "connecting"
            self._thread = threading.Thread(target=self._connect, name="bodyhealth-dask-connect", daemon=True)
            self._thread.start()

    @property
    def client(self) -> Client | None:
        """The connected client, or None (and connecting starts) while there is none."""
        with self._lock:
            c = self._client
            if c is not None and c.status in ("closed", "closing"):
                log.warning("lost the training cluster", extra={"cluster": self.options.where})
                self._client, c = None, None
                self._fault = "connection lost"
        if c is None:
            self.start()
        return c

    @property
    def fault(self) -> str | None:
        """Why no retrain can be submitted now (a sentence naming the cluster), None when one can."""
        with self._lock:
            c = self._client
            if c is not None:
                if c.status == "running":
                    return None
                return f"{self.options.where}: connection lost ({c.status})"
            if self._thread is None and self._fault == "not connected yet":
                return None  # an embedded cluster not needed yet is no fault
            return f"{self.options.where}: {self._fault}"

    def submit(self, fn: Any, *args: Any, key: str) -> Future | None:
        """``fn(*args)`` as the task named ``key`` (a key the scheduler already holds is that task, not a
        second one); None without a client (the caller keeps the work for later)."""
        c = self.client
        if c is None or c.status != "running":  # reconnecting: what it submits now would be cancelled
            return None
        return c.submit(fn, *args, key=key, pure=False, retries=0)

    def close(self) -> None:
        """Close the client, then the embedded cluster: its workers are told to stop and killed after
        ``worker_stop_seconds`` (retrains in flight are dropped); idempotent."""
        self._closed.set()
        thread = self._thread
        if thread is not None:
            # A start under way is waited for: Dask neither cuts a starting worker short nor lets the
            # process exit before it is up (its own exit hook closes the cluster then, killing busy
            # workers only after 4 s). The connecting thread sees the close and stops what it started.
            thread.join(self.options.connect_timeout + 60.0)
        with self._lock:
            client, cluster = self._client, self._cluster
            self._client = self._cluster = None
            self._fault = "closed"
        steps: list[Any] = []
        if client is not None:
            steps.append(client.close)
        if cluster is not None:
            steps += [lambda: stop_workers(cluster, self.options.worker_stop_seconds), cluster.close]
        for step in steps:
            try:
                step()
            except Exception:
                log.exception("closing the training cluster failed")

    # ------------------------------------------------------------------------- connecting
    def _connect(self) -> None:
        while not self._closed.is_set():
            try:
                client, cluster = self._open()
            except Exception as err:
                with self._lock:
                    self._fault = f"unreachable ({type(err).__name__}: {err})"
                log.warning(
                    "training cluster unreachable", extra={"cluster": self.options.where, "error": str(err)}
                )
                self._closed.wait(self.options.retry_seconds)
                continue
            with self._lock:
                if self._closed.is_set():
                    keep = False
                else:
                    keep = True
                    self._client, self._fault = client, None
                    if cluster is not None:
                        self._cluster = cluster
            if not keep:
                client.close()
                if cluster is not None:
                    stop_workers(cluster, self.options.worker_stop_seconds)
                    cluster.close()
            else:
                log.info("training cluster connected", extra={"cluster": self.options.where})
            return

    def _open(self) -> tuple[Client, LocalCluster | None]:
        from distributed import Client

        o = self.options
        if o.scheduler:
            return Client(o.scheduler, timeout=o.connect_timeout, set_as_default=False), None
        with self._lock:
            cluster = self._cluster
        if cluster is None or cluster.status.name == "closed":
            cluster = local_cluster(o.workers or embedded_workers())
            with self._lock:
                self._cluster = cluster
        try:
            return Client(cluster, timeout=o.connect_timeout, set_as_default=False), cluster
        except Exception:
            with self._lock:
                self._cluster = None
            cluster.close()
            raise
