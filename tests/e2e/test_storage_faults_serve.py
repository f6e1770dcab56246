"""Storage faults under a running ``bodyhealth serve`` replaying a recording: PostgreSQL stopped and
started again (the service reconnects by itself, and the stored data is exactly the recording's start,
no gap, no duplicate), and the SQLite file deleted under it (reported on ``/readyz`` and in one ERROR
log line, nothing more written, a clean SIGTERM). The PostgreSQL server is the test's own
(the ``pg_cluster`` fixture, :class:`~tests.service.faults.PgCluster`), never the shared one.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from bodyschema.recording import Recording
from service.store import open_store
from simulators.recording_io import save_recording
from tests.builders import synth
from tests.e2e.processes import start_service
from tests.service.faults import PgCluster
from tests.waits import wait_until

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

ROBOT = "arm"
PRUNE = 1.0  # the service's prune interval here, seconds


class Serve:
    """``bodyhealth serve`` replaying ``rec_path`` at ``speed`` into ``db_url``, with a commit log."""

    def __init__(self, tmp: Path, db_url: str, rec_path: Path, speed: float) -> None:
        self.log = tmp / "commits.jsonl"
        self.err_path = tmp / "serve.err"
        env = {
            **os.environ,
            "BODYHEALTH_WORKER_INTERVAL_SECONDS": "1",
            "BODYHEALTH_WINDOW_SECONDS": "5",
            "BODYHEALTH_PRUNE_INTERVAL_SECONDS": str(PRUNE),
        }
        spec = f"replay:{rec_path}@{speed:g}?robot={ROBOT}"
        self.proc, url = start_service(
            db_url, "--source", spec, "--commit-log", str(self.log), err=self.err_path, env=env, cwd=tmp
        )
        self.client = httpx.Client(base_url=url, timeout=10)

    def ready(self) -> tuple[int, dict[str, Any]] | None:
        assert self.proc.poll() is None, f"service died:\n{self.err_tail()}"
        try:
            r = self.client.get("/readyz")
        except httpx.HTTPError:
            return None
        return r.status_code, r.json()

    def committed(self) -> int:
        """Samples the service reported committed (the commit log's running total)."""
        lines = [ln for ln in self.log.read_text().splitlines() if ln.strip()] if self.log.exists() else []
        return json.loads(lines[-1])["samples"] if lines else 0

    def err_tail(self) -> str:
        return self.err_path.read_text()[-4000:]

    def log_records(self) -> list[dict[str, Any]]:
        out = []
        for line in self.err_path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                continue
        return out

    def terminate(self) -> int:
        self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(60)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(30)
        self.client.close()


def until_status(svc: Serve, code: int, timeout: float, what: str) -> dict[str, Any]:
    got = wait_until(lambda: (r := svc.ready()) is not None and r[0] == code and r, timeout, what, every=0.1)
    return got[1]


@pytest.fixture
def recording(tmp_path: Path, rng: np.random.Generator) -> tuple[Recording, Path]:
    rec = synth(rng, seconds=120.0)
    path = tmp_path / "run.npz"
    save_recording(rec, path)
    return rec, path


@pytest.mark.postgres
def test_postgres_stopped_and_started_under_serve(
    pg_cluster: PgCluster, recording: tuple[Recording, Path], tmp_path: Path
) -> None:
    rec, rec_path = recording
    svc = Serve(tmp_path, pg_cluster.url, rec_path, speed=4)
    try:
        until_status(svc, 200, 60, "readiness")
        wait_until(lambda: svc.committed() >= 300, 20, "first commits")
        pg_cluster.stop()
        t0 = time.monotonic()
        body = until_status(svc, 503, PRUNE + 1, "readyz 503 with PostgreSQL stopped")
        print(f"PostgreSQL stopped -> 503 after {time.monotonic() - t0:.2f} s: {body['reason']}")
        assert "database unreachable" in body["reasons"]
        r = svc.client.get("/api/v1/robots")
        assert r.status_code == 503 and r.headers["Retry-After"] == "5"
        assert r.json() == {"detail": "database unavailable (OperationalError); retry later"}
        time.sleep(2.0)  # frames keep arriving: they wait in the bounded queue
        down = svc.committed()
        text = svc.client.get("/metrics").text
        assert "bodyhealth_store_write_failing 1.0" in text and "bodyhealth_frames_dropped_total 0.0" in text
        pg_cluster.start()
        t1 = time.monotonic()
        until_status(svc, 200, 20, "readyz 200 after PostgreSQL is back")
        print(f"PostgreSQL started -> 200 after {time.monotonic() - t1:.2f} s")
        wait_until(lambda: svc.committed() >= down + 800, 20, "frames stored after the restart")
        assert svc.client.get("/api/v1/robots").json()[0]["name"] == ROBOT
        assert svc.terminate() == 0, svc.err_tail()
        committed = svc.committed()
    finally:
        svc.kill()
    # a short outage within the write retries loses nothing: the store holds exactly the recording's start
    with open_store(pg_cluster.url) as store:
        n = store.sample_count(ROBOT)
        got = store.read_between(ROBOT, -np.inf, np.inf)
    assert n == committed and got is not None and got.n_samples == n
    np.testing.assert_array_equal(got.t, rec.t[:n])
    np.testing.assert_array_equal(got.gyro, rec.gyro[:n])


def test_sqlite_file_deleted_under_serve(recording: tuple[Recording, Path], tmp_path: Path) -> None:
    _, rec_path = recording
    db = tmp_path / "serve.db"
    svc = Serve(tmp_path, f"sqlite:///{db}", rec_path, speed=4)
    try:
        until_status(svc, 200, 60, "readiness")
        wait_until(lambda: svc.committed() >= 300, 20, "first commits")
        db.unlink()
        t0 = time.monotonic()
        body = until_status(svc, 503, PRUNE + 1, "readyz 503 with the database file deleted")
        print(f"file deleted -> 503 after {time.monotonic() - t0:.2f} s: {body['reason']}")
        assert body["checks"]["storage_fault"] == f"database file {db} was deleted"
        assert body["reasons"][0] == body["checks"]["storage_fault"]
        stuck = svc.committed()
        time.sleep(PRUNE + 0.5)
        assert svc.committed() == stuck  # nothing more is written to the unlinked inode
        assert svc.ready()[0] == 503 and not db.exists()
        assert svc.terminate() == 0, svc.err_tail()
    finally:
        svc.kill()
    errors = [r for r in svc.log_records() if r.get("level") == "error" and "storage fault" in r["msg"]]
    assert len(errors) == 1 and f"database file {db} was deleted" in errors[0]["msg"]
    assert not db.exists()
