"""Storage faults under a running app: a full disk, the SQLite file deleted or replaced, a database that
stops answering, PostgreSQL going away and coming back. Real stores, a running ingest pipeline and the
real app (``create_app``); nothing is mocked.

The full disk is a real one where the test may mount a small tmpfs (root); elsewhere SQLite's
``max_page_count`` pragma is the fault-injection layer at the file-system boundary: past the limit
SQLite fails every write with the same ``database or disk is full`` (SQLITE_FULL) a full disk gives,
and raising the limit is freeing space. PostgreSQL faults run on a server of the test's own
(the ``pg_cluster`` fixture, :class:`~tests.service.faults.PgCluster`: initdb in a temp dir on a free
port), never the shared one.
"""

from __future__ import annotations

import logging
import os
import shutil
import sqlite3
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.ingest.pipeline import Pipeline
from service.metrics import Metrics
from service.settings import Settings
from service.store import Store, open_store
from tests.ports import free_port
from tests.service.faults import PRUNE, Committed, PgCluster, SmallDisk, TickSource
from tests.waits import wait_until


def settings_for(url: str) -> Settings:
    return Settings(database_url=url, prune_interval_seconds=PRUNE, worker_interval_seconds=1)


def ready(client: TestClient) -> tuple[int, dict[str, Any]]:
    r = client.get("/readyz")
    return r.status_code, r.json()


def beat(store: Store) -> None:
    """The worker's heartbeat (these apps run no worker): readiness then depends on storage only."""
    store.heartbeat("worker", time.time())


# --------------------------------------------------------------------------------- a full disk
def test_disk_full_turns_readyz_503_loses_nothing_and_recovers(small_disk: SmallDisk) -> None:
    url = f"sqlite:///{small_disk.dir / 'store.db'}"
    store = open_store(url)
    small_disk.attach(store)
    committed = Committed()
    src = TickSource(period=0.05)
    pipe = Pipeline(
        store, [src], settings=settings_for(url), write_retry_seconds=0.5, put_timeout=0.05,
        queue_max_batches=50, on_commit=committed,
    )  # fmt: skip
    app = create_app(store, settings=settings_for(url), pipeline=pipe, metrics=Metrics(counters=pipe.totals))
    client = TestClient(app)
    beat(store)
    with pipe:
        wait_until(lambda: len(committed.t) >= 5, 10, "first commits")
        assert ready(client)[0] == 200
        small_disk.fill()
        t_full = time.monotonic()
        # within one prune interval (plus the source's next batch and some scheduling slack)
        _, body = wait_until(lambda: (r := ready(client))[0] == 503 and r, PRUNE + 0.5, "readyz 503")
        # the writer saw the full disk; readiness followed it at once, well within one prune interval
        failed_at = pipe.write_health().last_failure
        assert failed_at is not None and time.time() - failed_at < 10
        assert "database or disk is full" in body["reason"] and body["reasons"][0].startswith(
            "writes failing"
        )
        assert body["checks"]["writes"]["failing"] is True and body["checks"]["database"] is True
        print(f"disk full -> 503 after {time.monotonic() - t_full:.2f} s (mounted={small_disk.mounted})")
        metrics = client.get("/metrics").text
        assert "bodyhealth_store_write_failing 1.0" in metrics
        stuck = pipe.counters()["tick"]["stored"]
        time.sleep(1.0)  # the source goes on; nothing gets in
        assert pipe.counters()["tick"]["stored"] == stuck
        assert ready(client)[0] == 503
        small_disk.free()
        t_free = time.monotonic()
        wait_until(lambda: ready(client)[0] == 200, 2 * PRUNE + 5, "readyz 200 after space was freed")
        print(f"space freed -> 200 after {time.monotonic() - t_free:.2f} s")
        wait_until(lambda: pipe.counters()["tick"]["stored"] > stuck + 500, 10, "frames stored again")
    c = pipe.counters()["tick"]
    assert c["received"] == c["stored"] + c["dropped"] and c["dropped"] > 0
    assert "bodyhealth_store_write_failing 0.0" in client.get("/metrics").text
    store.close()
    # nothing committed is lost: every stamp reported committed reads back, and nothing else
    with sqlite3.connect(small_disk.dir / "store.db") as conn:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    with open_store(url) as again:
        got = again.read_between("arm", -np.inf, np.inf)
        assert got is not None and got.n_samples == c["stored"] == committed.stamps().size
        np.testing.assert_array_equal(got.t, np.sort(committed.stamps()))


# --------------------------------------------------------------------- the SQLite file swapped
@pytest.mark.parametrize("how", ["deleted", "replaced"])
def test_sqlite_file_deleted_or_replaced_is_reported_and_not_written(
    how: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "store.db"
    url = f"sqlite:///{path}"
    store = open_store(url)
    src = TickSource(n=10, period=0.05)
    pipe = Pipeline(store, [src], settings=settings_for(url), write_retry_seconds=0.3, put_timeout=0.05)
    client = TestClient(create_app(store, settings=settings_for(url), pipeline=pipe))
    beat(store)
    caplog.set_level(logging.ERROR)
    with pipe:
        wait_until(lambda: pipe.counters()["tick"]["stored"] >= 50, 10, "first commits")
        assert ready(client)[0] == 200
        if how == "deleted":
            path.unlink()
        else:
            shutil.copy(path, tmp_path / "copy.db")
            os.replace(tmp_path / "copy.db", path)
        t0 = time.monotonic()
        # found by the writer itself (its writes and its prune), without a readiness probe asking
        wait_until(lambda: pipe.write_health().failing, PRUNE + 1.0, "the writer to see the fault")
        assert time.monotonic() - t0 <= PRUNE + 1.0
        code, body = ready(client)
        assert code == 503 and f"was {how}" in body["reason"] and str(path) in body["reason"]
        assert body["checks"]["storage_fault"] == body["reasons"][0]
        stuck = pipe.counters()["tick"]["stored"]
        time.sleep(3 * 0.05 + PRUNE)
        assert pipe.counters()["tick"]["stored"] == stuck  # nothing more goes to the orphaned inode
        r = client.get("/api/v1/robots")
        assert r.status_code == 503 and r.headers["Retry-After"] == "5"
        assert r.json() == {"detail": "database unavailable (DatabaseFileChanged); retry later"}
    errors = [r for r in caplog.records if r.levelno == logging.ERROR and "storage fault" in r.getMessage()]
    assert len(errors) == 1 and f"was {how}" in errors[0].getMessage()
    assert path.exists() == (how == "replaced")  # a deleted file is not silently recreated empty
    store.close()


# ------------------------------------------------------------------- database errors in routes
def test_database_errors_in_routes_are_503_with_retry_after(caplog: pytest.LogCaptureFixture) -> None:
    url = f"postgresql+psycopg://postgres@127.0.0.1:{free_port()}/nothing"  # nothing listens there
    store = Store(url, engine_kwargs={"connect_args": {"connect_timeout": 2}})
    client = TestClient(create_app(store, settings=settings_for(url)), raise_server_exceptions=False)
    for path in ("/api/v1/robots", "/api/v1/alerts", "/api/v1/robots/arm", "/api/v1/robots/arm/status"):
        r = client.get(path)
        assert r.status_code == 503, (path, r.status_code, r.text)
        assert r.headers["Retry-After"] == "5" and r.headers["content-type"] == "application/json"
        assert r.json() == {"detail": "database unavailable (OperationalError); retry later"}
    r = client.post("/api/v1/alerts/1/ack", json={})
    assert r.status_code == 503 and r.headers["Retry-After"] == "5"
    code, body = ready(client)
    assert code == 503 and body["reasons"] == ["database unreachable"] and body["checks"]["database"] is False
    assert any("database error OperationalError" in r.getMessage() for r in caplog.records)
    store.close()


# ------------------------------------------------------------------------- PostgreSQL, our own
def metric(text: str, line_start: str) -> float:
    """The value of the first metrics line starting with ``line_start``."""
    for line in text.splitlines():
        if line.startswith(line_start):
            return float(line.rsplit(" ", 1)[1])
    raise AssertionError(f"no metric {line_start!r}")


@pytest.mark.postgres
@pytest.mark.slow
def test_postgres_restart_reconnects_buffers_and_counts_drops(pg_cluster: PgCluster) -> None:
    store = open_store(pg_cluster.url, engine_kwargs={"connect_args": {"connect_timeout": 2}})
    committed = Committed()
    src = TickSource(n=10, period=0.02)
    pipe = Pipeline(
        store, [src], settings=settings_for(pg_cluster.url), queue_max_batches=20, put_timeout=0.02,
        write_retry_seconds=60, on_commit=committed,
    )  # fmt: skip
    metrics = Metrics(counters=pipe.totals)
    app = create_app(store, settings=settings_for(pg_cluster.url), pipeline=pipe, metrics=metrics)
    client = TestClient(app, raise_server_exceptions=False)
    beat(store)
    with pipe:
        wait_until(lambda: pipe.counters()["tick"]["stored"] >= 100, 10, "first commits")
        assert ready(client)[0] == 200
        pg_cluster.stop()
        _, body = wait_until(lambda: (r := ready(client))[0] == 503 and r, PRUNE + 0.5, "readyz 503")
        assert "database unreachable" in body["reasons"]
        r = client.get("/api/v1/robots")
        assert r.status_code == 503 and r.headers["Retry-After"] == "5"
        # the queue fills to its bound and holds; what comes beyond it is dropped and counted
        wait_until(lambda: pipe.totals().get("dropped_queue_full", 0) > 0, 10, "drops at the full queue")
        text = client.get("/metrics").text
        assert metric(text, "bodyhealth_ingest_queue_depth ") == 20
        assert metric(text, "bodyhealth_frames_dropped_total ") > 0
        assert metric(text, 'bodyhealth_ingest_events_total{event="dropped_queue_full"}') > 0
        assert metric(text, "bodyhealth_store_write_failing ") == 1
        stored_down = pipe.counters()["tick"]["stored"]
        pg_cluster.start()
        wait_until(lambda: ready(client)[0] == 200, 15, "readyz 200 after PostgreSQL is back")
        # the held batch and the 20 queued ones are written: none was dropped by the writer
        wait_until(
            lambda: pipe.counters()["tick"]["stored"] >= stored_down + 21 * 10 + 100, 15, "more commits"
        )
        assert client.get("/api/v1/robots").status_code == 200
    c = pipe.counters()["tick"]
    assert c["received"] == c["stored"] + c["dropped"]
    assert (
        pipe.totals().get("dropped_write_failed", 0) == 0
        and c["dropped"] == pipe.totals()["dropped_queue_full"]
    )
    assert store.sample_count("arm") == c["stored"] == committed.stamps().size
    store.close()
