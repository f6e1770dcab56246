"""Requests from other sites: a browser sends a body-less POST (or a form) to ``localhost`` from any page
it shows, without a CORS preflight. Every mutating route of the app, read from the app itself, refuses
such a request (403) with or without a token, and changes nothing; same-origin requests and clients
that are not browsers (no ``Origin``, a JSON body or ``X-Requested-With: bodyhealth``) pass. Also: one
``Host`` header only. Real app, real SQLite store in tmp_path."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.api.security import json_depth
from service.settings import Settings
from service.store import Store, open_store
from tests.service.access import (
    ACCEPTED,
    BODIES,
    TOPO,
    WRITE,
    Farm,
    Worker,
    concrete,
    mutating_routes,
)
from tests.service.builders import batch

INTENT = {"X-Requested-With": "bodyhealth"}
AUTH = {"Authorization": f"Bearer {WRITE}"}

#: What a page of another site can make a browser send, with what the browser adds on its own.
CROSS_SITE: dict[str, dict[str, str]] = {
    "origin": {"Origin": "https://evil.example"},
    "origin-port": {"Origin": "http://testserver:8080"},  # another service on the same machine
    "origin-scheme": {"Origin": "https://testserver"},
    "origin-null": {"Origin": "null"},  # sandboxed frames, some redirects
    "fetch-cross-site": {"Sec-Fetch-Site": "cross-site"},
    "fetch-same-site": {"Sec-Fetch-Site": "same-site"},  # on localhost, every port is one site
    "both": {"Origin": "https://evil.example", "Sec-Fetch-Site": "cross-site"},
}


@pytest.fixture
def store(tmp_path: Path) -> Iterator[Store]:
    s = open_store(f"sqlite:///{tmp_path / 'origin.db'}")
    s.write(batch("sim"))
    s.mark_simulated("sim", "ur5e")
    s.save_topology("sim", TOPO, 100.0, 0.19)
    yield s
    s.close()


def make_client(store: Store, farm: Farm, **settings: Any) -> TestClient:
    s = Settings(database_url="sqlite://", retrain_min_interval_seconds=0, **settings)
    worker = Worker(store)
    client = TestClient(create_app(store, settings=s, damage=farm, worker=worker))
    client.worker = worker  # type: ignore[attr-defined]
    return client


def unchanged(store: Store, farm: Farm, client: TestClient, samples: int) -> None:
    assert store.sample_count() == samples
    assert farm.calls == []
    assert client.worker.requests == []  # type: ignore[attr-defined]
    assert store.baseline("sim") is None
    assert not any(a.acked for a in store.alerts("sim"))


@pytest.mark.parametrize("token", [None, WRITE], ids=["no-token", "token"])
@pytest.mark.parametrize("kind", sorted(CROSS_SITE))
def test_a_cross_site_bodyless_post_is_403_on_every_mutating_route(
    store: Store, token: str | None, kind: str
) -> None:
    farm = Farm()
    client = make_client(store, farm, api_token=token)
    routes = mutating_routes(client)
    assert {p for _, p in routes} == set(ACCEPTED)  # a new route must be checked here too
    samples = store.sample_count()
    for method, template in routes:
        url = concrete(template, store)
        # what the page can send: no body; the intent header or a token cannot make it pass either
        for extra in ({}, INTENT, {**INTENT, **AUTH}):
            resp = client.request(method, url, headers={**CROSS_SITE[kind], **extra})
            assert resp.status_code == 403, (template, extra, resp.text)
            assert resp.json()["detail"].startswith("cross-site request refused"), resp.text
        # nor a body of its own (a form), nor a JSON one (which would need a preflight first)
        resp = client.request(method, url, json=BODIES.get(template, {}), headers=CROSS_SITE[kind])
        assert resp.status_code == 403, (template, resp.text)
    unchanged(store, farm, client, samples)


@pytest.mark.parametrize("token", [None, WRITE], ids=["no-token", "token"])
def test_a_bodyless_post_without_intent_is_403_and_changes_nothing(store: Store, token: str | None) -> None:
    """No Origin (a client that is not a browser, or an old one) and neither a JSON type nor the
    intent header: what an <img> or a plain link could trigger, refused with what to send instead."""
    farm = Farm()
    client = make_client(store, farm, api_token=token)
    samples = store.sample_count()
    auth = AUTH if token else {}
    for method, template in mutating_routes(client):
        resp = client.request(method, concrete(template, store), headers=auth)
        assert resp.status_code == 403, (template, resp.text)
        assert "X-Requested-With: bodyhealth" in resp.json()["detail"]
    unchanged(store, farm, client, samples)


@pytest.mark.parametrize(
    "headers",
    [
        {},  # curl, the CLI, a script: no Origin
        {"Origin": "http://testserver"},
        {"Origin": "http://TestServer:80"},  # the same origin, written differently
        {"Origin": "http://testserver", "Sec-Fetch-Site": "same-origin"},  # the dashboard
        {"Sec-Fetch-Site": "none"},  # typed by the user
    ],
    ids=["no-origin", "same-origin", "same-origin-default-port", "dashboard", "fetch-none"],
)
def test_same_origin_and_plain_clients_pass(store: Store, headers: dict[str, str]) -> None:
    farm = Farm()
    client = make_client(store, farm, api_token=WRITE)
    for method, template in mutating_routes(client):
        body = BODIES.get(template)
        extra = {} if body is not None else INTENT  # a JSON body's type is intent enough
        resp = client.request(
            method, concrete(template, store), json=body, headers={**headers, **extra, **AUTH}
        )
        assert resp.status_code == ACCEPTED[template], (template, resp.text)
    assert farm.calls and client.worker.requests and store.baseline("sim") is not None  # type: ignore[attr-defined]


def test_the_origin_is_compared_with_the_scheme_the_request_came_in_on(store: Store) -> None:
    farm = Farm()
    s = Settings(database_url="sqlite://")
    client = TestClient(create_app(store, settings=s, damage=farm), base_url="https://testserver")
    url = "/api/v1/robots/sim/simulate/damage"
    body = {"kind": "imu_dead"}
    assert client.post(url, json=body, headers={"Origin": "https://testserver"}).status_code == 201
    assert client.post(url, json=body, headers={"Origin": "https://testserver:443"}).status_code == 201
    assert client.post(url, json=body, headers={"Origin": "http://testserver"}).status_code == 403


def test_allowed_origins_admit_a_page_served_elsewhere(store: Store) -> None:
    """Behind a proxy that changes the scheme or the host, the dashboard's origin is not the one the
    service sees: it is listed in allowed_origins, and only it."""
    farm = Farm()
    client = make_client(store, farm, allowed_origins="https://robots.example.org, http://10.0.0.5:8000")
    url = "/api/v1/robots/sim/simulate/damage"
    body = {"kind": "imu_dead"}
    for origin, site in (
        ("https://robots.example.org", "same-origin"),
        ("https://robots.example.org:443", "same-site"),
        ("http://10.0.0.5:8000", "cross-site"),
    ):
        resp = client.post(url, json=body, headers={"Origin": origin, "Sec-Fetch-Site": site})
        assert resp.status_code == 201, (origin, resp.text)
    for origin in ("https://evil.example", "http://robots.example.org", "http://10.0.0.5"):
        assert client.post(url, json=body, headers={"Origin": origin}).status_code == 403, origin
    assert client.post(url, json=body, headers={"Sec-Fetch-Site": "same-site"}).status_code == 403
    assert len(farm.calls) == 3
    with pytest.raises(ValueError, match="not scheme://host"):
        create_app(store, settings=Settings(database_url="sqlite://", allowed_origins="robots.example.org"))


def test_two_origin_headers_are_refused(store: Store) -> None:
    farm = Farm()
    client = make_client(store, farm)
    headers = [("Origin", "http://testserver"), ("Origin", "https://evil.example"), *INTENT.items()]
    resp = client.post("/api/v1/robots/sim/topology/retrain", headers=headers)
    assert resp.status_code == 403 and "more than one Origin" in resp.json()["detail"]


def test_requests_no_route_serves_get_the_routers_answer(store: Store) -> None:
    """The check guards routes: a method a path does not take is still 405, an unknown path 404."""
    client = make_client(store, Farm())
    evil = CROSS_SITE["both"]
    assert client.put("/api/v1/robots/sim/baseline", headers=evil).status_code == 405
    assert client.delete("/api/v1/robots/sim/frames", headers=evil).status_code == 405
    assert client.post("/api/v1/nothing-here", headers=evil).status_code == 404
    # reads are not writes: another site may send them and cannot read the answer (no CORS)
    got = client.get("/api/v1/robots", headers=evil)
    assert got.status_code == 200 and "access-control-allow-origin" not in got.headers


def _raw(app: Any, headers: list[tuple[bytes, bytes]]) -> tuple[int, bytes]:
    """One GET through the app's ASGI interface with exactly ``headers`` (an HTTP client library
    merges or refuses a repeated Host)."""
    sent: list[dict[str, Any]] = []

    async def receive() -> dict[str, Any]:
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message: dict[str, Any]) -> None:
        sent.append(message)

    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "GET",
        "scheme": "http",
        "path": "/api/v1/robots",
        "raw_path": b"/api/v1/robots",
        "root_path": "",
        "query_string": b"",
        "headers": headers,
        "client": ("127.0.0.1", 5000),
        "server": ("127.0.0.1", 8000),
    }
    asyncio.run(app(scope, receive, send))
    return sent[0]["status"], b"".join(m.get("body", b"") for m in sent[1:])


def test_exactly_one_host_header(store: Store) -> None:
    app = create_app(store, settings=Settings(database_url="sqlite://"))
    status, body = _raw(app, [(b"host", b"localhost:8000"), (b"host", b"evil.example")])
    assert (status, body) == (400, b'{"detail":"more than one Host header"}')
    status, _ = _raw(app, [(b"host", b"localhost:8000")])
    assert status == 200


def test_json_depth_counts_brackets_outside_strings() -> None:
    assert json_depth(b'{"a": [[1], {"b": "]]]]{{{{"}], "c": "\\\\"}') == 3
    assert json_depth(b'["\\"[[[[", [[]]]') == 3
    assert json_depth(b"[" * 100_000 + b"]" * 100_000) == 100_000
    assert json_depth(b'"[[["') == 0 and json_depth(b"") == 0
