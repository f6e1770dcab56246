"""Prometheus metrics of one service instance.

Each :class:`Metrics` owns its own ``CollectorRegistry`` (not the process-global one), so several apps
in one test process do not collide. Frame counters are not incremented here: a collector reads them
from the ingest pipeline's :class:`~service.ingest.base.Counters` at scrape time, so the numbers on
``/metrics`` are exactly those the pipeline keeps. Transport-specific counters (CAN error frames,
serial CRC failures, reconnects, ...) summed over sources, and the store writer's own (transactions,
retries, write errors, pruned samples, and the samples dropped at a full queue (``dropped_queue_full``)
or after the write retries ran out (``dropped_write_failed``)) come out as
``bodyhealth_ingest_events_total{event=...}``; the queue between readers and the store writer as a
gauge, and whether the store writer's newest write failed as ``bodyhealth_store_write_failing`` (1/0).
Writes that waited over 100 ms for the store's write lock (:mod:`service.store.write_lock`) are counted
as ``bodyhealth_store_write_slow_waits_total``, with the longest wait as a gauge, and writes that held
it over 100 ms as ``bodyhealth_store_write_slow_holds_total``, with the longest hold, once
:meth:`Metrics.bind_write_lock` names the lock: a slow operator request is then visible on a dashboard
of the scrapes, not only in the log.

Example
-------
>>> from service.ingest.base import Counters
>>> c = Counters(); c.add("received", 7); c.add("error_frames", 2)
>>> m = Metrics(counters=lambda: {**c.as_dict(), "queue_depth": 3})
>>> m.retrain_seconds.labels(method="fast").observe(0.4)
>>> text = m.render().decode()
>>> "bodyhealth_frames_received_total 7.0" in text, "bodyhealth_retrain_seconds_count" in text
(True, True)
>>> 'bodyhealth_ingest_events_total{event="error_frames"} 2.0' in text
True
>>> "bodyhealth_ingest_queue_depth 3.0" in text
True
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Protocol

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    generate_latest,
)
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

__all__ = ["CONTENT_TYPE_LATEST", "Metrics"]

_FRAME_COUNTERS = ("received", "stored", "dropped", "malformed")
_QUEUE_DEPTH = "queue_depth"
_WRITE_FAILING = "write_failing"
_GAUGES = (_QUEUE_DEPTH, _WRITE_FAILING)


class _LockCounts(Protocol):
    """What the metrics read of the store's write lock (:class:`service.store.write_lock.WriteLock`)."""

    slow_waits: int
    longest_wait_s: float
    slow_holds: int
    longest_hold_s: float


class _WriteLockCollector(Collector):
    def __init__(self, lock: _LockCounts) -> None:
        self._lock = lock

    def collect(self) -> Iterator[CounterMetricFamily | GaugeMetricFamily]:
        yield CounterMetricFamily(
            "bodyhealth_store_write_slow_waits",
            "writes that waited longer than 100 ms for the store's write lock (the log names the holder)",
            value=float(self._lock.slow_waits),
        )
        yield GaugeMetricFamily(
            "bodyhealth_store_write_longest_wait_seconds",
            "the longest wait of a write for the store's write lock since the service started",
            value=float(self._lock.longest_wait_s),
        )
        yield CounterMetricFamily(
            "bodyhealth_store_write_slow_holds",
            "writes that held the store's write lock longer than 100 ms (the log says their commit's share)",
            value=float(self._lock.slow_holds),
        )
        yield GaugeMetricFamily(
            "bodyhealth_store_write_longest_hold_seconds",
            "the longest a write held the store's write lock since the service started",
            value=float(self._lock.longest_hold_s),
        )


class _FrameCollector(Collector):
    def __init__(self, read: Callable[[], dict[str, int]]) -> None:
        self._read = read

    def collect(self) -> Iterator[CounterMetricFamily | GaugeMetricFamily]:
        try:
            values = self._read() or {}
        except Exception:  # a scrape must never fail because the pipeline is shutting down
            values = {}
        for name in _FRAME_COUNTERS:
            yield CounterMetricFamily(
                f"bodyhealth_frames_{name}",
                f"frame samples {name} by the ingest pipeline",
                value=float(values.get(name, 0)),
            )
        events = CounterMetricFamily(
            "bodyhealth_ingest_events",
            "events counted by the ingest sources (summed over sources) and the store writer",
            labels=["event"],
        )
        for name, value in sorted(values.items()):
            if name not in _FRAME_COUNTERS and name not in _GAUGES:
                events.add_metric([name], float(value))
        yield events
        yield GaugeMetricFamily(
            "bodyhealth_ingest_queue_depth",
            "batches waiting between the transport readers and the store writer",
            value=float(values.get(_QUEUE_DEPTH, 0)),
        )
        yield GaugeMetricFamily(
            "bodyhealth_store_write_failing",
            "1 while the store writer's newest write failed (disk full, database gone, file replaced)",
            value=float(values.get(_WRITE_FAILING, 0)),
        )


class Metrics:
    """The service's metrics; ``counters`` returns the pipeline counters (received/stored/dropped)."""

    def __init__(self, counters: Callable[[], dict[str, int]] | None = None) -> None:
        self.registry = CollectorRegistry()
        self._counters = counters or dict
        self.registry.register(_FrameCollector(lambda: self._counters()))
        self.retrain_seconds = Histogram(
            "bodyhealth_retrain_seconds",
            "seconds one topology estimate took",
            ["method"],
            buckets=(0.05, 0.1, 0.25, 0.5, 1, 2, 5, 10, 30, 60, 120, 300),
            registry=self.registry,
        )
        self.retrain_failures = Counter(
            "bodyhealth_retrain_failures",
            "cluster retrains that raised, or were cancelled when the cluster was lost",
            ["method"],
            registry=self.registry,
        )
        self.retrains = Counter(
            "bodyhealth_retrains",
            "network retrains stored, by how their training started (warm: from the robot's stored "
            "weights; cold: from random ones)",
            ["method", "start"],
            registry=self.registry,
        )
        self.retrains_in_flight = Gauge(
            "bodyhealth_retrains_in_flight",
            "retrains submitted to the cluster, not yet collected",
            registry=self.registry,
        )
        self.retrains_waiting = Gauge(
            "bodyhealth_retrains_waiting",
            "retrains wanted, waiting for room in the training cluster's queue (max_retrains_queued)",
            registry=self.registry,
        )
        self.cycle_seconds = Histogram(
            "bodyhealth_worker_cycle_seconds",
            "seconds one worker cycle over all robots took",
            buckets=(0.1, 0.5, 1, 2, 5, 10, 30, 60),
            registry=self.registry,
        )
        self.cycles = Counter("bodyhealth_worker_cycles", "worker cycles run", registry=self.registry)
        self.cycle_errors = Counter(
            "bodyhealth_worker_errors", "robot cycles that failed", registry=self.registry
        )
        self.alerts_active = Gauge(
            "bodyhealth_alerts_active", "active (unresolved) alerts", ["robot"], registry=self.registry
        )
        self.robots = Gauge("bodyhealth_robots", "robots known to the store", registry=self.registry)

    def bind_counters(self, counters: Callable[[], dict[str, int]]) -> None:
        """Point the frame counters at a (new) pipeline."""
        self._counters = counters

    def bind_write_lock(self, lock: _LockCounts) -> None:
        """Report the store write lock's slow waits (once: a service has one store)."""
        self.registry.register(_WriteLockCollector(lock))

    def render(self) -> bytes:
        return generate_latest(self.registry)
