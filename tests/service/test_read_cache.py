"""The read routes' cache on a real store: a repeated read runs no SQL; after a commit of the store the
next read still gets the kept answer while one rendering runs off the request path, and the reads after
it get the new one; a write through the API is read at once; writers in another process are seen within
``api_cache_seconds``; concurrent requests share one rendering; errors are not kept; and
authentication still runs on every request."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from pydantic import SecretStr
from sqlalchemy import event

from service.api import create_app
from service.api.cache import ReadCache
from service.frames import FrameBatch
from service.settings import Settings
from service.store import Store, open_store
from tests.waits import cpu_bound

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


def _until(read: object, want: float, seconds: float = 5.0) -> float:
    """Poll ``read()`` until it gives ``want`` (a rendering in flight ends) or ``seconds`` pass."""
    deadline = time.monotonic() + seconds
    while (got := read()) != pytest.approx(want) and time.monotonic() < deadline:  # type: ignore[operator]
        time.sleep(0.01)
    return got


def test_a_commit_is_read_after_one_rendering_off_the_request_path(store: Store) -> None:
    c = client(store, api_cache_seconds=60.0)
    cache: ReadCache = c.app.state.read_cache  # type: ignore[attr-defined]

    def last_t() -> float:
        return c.get("/api/v1/robots/arm").json()["last_frame_t"]

    assert last_t() == pytest.approx(0.04)
    store.write(frames("arm", 1.0))  # the ingest writer's path
    assert last_t() == pytest.approx(0.04)  # the kept answer, while the new one renders
    assert cache.stale_hits == 1
    assert _until(last_t, 1.04) == pytest.approx(1.04)
    assert [r["name"] for r in c.get("/api/v1/robots").json()] == ["arm"]
    assert c.post("/api/v1/robots/b/frames", json=_body(2.0)).status_code == 201  # the API's own write
    assert [r["name"] for r in c.get("/api/v1/robots").json()] == ["arm", "b"]  # read at once
    assert c.post("/api/v1/robots/b/frames", json={"t": []}).status_code == 422  # a failed write
    assert cache._entries  # keeps what was kept


def test_concurrent_requests_share_one_rendering(store: Store) -> None:
    cache = ReadCache(store, max_age=60.0)
    calls: list[int] = []
    gate = threading.Event()

    def render() -> dict[str, int]:
        calls.append(store.generation)
        assert gate.wait(10)
        return {"generation": calls[-1]}

    async def burst(n: int) -> list[bytes]:
        tasks = [asyncio.create_task(cache.respond(("k",), render)) for _ in range(n)]
        await asyncio.sleep(0.05)
        gate.set()
        return [r.body for r in await asyncio.gather(*tasks)]

    g0 = store.generation
    assert asyncio.run(burst(20)) == [f'{{"generation":{g0}}}'.encode()] * 20
    assert calls == [g0]  # twenty waiting requests, one rendering
    gate.clear()
    store.write(frames("arm", 1.0))
    # after the commit: the kept answer at once, for every request, and one rendering in flight
    assert asyncio.run(burst(20)) == [f'{{"generation":{g0}}}'.encode()] * 20
    assert calls == [g0, g0 + 1]
    deadline = time.monotonic() + cpu_bound(5)
    while cache._inflight and time.monotonic() < deadline:
        time.sleep(0.01)
    assert asyncio.run(cache.respond(("k",), render)).body == f'{{"generation":{g0 + 1}}}'.encode()
    assert calls == [g0, g0 + 1]


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
    # The cache's own clock, set by hand. On the wall clock the test raced it: an entry's age counts
    # from when its rendering began, which a loaded machine puts well after the test's start, so the
    # read timed at max age + 50 ms from the start still found the entry young (beside two busy loops).
    max_age, now = 1.0, [0.0]
    c = client(store, api_cache_seconds=max_age)
    c.app.state.read_cache.clock = lambda: now[0]
    other = open_store(db)  # another store object: its commits do not move this store's count
    try:
        assert c.get("/api/v1/robots/arm").json()["last_frame_t"] == pytest.approx(0.04)
        other.write(frames("arm", 5.0))
    finally:
        other.close()
    now[0] = 0.4 * max_age  # young, and nothing committed through this store: the kept answer
    assert c.get("/api/v1/robots/arm").json()["last_frame_t"] == pytest.approx(0.04)
    now[0] = max_age + 0.05  # too old: rendered again, with the other writer's frames
    assert c.get("/api/v1/robots/arm").json()["last_frame_t"] == pytest.approx(5.04)


def test_a_status_is_judged_again_only_after_more_than_frames_was_committed(store: Store) -> None:
    from bodyschema.topology import Topology

    c = client(store, api_cache_seconds=60.0)
    learned: list[str] = []  # statements on what a status is judged from

    def seen(_conn: object, _cursor: object, sql: str, *_args: object) -> None:
        if any(f"FROM {t}" in sql for t in ("topologies", "baselines", "alerts")):
            learned.append(sql)

    def detail() -> dict:
        return c.get("/api/v1/robots/arm").json()

    assert detail()["has_baseline"] is False and c.get("/api/v1/robots/arm/status").status_code == 200
    generation = store.analysis_generation
    event.listen(store.engine, "before_cursor_execute", seen)
    try:
        store.write(frames("arm", 1.0))  # the ingest writer's commit: frames alone
        assert store.analysis_generation == generation
        assert _until(lambda: detail()["last_frame_t"], 1.04) == pytest.approx(1.04)  # rendered again
        assert learned == []  # ... with the status it had
        store.set_baseline("arm", Topology({"j1": None}, {"imu0": "j1"}), "operator")
        assert store.analysis_generation == generation + 1
        assert _until(lambda: detail()["has_baseline"], True) is True
        assert learned  # judged again
    finally:
        event.remove(store.engine, "before_cursor_execute", seen)


def test_zero_max_age_renders_every_request(store: Store) -> None:
    c, sql = client(store, api_cache_seconds=0.0), Statements(store)
    ran = []
    for _ in range(3):  # the first also looks the robot's id up (kept by the store, not the cache)
        before = sql.n
        c.get("/api/v1/robots")
        ran.append(sql.n - before)
    assert ran[0] >= ran[1] == ran[2] > 0


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


def test_a_robots_status_is_taken_from_the_fleets_while_no_more_than_frames_was_committed(
    store: Store,
) -> None:
    """The robot list judges every robot's status at once; a robot's own routes asked meanwhile take
    theirs from it instead of reading the store again, until more than frames is committed."""
    from bodyschema.topology import Topology

    store.write(frames("b", 0.0))
    store.set_baseline("arm", Topology({"j1": None}, {"imu0": "j1"}), "operator")
    c = client(store, api_cache_seconds=60.0)
    learned: list[str] = []

    def seen(_conn: object, _cursor: object, sql: str, *_args: object) -> None:
        if any(f"FROM {t}" in sql for t in ("topologies", "baselines", "alerts")):
            learned.append(sql)

    listed = {r["name"]: r for r in c.get("/api/v1/robots").json()}
    assert listed["arm"]["has_baseline"] is True and listed["b"]["has_baseline"] is False
    event.listen(store.engine, "before_cursor_execute", seen)
    try:
        assert c.get("/api/v1/robots/arm/status").json() == listed["arm"]["status"]
        assert c.get("/api/v1/robots/b").json() == listed["b"]
        assert learned == []  # both from the fleet's statuses
        store.write(frames("c", 0.0))  # a new robot: frames alone, and the list judges it too
        assert _until(lambda: len(c.get("/api/v1/robots").json()), 3) == 3
        assert c.get("/api/v1/robots").json()[2]["status"]["status"] == "undetermined"
        store.set_baseline("b", Topology({"j1": None}, {"imu0": "j1"}), "operator")
        learned.clear()
        assert c.get("/api/v1/robots/b/status").json()["has_baseline"] is True  # judged again
        assert learned
    finally:
        event.remove(store.engine, "before_cursor_execute", seen)


def test_answers_are_encoded_as_fastapi_encodes_them() -> None:
    """The cache writes a route's models with pydantic's serializer: the same bytes as FastAPI's
    ``jsonable_encoder`` and ``JSONResponse``, and a NaN still refused."""
    from fastapi.encoders import jsonable_encoder
    from fastapi.responses import JSONResponse

    from bodyschema.topology import Topology
    from service.api.cache import _encode
    from service.api.schemas import RobotOut, StatusOut
    from service.status import judge
    from service.store import RobotInfo

    topo = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j2"})
    info = RobotInfo(
        "arm-é", ["j1", "j2"], ["imu0", "imu1"], ["imu1"], 1.5e9, 2.5e-7, True, "ur5e", {"j1": 1e-5}
    )
    value = [RobotOut.of(info, True, 0, StatusOut.of(judge("arm-é", topo, topo))), {"x": (1, 2.0, None)}]
    assert _encode(value) == bytes(JSONResponse(jsonable_encoder(value)).body)
    with pytest.raises(ValueError):
        _encode({"loss": float("nan")})


def test_routes_that_read_by_name_look_the_robot_up_once(store: Store) -> None:
    """A robot's status, topology, history and alerts need only to know the robot exists (404
    otherwise): its id, remembered by the store, not its parts read again at every rendering."""
    c = client(store, api_cache_seconds=0.0)  # every request renders
    parts: list[str] = []

    def seen(_conn: object, _cursor: object, sql: str, *_args: object) -> None:
        if any(f"FROM {t}" in sql for t in ("robots", "joints", "imus")):
            parts.append(sql)

    paths = [
        "/api/v1/robots/arm/status",
        "/api/v1/robots/arm/topology",
        "/api/v1/robots/arm/topology/history",
        "/api/v1/robots/arm/alerts",
    ]
    assert all(c.get(p).status_code == 200 for p in paths)
    event.listen(store.engine, "before_cursor_execute", seen)
    try:
        assert [c.get(p).status_code for p in paths] == [200] * 4
        # what the worker waits on changes by the cycle: read alone, never the robot's parts
        assert [p for p in parts if not p.startswith("SELECT robots.name, robots.waiting ")] == []
        assert [c.get(p.replace("arm", "nobody")).status_code for p in paths] == [404] * 4
        store.write(frames("nobody", 0.0))
        assert [c.get(p.replace("arm", "nobody")).status_code for p in paths] == [200] * 4
    finally:
        event.remove(store.engine, "before_cursor_execute", seen)
