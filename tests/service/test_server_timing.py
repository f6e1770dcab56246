"""The service's own time on every answer (``Server-Timing``), which the alerts bench keeps beside each
approval's round trip."""

from __future__ import annotations

import time

from fastapi import FastAPI
from fastapi.testclient import TestClient

from service.api import create_app
from service.api.timing import ServerTiming, server_ms
from service.store import open_store


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
    ms = server_ms(r.headers["server-timing"])
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
        assert server_ms(r.headers.get("server-timing")) is not None, (r.request.url, r.status_code)
    assert client.post("/api/v1/robots/nope/baseline").status_code == 403


def test_other_timings_in_the_header_are_skipped_and_a_missing_one_is_none() -> None:
    assert server_ms("db;dur=3.0, app;dur=7.25") == 7.25
    assert server_ms("db;dur=3.0") is None
    assert server_ms("") is None
