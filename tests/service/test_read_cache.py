"""The read routes' cache on a real store: a repeated read runs no SQL, any commit of the store makes the
next read fresh, writers in another process are seen within ``api_cache_seconds``, errors are not kept,
and authentication still runs on every request."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from pydantic import SecretStr
from sqlalchemy import event

from service.api import create_app
from service.frames import FrameBatch
from service.settings import Settings
from service.store import Store, open_store

READS = [
    "/api/v1/robots",
    "/api/v1/robots/arm",
    "/api/v1/robots/arm/status",
    "/api/v1/robots/arm/topology",
    "/api/v1/robots/arm/topology/history",
    "/api/v1/alerts",
    "/api/v1/robots/arm/alerts",
    "/api/v1/robots/arm/diagnostics",
]


def frames(robot: str, t0: float, n: int = 5) -> FrameBatch:
    t = t0 + np.arange(n) / 100.0
    return FrameBatch(robot, t, ("j1",), np.zeros((n, 1)), ("imu0",), np.zeros((n, 1, 3)), np.ones((n, 1, 3)))


class Statements:
    """Counts the SQL statements an engine runs."""

    def __init__(self, store: Store) -> None:
        self.n = 0
        event.listen(store.engine, "before_cursor_execute", self._count)

    def _count(self, *_: object) -> None:
        self.n += 1


@pytest.fixture
def db(tmp_path: Path) -> str:
    return f"sqlite:///{tmp_path / 'cache.db'}"


@pytest.fixture
def store(db: str) -> Iterator[Store]:
    s = open_store(db)
    s.write(frames("arm", 0.0))
    yield s
    s.close()


def client(store: Store, **settings: object) -> TestClient:
    return TestClient(create_app(store, settings=Settings(database_url="sqlite://", **settings)))


def test_a_repeated_read_runs_no_sql_and_answers_the_same(store: Store) -> None:
    c, sql = client(store, api_cache_seconds=60.0), Statements(store)
    first = {path: c.get(path) for path in READS}
    assert all(r.status_code == 200 for r in first.values()), {p: r.status_code for p, r in first.items()}
    ran = sql.n
    assert ran > len(READS)
    again = {path: c.get(path) for path in READS}
    assert sql.n == ran  # every second read came from the cache
    assert {p: r.json() for p, r in again.items()} == {p: r.json() for p, r in first.items()}
    assert store.generation > 0


def test_any_commit_of_the_store_makes_the_next_read_fresh(store: Store) -> None:
    c = client(store, api_cache_seconds=60.0)
    assert c.get("/api/v1/robots/arm").json()["last_frame_t"] == pytest.approx(0.04)
    store.write(frames("arm", 1.0))  # the ingest writer's path
    assert c.get("/api/v1/robots/arm").json()["last_frame_t"] == pytest.approx(1.04)
    assert [r["name"] for r in c.get("/api/v1/robots").json()] == ["arm"]
    assert c.post("/api/v1/robots/b/frames", json=_body(2.0)).status_code == 201  # the API's own write
    assert [r["name"] for r in c.get("/api/v1/robots").json()] == ["arm", "b"]


def _body(t0: float) -> dict[str, object]:
    return {
        "t": [t0, t0 + 0.01],
        "joint_names": ["j1"],
        "q": [[0.0], [0.0]],
        "imu_names": ["imu0"],
        "acc": [[[0.0, 0.0, 9.81]]] * 2,
        "gyro": [[[0.0, 0.0, 0.0]]] * 2,
    }


def test_a_writer_in_another_process_is_seen_within_the_max_age(store: Store, db: str) -> None:
    c = client(store, api_cache_seconds=0.3)
    assert c.get("/api/v1/robots/arm").json()["last_frame_t"] == pytest.approx(0.04)
    other = open_store(db)  # another store object: its commits do not move this store's count
    try:
        other.write(frames("arm", 5.0))
    finally:
        other.close()
    assert c.get("/api/v1/robots/arm").json()["last_frame_t"] == pytest.approx(0.04)  # kept
    time.sleep(0.35)
    assert c.get("/api/v1/robots/arm").json()["last_frame_t"] == pytest.approx(5.04)


def test_zero_max_age_renders_every_request(store: Store) -> None:
    c, sql = client(store, api_cache_seconds=0.0), Statements(store)
    c.get("/api/v1/robots")
    ran = sql.n
    c.get("/api/v1/robots")
    assert sql.n == 2 * ran > 0


def test_errors_are_not_kept(store: Store) -> None:
    c = client(store, api_cache_seconds=60.0)
    assert c.get("/api/v1/robots/new/status").status_code == 404
    store.write(frames("new", 0.0))
    assert c.get("/api/v1/robots/new/status").status_code == 200


def test_a_cached_read_still_needs_its_token(store: Store) -> None:
    c = client(
        store, api_cache_seconds=60.0, api_token=SecretStr("w" * 24), api_read_token=SecretStr("r" * 24)
    )
    ok = c.get("/api/v1/robots", headers={"Authorization": f"Bearer {'r' * 24}"})
    assert ok.status_code == 200 and ok.json()[0]["name"] == "arm"
    resp = c.get("/api/v1/robots")
    assert resp.status_code == 401 and resp.headers["www-authenticate"] == "Bearer"
    assert c.get("/api/v1/robots", headers={"Authorization": "Bearer wrong"}).status_code == 401
