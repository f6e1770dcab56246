"""The ingest writer's commit interval, on SQLite and PostgreSQL: while frames stream it commits at most
once per interval (big chunks, few page rewrites: docs/bench/writes.md), yet a batch pushed over the API
and a stopping pipeline never wait for the interval."""

from __future__ import annotations

import math
import time
from collections.abc import Iterable

import numpy as np

from service.frames import FrameBatch
from service.ingest.base import Source
from service.ingest.pipeline import Pipeline
from service.settings import Settings
from service.store import Store


def batch(robot: str, k: int, n: int = 5) -> FrameBatch:
    t = (k * n + np.arange(n)) / 100.0
    return FrameBatch(robot, t, ("j1",), np.zeros((n, 1)), ("imu0",), np.zeros((n, 1, 3)), np.ones((n, 1, 3)))


class Streaming(Source):
    """``count`` batches, one every ``period`` seconds of wall time (a robot streaming in real time)."""

    def __init__(self, count: int, period: float, robot: str = "arm") -> None:
        super().__init__(f"stream-{robot}")
        self.robot, self.count, self.period = robot, count, period
        self.sent = 0
        self.exhausted = False

    def _read_raw(self, timeout: float) -> Iterable[FrameBatch]:
        if self.sent >= self.count:
            self.exhausted = True
            return []
        time.sleep(self.period)
        self.sent += 1
        return [batch(self.robot, self.sent - 1)]


def settings(interval: float) -> Settings:
    return Settings(database_url="sqlite://", ingest_commit_interval_seconds=interval)


def test_writer_commits_at_most_once_per_interval_while_frames_stream(store: Store) -> None:
    src = Streaming(count=30, period=0.05)
    pipe = Pipeline(store, [src], settings=settings(0.5))
    t0 = time.monotonic()
    with pipe:
        assert pipe.wait_exhausted(timeout=60)
    elapsed = time.monotonic() - t0
    assert src.counters.as_dict()["stored"] == 150 and store.sample_count("arm") == 150
    # one commit for the first batch, then at most one per interval, and one for what stop drains
    txns = int(pipe.stats.extra["transactions"])
    assert 2 <= txns <= 2 + math.ceil(elapsed / 0.5), (txns, elapsed)


def test_without_an_interval_the_writer_commits_what_is_queued(store: Store) -> None:
    src = Streaming(count=30, period=0.05)
    pipe = Pipeline(store, [src], settings=settings(0.0))
    with pipe:
        assert pipe.wait_exhausted(timeout=60)
    # batches arrive 50 ms apart and a commit takes a few ms: most go alone
    assert int(pipe.stats.extra["transactions"]) >= 10
    assert store.sample_count("arm") == 150


def test_a_pushed_batch_and_a_stop_do_not_wait_for_the_interval(store: Store) -> None:
    src = Streaming(count=10_000, period=0.02)
    pipe = Pipeline(store, [src], settings=settings(60.0)).start()
    try:
        time.sleep(0.3)  # the writer has committed the first batch and lingers for the rest
        t0 = time.monotonic()
        assert pipe.submit(batch("pushed", 0), timeout=20.0) == 5
        assert time.monotonic() - t0 < 10.0
        assert store.sample_count("pushed") == 5
    finally:
        t0 = time.monotonic()
        pipe.stop()
        assert time.monotonic() - t0 < 10.0
    stored = src.counters.as_dict()["stored"]
    assert stored == 5 * src.sent and store.sample_count("arm") == stored
