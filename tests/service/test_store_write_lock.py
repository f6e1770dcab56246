"""The store's write lock names the writer a long wait was behind, so a slow request can be explained:
the waiting writer, the holder (thread and store method) and the count of slow waits."""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import pytest
from sqlalchemy import event

from service.store import open_store
from service.store.write_lock import WriteLock


class _Asking:
    """The lock's inner lock, which says when a writer starts to wait on it."""

    def __init__(self, inner: object) -> None:
        self.inner, self.waiting = inner, threading.Event()

    def acquire(self, blocking: bool = True) -> bool:
        if blocking:
            self.waiting.set()
        return self.inner.acquire(blocking)  # type: ignore[attr-defined]

    def release(self) -> None:
        self.inner.release()  # type: ignore[attr-defined]


def _hold_until(lock: WriteLock, held: threading.Event, release: threading.Event) -> None:
    with lock:
        held.set()
        release.wait(10)


def test_a_wait_is_logged_with_the_holder_and_the_writer(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    store = open_store(f"sqlite:///{tmp_path / 'lock.db'}")
    lock = store._write_lock
    assert isinstance(lock, WriteLock)
    lock.slow_s = 0.0  # every wait counts: the holder lets go only once the writer waits
    asking = _Asking(lock._lock)
    lock._lock = asking  # type: ignore[assignment]
    held = threading.Event()
    holder = threading.Thread(target=_hold_until, args=(lock, held, asking.waiting), name="ingest")
    holder.start()
    assert held.wait(10)
    assert lock.holder == "ingest: _hold_until"
    with caplog.at_level(logging.INFO, logger="service.store.write_lock"):
        store.mark_simulated("r", "ur5e")  # the writer's own nested takes count once
    holder.join(10)
    (rec,) = [r for r in caplog.records if r.msg.startswith("store write waited")]
    assert rec.getMessage().endswith("behind ingest: _hold_until")
    assert rec.writer.startswith("MainThread: ") and rec.writer.endswith("mark_simulated")
    assert rec.waited_ms > 0 and lock.slow_waits == 1 and lock.longest_wait_s > 0
    assert lock.holder is None and store.robot("r") is not None
    # an uncontended write is not a wait
    store.mark_simulated("r2", "ur5e")
    assert lock.slow_waits == 1
    store.close()


def test_the_slow_waits_are_on_the_metrics_of_the_service(tmp_path: Path) -> None:
    """``bodyhealth serve`` reports its store's slow write waits on ``/metrics``, counted as they are
    logged: a dashboard of the scrapes shows a slow approval's cause without the log."""
    from service.daemon import Daemon
    from service.metrics import Metrics
    from service.settings import Settings

    daemon = Daemon(Settings(database_url=f"sqlite:///{tmp_path / 'serve.db'}", dask_enabled=False))
    daemon.start()
    try:
        assert daemon.worker is not None and daemon.store is not None
        lock = daemon.store.write_lock
        lock.slow_waits, lock.longest_wait_s = 3, 0.25  # as three waits, the longest 250 ms, leave them
        lock.slow_holds, lock.longest_hold_s = 2, 0.5
        text = daemon.worker.metrics.render().decode()
    finally:
        daemon.stop()
    assert "bodyhealth_store_write_slow_waits_total 3.0" in text
    assert "bodyhealth_store_write_longest_wait_seconds 0.25" in text
    assert "bodyhealth_store_write_slow_holds_total 2.0" in text
    assert "bodyhealth_store_write_longest_hold_seconds 0.5" in text
    # a registry without a lock bound has neither
    assert "slow_waits" not in Metrics().render().decode()


#: How long the slowed commits below take at least.
COMMIT_S = 0.05


def test_a_long_hold_is_logged_with_its_commits_share_its_cpu_and_the_wal(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A write whose commit is slow (here: the commit sleeps, as one that waits for the disk) is logged
    once, with the commit's share of the hold, its thread's CPU (a sleep spends none) and the WAL's size
    when the commit began; a quick write is not."""
    store = open_store(f"sqlite:///{tmp_path / 'hold.db'}")
    lock = store.write_lock
    store.mark_simulated("r1", "ur5e")  # the WAL now holds a transaction
    assert lock.slow_holds == 0 and 0 < lock.longest_hold_s < lock.slow_s

    def slow_commit(_conn: object) -> None:
        time.sleep(COMMIT_S)

    lock.slow_s = COMMIT_S / 2
    event.listen(store.engine, "commit", slow_commit)
    with caplog.at_level(logging.INFO, logger="service.store.write_lock"):
        store.mark_simulated("r2", "ur5e")
    event.remove(store.engine, "commit", slow_commit)
    (rec,) = [r for r in caplog.records if r.msg.startswith("store write held")]
    assert rec.writer.startswith("MainThread: ") and rec.writer.endswith("mark_simulated")
    assert 1e3 * COMMIT_S <= rec.commit_ms <= rec.held_ms
    assert rec.cpu_ms < 1e3 * COMMIT_S  # the sleep took no CPU: a long hold that waited says so
    assert rec.process_cpu_ms >= rec.cpu_ms
    assert 0 < rec.wal_bytes < store.wal_bytes()  # its size when the commit began, which then grew it
    assert lock.slow_holds == 1 and lock.longest_hold_s >= COMMIT_S
    store.close()


def test_the_wal_is_copied_outside_the_write_lock_and_truncated_under_it(tmp_path: Path) -> None:
    """The checkpoint's copy and sync (a passive checkpoint) run without the write lock, so other
    writers go on meanwhile; only the truncation, left with the frames committed since, holds it."""
    store = open_store(f"sqlite:///{tmp_path / 'wal.db'}")
    for k in range(5):
        store.mark_simulated(f"r{k}", "ur5e")
    assert store.wal_bytes() > 0
    seen: list[tuple[str, bool]] = []
    checkpoint = store._checkpoint

    def spy(mode: str) -> int | None:
        seen.append((mode, store.write_lock.holder is not None))
        return checkpoint(mode)

    store._checkpoint = spy  # type: ignore[method-assign]
    assert store.truncate_wal() and store.wal_bytes() == 0 and store.wal_truncations == 1
    assert seen == [("PASSIVE", False), ("TRUNCATE", True)]
    assert [store.robot(f"r{k}") is not None for k in range(5)] == [True] * 5  # nothing lost
    store.close()
