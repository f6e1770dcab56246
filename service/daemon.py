"""The service process: REST API + dashboard (uvicorn), ingest pipeline and monitoring worker in one.

Start order: store (migrated) → pipeline (sources attached, reader and writer threads) → worker thread
(its estimates in a child process, :mod:`service.estimation`) → HTTP server in the main thread. The
training cluster (:mod:`service.cluster`) never delays the start: an external scheduler is connected on
a background thread, an embedded cluster is started there on the first retrain. SIGTERM or SIGINT stops
the server, then, side by side, the worker (after its current robot) and its estimating child, the
training cluster (an embedded one's worker processes end; retrains in flight are dropped) and the
pipeline (readers stop, everything already queued is written) with its sources; then the store is
closed, and the process exits 0. A SIGKILL loses at most the batches still queued: every committed
transaction is in the database (SQLite WAL or PostgreSQL), and a replay source resumes after the last
stored frame; the estimating child ends within a second of its parent.
"""

from __future__ import annotations

import logging
import signal
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from service.api import create_app
from service.cluster import ClusterOptions, TrainingCluster
from service.estimation import EstimatorProcess
from service.heap import freeze_startup_heap
from service.ingest.base import Source
from service.ingest.farm import FarmDamage, FarmSource
from service.ingest.pipeline import CommitLog, Pipeline
from service.metrics import Metrics
from service.retrain import RemoteRetrains, RetrainLimits, TrainingOptions, shareable_url
from service.settings import Settings
from service.store import Store
from service.worker import Estimator, Worker

__all__ = ["DEMO_ROBOTS", "Daemon", "demo_spec", "farm_damage", "switch_interval"]

log = logging.getLogger(__name__)

#: The catalog models ``serve --demo`` simulates.
DEMO_ROBOTS: tuple[str, ...] = ("ur5e", "paper-3", "quadruped")


def demo_spec(speed: float = 1.0) -> str:
    """The farm source spec of the demo at ``speed`` × real time.

    >>> demo_spec(10)
    'farm:ur5e,paper-3,quadruped@10'
    """
    return f"farm:{','.join(DEMO_ROBOTS)}@{speed:g}"


def farm_damage(sources: Sequence[Source]) -> FarmDamage | None:
    """The damage control over every farm source among ``sources`` (None when there is none)."""
    farms = [s for s in sources if isinstance(s, FarmSource)]
    return FarmDamage(farms) if farms else None


def _with_farm_filter_delay(settings: Settings, sources: Sequence[Source]) -> Settings:
    """``settings`` with ``imu_filter_delay_ms`` set from the farm's sensing model when the service
    runs the simulated farm and the delay is not stated: the farm's IMUs are known parts (with farms
    of different filters the delay stays unstated)."""
    delays = {x.farm.sensing.gyro_delay for x in sources if isinstance(x, FarmSource)}
    if settings.imu_filter_delay_ms is not None or len(delays) != 1:
        return settings
    return settings.model_copy(update={"imu_filter_delay_ms": 1e3 * delays.pop()})


@dataclass
class Daemon:
    """Everything one ``bodyhealth serve`` runs (see the module doc)."""

    settings: Settings
    specs: Sequence[str] = ()
    estimator: Estimator | None = None
    commit_log: Path | None = None
    training: TrainingOptions | None = None
    store: Store | None = field(default=None, init=False)
    cluster: TrainingCluster | None = field(default=None, init=False)
    pipeline: Pipeline | None = field(default=None, init=False)
    worker: Worker | None = field(default=None, init=False)
    sources: list[Source] = field(default_factory=list, init=False)
    _stop: threading.Event = field(default_factory=threading.Event, init=False)
    _commit_log: Any = field(default=None, init=False)
    _estimates: EstimatorProcess | None = field(default=None, init=False)

    def start(self) -> Any:
        """Open the store, start ingest and the worker; returns the ASGI app (not yet served)."""
        from service.ingest.spec import open_source

        s = self.settings
        _ensure_sqlite_dir(s.database_url)
        self.store = Store(s.database_url, settings=s)
        self.store.upgrade()  # the schema step of every start (a store never migrates on its own)
        self.sources = [open_source(spec, s) for spec in self.specs]
        s = self.settings = _with_farm_filter_delay(s, self.sources)
        metrics = Metrics()
        self._commit_log = CommitLog(self.commit_log) if self.commit_log else None
        self.pipeline = Pipeline(self.store, self.sources, settings=s, on_commit=self._commit_log)
        metrics.bind_counters(self.pipeline.totals)
        metrics.bind_write_lock(self.store.write_lock)
        self.pipeline.start()
        remote = self._remote_retrains(metrics)
        estimator = self.estimator
        if estimator is None:  # estimates off the API's interpreter lock (service.estimation)
            estimator = self._estimates = EstimatorProcess(s.imu_filter_delay, s.network_heldout_check)
        # the worker's other CPU-bound steps (the geometry's estimates above all: seconds of Python
        # per robot) go to the same child; in the worker thread they held the lock that every
        # request needs, and an operator's approval waited up to 0.4 s behind them
        compute = None if self._estimates is None else self._estimates.run
        self.worker = Worker(
            self.store, s, estimator=estimator, metrics=metrics, remote=remote, compute=compute
        )
        self.worker.start()
        app = create_app(
            self.store,
            settings=s,
            pipeline=self.pipeline,
            worker=self.worker,
            metrics=metrics,
            damage=farm_damage(self.sources),
        )
        frozen = freeze_startup_heap()  # before serving: see service.heap
        log.info(
            "service started",
            extra={"sources": list(self.specs), "database": repr(self.store), "frozen_objects": frozen},
        )
        return app

    def _remote_retrains(self, metrics: Metrics) -> RemoteRetrains | None:
        """The cluster retrains of the worker; None (they run in the worker thread) when the settings
        turn the cluster off or the database is in memory (no worker process could read it)."""
        s = self.settings
        assert self.store is not None
        if not s.dask_enabled:
            return None
        if shareable_url(self.store.url) is None:
            log.warning("in-memory database: the sensor networks train in the worker thread")
            return None
        self.cluster = TrainingCluster(ClusterOptions.from_settings(s))
        if s.dask_scheduler:
            self.cluster.start()  # an external scheduler: connect now, so /readyz can report it
        options = TrainingOptions.from_settings(s, self.training)
        limits = RetrainLimits.from_settings(s)
        return RemoteRetrains(
            self.cluster, self.store, s.window_seconds, options=options, metrics=metrics, limits=limits
        )

    def stop(self) -> None:
        """Stop worker, close the training cluster, drain the pipeline, close the store (idempotent).

        Three independent parts stop side by side, each waiting mostly on threads and processes: the
        worker (after its current robot) and its estimating child; the training cluster (retrains in
        flight are dropped); the pipeline (everything queued is written) and then its sources. The
        store is closed once all three are done. The seconds each part took are logged with ``service
        stopped`` (``steps``), so a slow stop says which part held it."""
        steps: dict[str, float] = {}
        parts = [
            ("worker", self._stop_worker),
            ("cluster", self._stop_cluster),
            ("ingest", self._stop_ingest),
        ]
        threads = [
            threading.Thread(target=_timed, args=(fn, name, steps), name=f"bodyhealth-stop-{name}")
            for name, fn in parts
        ]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        if self._commit_log is not None:
            self._commit_log.close()
            self._commit_log = None
        if self.store is not None:
            _timed(self.store.close, "store", steps)
        self.worker = self.pipeline = self.store = None
        log.info("service stopped", extra={"steps": steps})

    def _stop_worker(self) -> None:
        # The worker stops after its current robot; that robot's estimate is ended with the child
        # rather than waited for (seconds on a loaded machine), and the next start estimates afresh.
        if self.worker is not None:
            self.worker.request_stop()
        if self._estimates is not None:
            self._estimates.abort()
        if self.worker is not None:
            self.worker.stop()
        if self._estimates is not None:
            self._estimates.close()
            self._estimates = None

    def _stop_cluster(self) -> None:
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None

    def _stop_ingest(self) -> None:
        if self.pipeline is not None:
            self.pipeline.stop()
            log.info("ingest drained", extra={"counters": self.pipeline.totals()})
        for src in self.sources:
            try:
                src.close()
            except Exception:
                log.exception("closing source %s failed", src.name)

    def serve(self, announce: bool = True) -> int:
        """Run until SIGTERM/SIGINT; returns the exit code (0 on a clean stop)."""

        def on_signal(sig: int, frame: object) -> None:
            self._stop.set()

        # Our handler stays installed around uvicorn's own: uvicorn re-raises the signal it caught
        # after its shutdown, which then lands here instead of killing the process before the drain.
        previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
        code = 0
        with switch_interval(self.settings.interpreter_switch_ms):
            try:
                self._serve_http(announce)
            except SystemExit as err:  # uvicorn exits this way when it cannot bind the port
                code = int(err.code or 1)
            finally:
                t0 = time.monotonic()
                self.stop()
                log.info("shutdown took %.2f s", time.monotonic() - t0)
                for sig, h in previous.items():
                    signal.signal(sig, h)
        return code

    def _serve_http(self, announce: bool) -> None:
        """Start everything, then serve HTTP in this thread until the server stops."""
        import uvicorn

        app = self.start()
        config = uvicorn.Config(
            app,
            host=self.settings.host,
            port=self.settings.port,
            log_config=None,
            access_log=False,
            lifespan="off",
        )
        server = uvicorn.Server(config)
        # Bound here, before the address is announced, so that the announced port is the one held
        # (port 0: the system picks a free one, which a caller reads from the announcement, with
        # no window in which another process can take it).
        sock = config.bind_socket()
        if announce:
            host = "127.0.0.1" if self.settings.host in ("0.0.0.0", "::") else self.settings.host
            if ":" in host:
                host = f"[{host}]"
            print(
                f"bodyhealth: dashboard at http://{host}:{sock.getsockname()[1]}/  (API docs at /docs)",
                flush=True,
            )
        if not self._stop.is_set():
            server.run(sockets=[sock])
        sock.close()


@contextmanager
def switch_interval(ms: float) -> Iterator[None]:
    """Let a thread keep the interpreter at most ``ms`` while another waits for it, then restore the
    interval before. A request thread gives the interpreter up at every socket and database call and
    waits up to the interval to get it back while the farm, ingest and worker threads compute, so at
    Python's 5 ms a short request can spend most of its time waiting (docs/alert-latency.md).

    >>> import sys
    >>> with switch_interval(2.0):
    ...     round(sys.getswitchinterval(), 6)
    0.002
    """
    before = sys.getswitchinterval()
    sys.setswitchinterval(ms / 1e3)
    try:
        yield
    finally:
        sys.setswitchinterval(before)


def _timed(fn: Any, name: str, steps: dict[str, float]) -> None:
    """Run ``fn()`` and put the seconds it took under ``name`` in ``steps``; an error is logged, so one
    part that fails to stop does not keep the others from stopping."""
    t0 = time.monotonic()
    try:
        fn()
    except Exception:
        log.exception("stopping the %s failed", name)
    steps[name] = round(time.monotonic() - t0, 3)


def _ensure_sqlite_dir(url: str) -> None:
    """Create the folder of a relative or absolute SQLite file URL (``sqlite:///./var/x.db``)."""
    if url.startswith("sqlite:///") and not url.startswith("sqlite:///:memory:"):
        Path(url[len("sqlite:///") :].split("?", 1)[0]).parent.mkdir(parents=True, exist_ok=True)
