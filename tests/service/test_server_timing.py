"""The service's own time on every answer (``Server-Timing``), which the alerts bench keeps beside each
approval's round trip."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import event

from service.api import create_app
from service.api.timing import ServerTiming, server_timings
from service.store import open_store
from service.store.write_lock import LOCK_TIMES, WriteLock

#: How long the writers below keep the store's write lock.
HOLD_S = 0.04


def test_the_header_holds_the_routes_time_and_no_more_than_the_round_trip() -> None:
    app = FastAPI()

    @app.get("/slow")
    def slow() -> dict[str, bool]:
        time.sleep(0.05)
        return {"ok": True}

    app.add_middleware(ServerTiming)
    client = TestClient(app)
    t = time.perf_counter()
    r = client.get("/slow")
    round_trip_ms = (time.perf_counter() - t) * 1e3
    ms = server_timings(r.headers["server-timing"]).get("app")
    assert ms is not None
    assert 50.0 <= ms <= round_trip_ms


def test_every_answer_of_the_service_carries_it_errors_and_refusals_too() -> None:
    client = TestClient(create_app(open_store("sqlite://")))
    for r in (
        client.get("/api/v1/robots"),
        client.get("/api/v1/robots/nope"),
        client.post("/api/v1/robots/nope/baseline"),  # refused by the write guard: no JSON type
        client.get("/livez"),
    ):
        assert "app" in server_timings(r.headers.get("server-timing")), (r.request.url, r.status_code)
    assert client.post("/api/v1/robots/nope/baseline").status_code == 403


def test_each_timing_in_the_header_is_read_by_name_and_a_missing_one_is_absent() -> None:
    assert server_timings("db;dur=3.0, app;dur=7.25")["app"] == 7.25
    assert "app" not in server_timings("db;dur=3.0")
    assert server_timings("") == server_timings(None) == {}


def test_a_requests_store_writes_say_how_long_they_waited_for_the_lock_and_held_it() -> None:
    # the routes run in worker threads: the request's share reaches them through its context
    app, lock = FastAPI(), WriteLock()
    asked = threading.Event()

    @app.post("/write")
    def write() -> dict[str, bool]:
        asked.set()
        with lock, lock:  # a nested write is counted once
            time.sleep(HOLD_S)
        return {"ok": True}

    @app.get("/read")
    def read() -> dict[str, bool]:
        return {"ok": True}

    app.add_middleware(ServerTiming)
    client = TestClient(app)
    alone = server_timings(client.post("/write").headers["server-timing"])
    assert alone["store-wait"] == 0.0 and 1e3 * HOLD_S <= alone["store-held"] <= alone["app"]
    assert server_timings(client.get("/read").headers["server-timing"])["store-held"] == 0.0

    def holder() -> None:  # another writer, holding the lock from before the request asks until after
        with lock:
            started.set()
            asked.wait(10)
            time.sleep(HOLD_S)

    started = threading.Event()
    asked.clear()
    t = threading.Thread(target=holder)
    t.start()
    started.wait(10)
    queued = server_timings(client.post("/write").headers["server-timing"])
    t.join()
    assert queued["store-wait"] >= 1e3 * HOLD_S and queued["store-held"] >= 1e3 * HOLD_S
    assert queued["store-wait"] + queued["store-held"] <= queued["app"]
    assert LOCK_TIMES.get() is None  # nothing is kept outside a request


def test_a_requests_commits_are_their_share_of_its_hold(tmp_path: Path) -> None:
    """``store-commit`` times the store's commits and nothing else: a commit slowed by 40 ms (as one
    that waits for the disk) shows in it and in the hold; a route's own time holding no lock does not."""
    store, app = open_store(f"sqlite:///{tmp_path / 'commit.db'}"), FastAPI()

    @app.post("/write")
    def write() -> dict[str, bool]:
        store.mark_simulated("r", "ur5e")
        time.sleep(HOLD_S)  # after the write: in the app's time only
        return {"ok": True}

    app.add_middleware(ServerTiming)
    client = TestClient(app)

    def slow_commit(_conn: object) -> None:
        time.sleep(HOLD_S)

    quick = server_timings(client.post("/write").headers["server-timing"])
    event.listen(store.engine, "commit", slow_commit)
    slow = server_timings(client.post("/write").headers["server-timing"])
    event.remove(store.engine, "commit", slow_commit)
    for t in (quick, slow):  # the route's sleep after its write is the app's and not the hold's
        assert t["store-commit"] <= t["store-held"] and t["store-held"] + 1e3 * HOLD_S <= t["app"] + 0.1
    assert 1e3 * HOLD_S <= slow["store-commit"] and quick["store-commit"] < 1e3 * HOLD_S
    store.close()
