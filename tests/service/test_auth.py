"""Who may call the API: bearer tokens on every mutating route (and on reads of robot data unless
``read_token_required`` is off), JSON-only bodies, trusted Host headers, no CORS, the OpenAPI security
scheme, and ``serve`` refusing a network address without a token. Requests from other sites:
tests/service/test_security_origin.py. Real app, real SQLite store in tmp_path."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from cli.main import main as cli_main
from service.api import create_app
from service.api.security import MUTATING_METHODS
from service.settings import Settings, get_settings, reset_settings
from service.store import Store, open_store
from tests.service.access import (
    ACCEPTED,
    BODIES,
    READ,
    TOPO,
    WRITE,
    Farm,
    Worker,
    concrete,
    mutating_routes,
    read_routes,
)
from tests.service.builders import batch
from tests.service.geometry import geometry_json


@pytest.fixture
def store(tmp_path: Path) -> Iterator[Store]:
    s = open_store(f"sqlite:///{tmp_path / 'auth.db'}")
    s.write(batch("sim"))
    s.mark_simulated("sim", "ur5e")
    s.save_topology("sim", TOPO, 100.0, 0.19)
    yield s
    s.close()


def learn_geometry(store: Store) -> None:
    """Give ``sim`` a geometry under its baseline (made one if it has none), so every read has something
    to answer (the URDF is 404 before a geometry is learned)."""
    base = store.baseline("sim")
    bid = base.id if base is not None else store.set_baseline("sim", TOPO, "operator")
    store.save_kinematics("sim", bid, geometry_json(TOPO), wall_time=1.0)


def make_client(store: Store, farm: Farm | None = None, **settings: Any) -> TestClient:
    s = Settings(database_url="sqlite://", **settings)
    return TestClient(create_app(store, settings=s, damage=farm or Farm(), worker=Worker(store)))


#: What a client of the API sends with a body-less request (a JSON body's type does as much).
INTENT = {"X-Requested-With": "bodyhealth"}


def send(client: TestClient, method: str, template: str, store: Store, headers: dict[str, str]) -> Any:
    body = BODIES.get(template)
    return client.request(method, concrete(template, store), json=body, headers={**INTENT, **headers})


def test_the_app_has_the_mutating_routes_this_test_knows(store: Store) -> None:
    # A new mutating route must be added to ACCEPTED (and BODIES) so the tests below check it properly.
    got = {p for _, p in mutating_routes(make_client(store, api_token=WRITE))}
    assert got == set(ACCEPTED)


@pytest.mark.parametrize(
    "headers",
    [
        {},
        {"Authorization": "Bearer wrong-token"},
        {"Authorization": f"Bearer {WRITE}x"},
        {"Authorization": f"Basic {WRITE}"},
        {"Authorization": WRITE},
        {"Authorization": f"Bearer {READ}"},  # the read token changes nothing
    ],
    ids=["none", "wrong", "longer", "basic", "no-scheme", "read-token"],
)
def test_every_mutating_route_refuses_a_missing_or_wrong_token(store: Store, headers: dict[str, str]) -> None:
    farm = Farm()
    client = make_client(store, farm, api_token=WRITE, api_read_token=READ)
    before = store.sample_count()
    routes = mutating_routes(client)
    assert len(routes) == 7
    for method, template in routes:
        resp = send(client, method, template, store, headers)
        assert resp.status_code == 401, (template, resp.text)
        assert resp.headers["www-authenticate"] == "Bearer"
        assert resp.headers["content-type"] == "application/json"
        detail = resp.json()["detail"]
        assert isinstance(detail, str) and detail
        if headers == {"Authorization": f"Bearer {READ}"}:
            assert "read token" in detail
    # nothing happened
    assert store.sample_count() == before
    assert farm.calls == []
    assert store.baseline("sim") is None
    assert not any(a.acked for a in store.alerts("sim"))


def test_every_mutating_route_accepts_the_write_token(store: Store) -> None:
    farm = Farm()
    client = make_client(store, farm, api_token=WRITE, api_read_token=READ)
    for method, template in mutating_routes(client):
        resp = send(client, method, template, store, {"Authorization": f"Bearer {WRITE}"})
        assert resp.status_code == ACCEPTED[template], (template, resp.text)
    assert farm.calls == [("sim", "imu_dead", {"imu": "imu0"})]
    assert store.baseline("sim").source == "operator"


def test_without_tokens_the_api_stays_open(store: Store) -> None:
    client = make_client(store)
    for method, template in mutating_routes(client):
        assert send(client, method, template, store, {}).status_code == ACCEPTED[template], template
    learn_geometry(store)
    for path in read_routes(client):
        assert client.get(concrete(path, store)).status_code == 200, path


def test_write_token_alone_guards_reads_unless_told_not_to(store: Store) -> None:
    client = make_client(store, api_token=WRITE)
    learn_geometry(store)
    paths = read_routes(client)
    for path in paths:
        url = concrete(path, store)
        assert client.get(url).status_code == 401, path
        assert client.get(url, headers={"Authorization": f"Bearer {WRITE}"}).status_code == 200, path
    open_reads = make_client(store, api_token=WRITE, read_token_required=False)
    for path in paths:
        assert open_reads.get(concrete(path, store)).status_code == 200, path


def test_read_token_guards_every_read_and_either_token_opens_it(store: Store) -> None:
    client = make_client(store, api_token=WRITE, api_read_token=READ)
    learn_geometry(store)
    paths = read_routes(client)
    assert len(paths) == 11
    for path in paths:
        url = concrete(path, store)
        for headers in ({}, {"Authorization": "Bearer nope"}):
            resp = client.get(url, headers=headers)
            assert resp.status_code == 401 and resp.headers["www-authenticate"] == "Bearer", path
            assert isinstance(resp.json()["detail"], str)
        for token in (READ, WRITE):
            assert client.get(url, headers={"Authorization": f"Bearer {token}"}).status_code == 200, path
    # probes, metrics, the dashboard and the API docs stay open: the page must load to ask for a token
    assert client.get("/livez").json() == {"status": "ok"}
    assert client.get("/readyz").status_code == 503  # no worker heartbeat: not ready, but not 401
    assert client.get("/metrics").status_code == 200
    assert client.get("/").status_code == 200 and client.get("/static/app.js").status_code == 200
    assert client.get("/openapi.json").status_code == 200


def test_token_from_file_and_environment(
    store: Store, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    f = tmp_path / "token"
    f.write_text(f"  {WRITE}\n")
    client = make_client(store, api_token_file=f)
    url = "/api/v1/robots/sim/topology/retrain"
    assert client.post(url, headers=INTENT).status_code == 401
    assert client.post(url, headers={"Authorization": f"Bearer {WRITE}", **INTENT}).status_code == 202
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BODYHEALTH_API_TOKEN", WRITE)
    monkeypatch.setenv("BODYHEALTH_API_READ_TOKEN", READ)
    reset_settings()
    try:
        s = get_settings()
        assert (s.write_token(), s.read_token()) == (WRITE, READ)
        assert WRITE not in repr(s) and READ not in repr(s)
    finally:
        reset_settings()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"api_token_file": "missing-file"}, "api_token_file"),
        ({"api_token_file": "empty"}, "is empty"),
        ({"api_token": WRITE, "api_token_file": "empty"}, "not both"),
        ({"api_read_token": READ}, "api_read_token needs api_token"),
        ({"read_token_required": True}, "read_token_required needs api_token"),
        ({"api_token": WRITE, "api_read_token": READ, "read_token_required": False}, "unset one of them"),
    ],
)
def test_token_misconfiguration_is_refused(tmp_path: Path, kwargs: dict[str, str], message: str) -> None:
    (tmp_path / "empty").write_text(" \n")
    kwargs = {k: (str(tmp_path / v) if k == "api_token_file" else v) for k, v in kwargs.items()}
    with pytest.raises(ValueError, match=message) as err:
        Settings(database_url="sqlite://", **kwargs)
    assert WRITE not in str(err.value) and READ not in str(err.value)


def test_a_blank_token_variable_means_no_token() -> None:
    assert Settings(database_url="sqlite://", api_token="  ").write_token() is None


@pytest.mark.parametrize(
    ("headers", "content"),
    [
        ({"content-type": "application/x-www-form-urlencoded"}, b"kind=imu_dead"),
        (
            {"content-type": "multipart/form-data; boundary=x"},
            b'--x\r\nContent-Disposition: form-data; name="kind"\r\n\r\nimu_dead\r\n--x--\r\n',
        ),
        ({"content-type": "text/plain"}, b'{"kind": "imu_dead"}'),
        ({"content-type": "application/x-www-form-urlencoded"}, b""),  # an empty HTML form
        ({}, b'{"kind": "imu_dead"}'),  # a body without a type
    ],
    ids=["urlencoded", "multipart", "text-plain", "empty-form", "untyped-body"],
)
def test_mutating_routes_take_json_bodies_only(store: Store, headers: dict[str, str], content: bytes) -> None:
    farm = Farm()
    client = make_client(store, farm, api_token=WRITE)
    auth = {"Authorization": f"Bearer {WRITE}"}
    before = store.sample_count()
    for method, template in mutating_routes(client):
        resp = client.request(method, concrete(template, store), content=content, headers={**auth, **headers})
        assert resp.status_code == 415, (template, resp.text)
        assert "application/json" in resp.json()["detail"]
    assert farm.calls == [] and store.sample_count() == before and store.baseline("sim") is None


def test_json_bodies_and_bodyless_posts_pass_the_type_check(store: Store) -> None:
    client = make_client(store, retrain_min_interval_seconds=0)  # retrains in a row below
    resp = client.post(
        "/api/v1/robots/sim/simulate/damage",
        content=b'{"kind": "imu_dead"}',
        headers={"content-type": "application/json; charset=utf-8"},
    )
    assert resp.status_code == 201
    # a body-less post says it is JSON or sends the intent header; with neither it is refused
    url = "/api/v1/robots/sim/topology/retrain"
    assert client.post(url, headers=INTENT).status_code == 202
    assert client.post(url, headers={"content-type": "application/json"}).status_code == 202
    resp = client.post(url)
    assert resp.status_code == 403 and "X-Requested-With: bodyhealth" in resp.json()["detail"]
    assert client.post(url, headers={"X-Requested-With": "XMLHttpRequest"}).status_code == 403


def test_untrusted_host_header_is_400(store: Store) -> None:
    client = make_client(store)
    for host in ("evil.example", "127.0.0.1.evil.example", "10.0.0.7"):
        resp = client.get("/api/v1/robots", headers={"host": host})
        assert resp.status_code == 400 and resp.text == "Invalid host header", host
    for host in ("localhost:8000", "127.0.0.1", "[::1]:8000", "testserver"):
        assert client.get("/api/v1/robots", headers={"host": host}).status_code == 200, host
    # the bind host is trusted by default; allowed_hosts replaces the list
    bound = make_client(store, host="10.0.0.7")
    assert bound.get("/api/v1/robots", headers={"host": "10.0.0.7:8000"}).status_code == 200
    assert Settings(host="0.0.0.0").trusted_hosts() == [
        "localhost",
        "127.0.0.1",
        "::1",
        "[::1]",
        "testserver",
    ]
    named = make_client(store, allowed_hosts="robots.lan, testserver")
    assert named.get("/api/v1/robots", headers={"host": "robots.lan"}).status_code == 200
    assert named.get("/api/v1/robots", headers={"host": "localhost"}).status_code == 400


def test_no_cors(store: Store) -> None:
    client = make_client(store)
    assert not [m for m in client.app.user_middleware if "cors" in m.cls.__name__.lower()]
    origin = {"Origin": "https://evil.example"}
    pre = client.options(
        "/api/v1/robots/sim/baseline", headers={**origin, "Access-Control-Request-Method": "POST"}
    )
    assert pre.status_code == 405 and "access-control-allow-origin" not in pre.headers
    got = client.get("/api/v1/robots", headers=origin)
    assert got.status_code == 200 and "access-control-allow-origin" not in got.headers


@pytest.mark.parametrize(
    ("settings", "reads", "writes"),
    [
        ({}, False, False),
        ({"api_token": WRITE}, True, True),
        ({"api_token": WRITE, "read_token_required": False}, False, True),
    ],
    ids=["no-token", "token", "token-open-reads"],
)
def test_openapi_declares_what_each_operation_needs(
    store: Store, settings: dict[str, Any], reads: bool, writes: bool
) -> None:
    """Per operation: the bearer scheme where a token is needed, an empty list where none is."""
    client = make_client(store, **settings)
    spec = client.get("/openapi.json").json()
    scheme = spec["components"]["securitySchemes"]["bearer"]
    assert (scheme["type"], scheme["scheme"]) == ("http", "bearer")
    n = 0
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            mutating = method.upper() in MUTATING_METHODS
            needed = path.startswith("/api/v1") and (writes if mutating else reads)
            assert op["security"] == ([{"bearer": []}] if needed else []), (method, path)
            if path.startswith("/api/v1"):
                assert "401" in op["responses"], (method, path)
                n += 1
            # and the answers agree with the document
            if needed and not mutating and "{" not in path:
                assert client.get(path).status_code == 401, path
    assert n == len(mutating_routes(client)) + len(read_routes(client))


def test_serve_refuses_a_network_address_without_a_token(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    for var in ("BODYHEALTH_API_TOKEN", "BODYHEALTH_API_TOKEN_FILE", "BODYHEALTH_API_READ_TOKEN"):
        monkeypatch.delenv(var, raising=False)
    reset_settings()
    try:
        for host in ("0.0.0.0", "::", "192.168.1.20", "robot-host.lan"):
            assert cli_main(["serve", "--host", host, "--database-url", "sqlite://"]) == 2, host
            err = capsys.readouterr().err
            assert f"refusing to listen on {host}" in err
            assert "BODYHEALTH_API_TOKEN=" in err and "BODYHEALTH_API_TOKEN_FILE=" in err
    finally:
        reset_settings()
    assert not (tmp_path / "var").exists()  # refused before anything was opened


def test_allowed_hosts_setting(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    assert Settings(allowed_hosts='["a.example", "*.robots.lan"]').trusted_hosts() == [
        "a.example",
        "*.robots.lan",
    ]
    assert Settings(host="fe80::1").trusted_hosts()[-2:] == ["fe80::1", "[fe80::1]"]
    for bad in ("a*b", "*x.org", "x.*"):
        with pytest.raises(ValueError, match="allowed_hosts"):
            Settings(allowed_hosts=bad)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BODYHEALTH_ALLOWED_HOSTS", "robots.lan, 10.0.0.5")
    reset_settings()
    try:
        assert get_settings().trusted_hosts() == ["robots.lan", "10.0.0.5"]
    finally:
        reset_settings()
