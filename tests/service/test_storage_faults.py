"""Storage faults under a running app: a full disk, the SQLite file deleted or replaced, a database that
stops answering, PostgreSQL going away and coming back. Real stores, a running ingest pipeline and the
real app (``create_app``); nothing is mocked.

The full disk is a real one where the test may mount a small tmpfs (root); elsewhere SQLite's
``max_page_count`` pragma is the fault-injection layer at the file-system boundary: past the limit
SQLite fails every write with the same ``database or disk is full`` (SQLITE_FULL) a full disk gives,
and raising the limit is freeing space. PostgreSQL faults run on a server of the test's own
(:class:`PgCluster`, initdb in a temp dir on a free port), never the shared one.
"""

from __future__ import annotations

import glob
import logging
import os
import shutil
import sqlite3
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import event

from service.api import create_app
from service.frames import FrameBatch
from service.ingest.base import Source
from service.ingest.pipeline import Pipeline
from service.metrics import Metrics
from service.settings import Settings
from service.store import Store, open_store
from tests.ports import free_port

__all__ = ["PgCluster", "TickSource", "wait_until"]

PRUNE = 0.5  # prune interval of these tests, seconds
N_IMU = 8


def wait_until(cond: Callable[[], Any], timeout: float, what: str, every: float = 0.05) -> Any:
    """Poll ``cond`` until it is truthy; its value, or an AssertionError naming ``what``."""
    deadline = time.monotonic() + timeout
    while True:
        got = cond()
        if got:
            return got
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.1f} s waiting for {what}")
        time.sleep(every)


class TickSource(Source):
    """An endless robot: ``n`` samples of ``N_IMU`` IMUs per read, device time running on, one read per
    ``period`` seconds (about 40 kB a batch, so a small disk fills in a moment)."""

    def __init__(self, name: str = "tick", robot: str = "arm", n: int = 100, period: float = 0.02) -> None:
        super().__init__(name)
        self.robot, self.n, self.period, self._k = robot, n, period, 0
        self._rng = np.random.default_rng(0)

    def _read_raw(self, timeout: float) -> list[FrameBatch]:
        time.sleep(self.period)
        t = (self._k * self.n + np.arange(self.n)) * 0.01
        self._k += 1
        acc = self._rng.standard_normal((self.n, N_IMU, 3))
        gyro = self._rng.standard_normal((self.n, N_IMU, 3))
        imus = tuple(f"imu{i}" for i in range(N_IMU))
        return [FrameBatch(self.robot, t, ("j1",), np.zeros((self.n, 1)), imus, acc, gyro)]


class Committed:
    """``on_commit``: every device time stamp the pipeline reported committed."""

    def __init__(self) -> None:
        self.t: list[np.ndarray] = []
        self._lock = threading.Lock()

    def __call__(self, batches: list[FrameBatch]) -> None:
        with self._lock:
            self.t.extend(b.t.copy() for b in batches)

    def stamps(self) -> np.ndarray:
        with self._lock:
            return np.concatenate(self.t) if self.t else np.zeros(0)


def settings_for(url: str) -> Settings:
    return Settings(database_url=url, prune_interval_seconds=PRUNE, worker_interval_seconds=1)


def ready(client: TestClient) -> tuple[int, dict[str, Any]]:
    r = client.get("/readyz")
    return r.status_code, r.json()


def beat(store: Store) -> None:
    """The worker's heartbeat (these apps run no worker): readiness then depends on storage only."""
    store.heartbeat("worker", time.time())


# --------------------------------------------------------------------------------- a full disk
class SmallDisk:
    """Room for the database that can run out and be given back: a 64 MiB tmpfs filled up to
    ``headroom`` bytes by a ballast file when mounting is allowed, else ``max_page_count``."""

    def __init__(self, tmp: Path) -> None:
        self.dir = tmp / "disk"
        self.dir.mkdir()
        self.mounted = os.geteuid() == 0 and self._mount()
        self.ballast = self.dir / "ballast"
        self._limit = [2**30]
        self.store: Store | None = None

    def _mount(self) -> bool:
        r = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs", str(self.dir)], capture_output=True
        )
        return r.returncode == 0

    def attach(self, store: Store) -> None:
        """Without a tmpfs: every new connection of ``store`` gets the current page limit."""
        self.store = store
        if not self.mounted:

            def limit(dbapi_conn: Any, _rec: Any) -> None:
                dbapi_conn.execute(f"PRAGMA max_page_count={self._limit[0]}")

            event.listen(store.engine, "connect", limit)

    def fill(self, headroom: int = 256 * 1024) -> None:
        if self.mounted:
            block = b"\0" * 65536
            with open(self.ballast, "wb") as fh:  # the store grows meanwhile: stop at the headroom or full
                try:
                    while (st := os.statvfs(self.dir)).f_bavail * st.f_frsize > headroom:
                        fh.write(block)
                        fh.flush()
                except OSError:
                    pass
        else:
            assert self.store is not None
            with self.store.engine.connect() as conn:
                pages = conn.exec_driver_sql("PRAGMA page_count").scalar()
            self._set_limit(int(pages) + 4)

    def free(self) -> None:
        if self.mounted:
            self.ballast.unlink()
        else:
            self._set_limit(2**30)

    def _set_limit(self, pages: int) -> None:
        self._limit[0] = pages
        assert self.store is not None
        self.store.engine.dispose()  # pooled connections go; new ones take the new limit

    def close(self) -> None:
        if self.mounted:
            subprocess.run(["umount", "-l", str(self.dir)], capture_output=True)


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[SmallDisk]:
    disk = SmallDisk(tmp_path)
    try:
        yield disk
    finally:
        disk.close()


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
class PgCluster:
    """A PostgreSQL server of the test's own (initdb in a temp dir, a free port), to stop and start at
    will; as root it runs as the ``postgres`` user (initdb refuses root)."""

    def __init__(self) -> None:
        initdbs = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
        if not initdbs:
            pytest.skip("no initdb under /usr/lib/postgresql: cannot run a PostgreSQL server to stop")
        self.bindir = Path(initdbs[-1]).parent
        self.base = Path(tempfile.mkdtemp(prefix="bodyhealth-pgfault-"))
        self.data, self.port = self.base / "pgdata", free_port()
        self.prefix: list[str] = []
        if os.geteuid() == 0:
            import pwd

            pw = pwd.getpwnam("postgres")
            os.chown(self.base, pw.pw_uid, pw.pw_gid)
            self.prefix = ["runuser", "-u", "postgres", "--"]
        self._run("initdb", "-D", str(self.data), "-U", "postgres", "--auth=trust", "-E", "UTF8")
        self.start()
        self._run("createdb", "-h", "127.0.0.1", "-p", str(self.port), "-U", "postgres", "bodyhealth")

    @property
    def url(self) -> str:
        return f"postgresql+psycopg://postgres@127.0.0.1:{self.port}/bodyhealth"

    def _run(self, tool: str, *args: str) -> None:
        cmd = [*self.prefix, str(self.bindir / tool), *args]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, f"{tool} failed: {r.stderr[-2000:]}"

    def start(self) -> None:
        opts = f"-p {self.port} -k {self.base} -c listen_addresses=127.0.0.1 -c fsync=off"
        self._run("pg_ctl", "-D", str(self.data), "-l", str(self.base / "pg.log"), "-w", "-o", opts, "start")

    def stop(self) -> None:
        """Stop as a crash would (``immediate``): connections die mid-session."""
        self._run("pg_ctl", "-D", str(self.data), "-m", "immediate", "-w", "stop")

    def destroy(self) -> None:
        subprocess.run(
            [*self.prefix, str(self.bindir / "pg_ctl"), "-D", str(self.data), "-m", "immediate", "stop"],
            capture_output=True,
            timeout=60,
        )
        shutil.rmtree(self.base, ignore_errors=True)


@pytest.fixture
def pg_cluster() -> Iterator[PgCluster]:
    cluster = PgCluster()
    try:
        yield cluster
    finally:
        cluster.destroy()


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
