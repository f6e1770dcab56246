"""Input bounds of the API and of every frame batch: 64-bit alert ids, the one name pattern for robots,
joints and IMUs, finite non-negative device times without absurd jumps, error bodies that name fields
and never code, and the error statuses the OpenAPI document lists. A rejected batch loses nothing
accepted before it. Real app, real SQLite store in tmp_path."""

from __future__ import annotations

import inspect
import json
import re
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.api.schemas import DAMAGE_MODES, DAMAGE_PARAMS
from service.daemon import DEMO_ROBOTS
from service.frames import NAME_PATTERN, FrameBatch, FrameError, check_names
from service.ingest.farm import farm_robot_names
from service.ingest.pipeline import Pipeline
from service.settings import Settings
from service.store import Store
from tests.service.access import StrictFarm
from tests.service.builders import frame_batch, frames_body, simulated_store

SETTINGS = Settings(database_url="sqlite://")


@pytest.fixture
def store(tmp_path: Path) -> Iterator[Store]:
    s = simulated_store(tmp_path / "bounds.db")
    yield s
    s.close()


@pytest.fixture
def farm() -> StrictFarm:
    return StrictFarm()


@pytest.fixture
def client(store: Store, farm: StrictFarm) -> TestClient:
    # a client of the API: its body-less requests say so (tests/service/test_security_origin.py)
    return TestClient(
        create_app(store, settings=SETTINGS, damage=farm), headers={"X-Requested-With": "bodyhealth"}
    )


# ---------------------------------------------------------------------------------------- alert ids
@pytest.mark.parametrize("path", ["/api/v1/alerts/{id}/ack", "/api/v1/robots/sim/alerts/{id}/ack"])
def test_alert_ids_must_fit_a_signed_64_bit_key(client: TestClient, path: str) -> None:
    for bad in (2**63, 2**64 + 5, 0, -1):
        resp = client.post(path.format(id=bad))
        assert resp.status_code == 422, (bad, resp.text)
        (err,) = resp.json()["detail"]
        assert err["loc"] == ["path", "alert_id"]
        assert err["type"] in ("less_than_equal", "greater_than_equal")
    resp = client.post(path.format(id=2**63 - 1))
    assert resp.status_code == 404


# -------------------------------------------------------------------------------------------- names
BAD_NAMES = ["arm 2", "a" * 65, "ärm", "arm\n", "arm;rm", "arm:x", "<b>"]


@pytest.mark.parametrize("name", BAD_NAMES)
def test_robot_names_in_paths(client: TestClient, farm: StrictFarm, store: Store, name: str) -> None:
    r = quote(name, safe="")
    before = store.sample_count()
    for method, path, body in [
        ("GET", f"/api/v1/robots/{r}", None),
        ("GET", f"/api/v1/robots/{r}/status", None),
        ("GET", f"/api/v1/robots/{r}/topology", None),
        ("GET", f"/api/v1/robots/{r}/alerts", None),
        ("POST", f"/api/v1/robots/{r}/frames", frames_body()),
        ("POST", f"/api/v1/robots/{r}/baseline", None),
        ("POST", f"/api/v1/robots/{r}/simulate/damage", {"kind": "imu_dead"}),
        ("POST", f"/api/v1/robots/{r}/alerts/1/ack", None),
    ]:
        resp = client.request(method, path, json=body)
        assert resp.status_code == 422, (path, resp.text)
        errs = resp.json()["detail"]
        assert {
            "loc": ["path", "robot"],
            "msg": f"String should match pattern '{NAME_PATTERN}'",
            "type": "string_pattern_mismatch",
        } in errs, errs
    assert store.sample_count() == before and farm.calls == [] and [x.name for x in store.robots()] == ["sim"]


def test_longest_name_is_accepted(client: TestClient) -> None:
    name = "a" * 64
    assert client.get(f"/api/v1/robots/{name}").status_code == 404
    assert client.post(f"/api/v1/robots/{name}/frames", json=frames_body()).status_code == 201
    assert client.get(f"/api/v1/robots/{name}").json()["name"] == name


@pytest.mark.parametrize("field", ["joint_names", "imu_names"])
@pytest.mark.parametrize("name", ["j 1", "imu/0", "imu0\n", "", "x" * 65, "Gelenk-ä"])
def test_part_names_in_frame_bodies(client: TestClient, store: Store, field: str, name: str) -> None:
    body = frames_body()
    body[field] = [name, body[field][1]]
    resp = client.post("/api/v1/robots/arm/frames", json=body)
    assert resp.status_code == 422
    assert resp.json()["detail"] == [
        {
            "loc": ["body", field, 0],
            "msg": f"String should match pattern '{NAME_PATTERN}'",
            "type": "string_pattern_mismatch",
        }
    ]
    assert store.robot("arm") is None


@pytest.mark.parametrize("field", ["imu", "joint", "to"])
def test_part_names_in_damage_bodies(client: TestClient, farm: StrictFarm, field: str) -> None:
    kind = {"imu": "imu_dead", "joint": "joint_locked", "to": "imu_moved"}[field]
    resp = client.post("/api/v1/robots/sim/simulate/damage", json={"kind": kind, field: "imu 0"})
    assert resp.status_code == 422
    assert resp.json()["detail"][0]["loc"] == ["body", field]
    assert farm.calls == []


def test_sources_are_held_to_the_same_names(store: Store) -> None:
    """CAN, serial, farm and replay sources hand in FrameBatch objects: the check is in its validate(),
    which both the pipeline and the store run."""
    t = np.arange(3) * 0.01
    for b, what in [
        (frame_batch("arm 1", t), "robot name 'arm 1'"),
        (frame_batch("arm", t, joints=("j:1",)), "joint name 'j:1'"),
        (frame_batch("arm", t, imus=("imu0", "i" * 65)), "IMU name"),
    ]:
        with pytest.raises(FrameError, match=re.escape(what) + r".*is not allowed \(names: 1-64 characters"):
            b.validate()
        with pytest.raises(FrameError, match="is not allowed"):
            store.write(b)
        pipe = Pipeline(store, [], settings=SETTINGS)
        with pytest.raises(FrameError, match="is not allowed"):
            pipe.submit(b)
        assert pipe.counters()["api"]["malformed"] == 3
    assert store.robot("arm") is None and store.robot("arm 1") is None


def test_catalog_and_demo_robots_pass_the_name_check() -> None:
    from simulators.catalog import CATALOG
    from simulators.robot import Robot

    for name in CATALOG:
        r = Robot.from_catalog(name)
        check_names(name, r.joint_names, r.imu_names)  # raises if one fails
        assert len(r.imu_names) > 0 and len(r.joint_names) > 0
    demo = farm_robot_names(list(DEMO_ROBOTS))
    assert sorted(demo) == ["paper-3-1", "quadruped-1", "ur5e-1"]
    for name in demo:
        check_names(name, (), ())


# -------------------------------------------------------------------------------------------- times
def test_negative_and_non_finite_times_are_422(client: TestClient, store: Store) -> None:
    body = frames_body(3)
    body["t"] = [-0.02, -0.01, 0.0]
    resp = client.post("/api/v1/robots/arm/frames", json=body)
    assert resp.status_code == 422
    assert [(e["loc"], e["msg"]) for e in resp.json()["detail"]] == [
        (["body", "t", 0], "Input should be greater than or equal to 0"),
        (["body", "t", 1], "Input should be greater than or equal to 0"),
    ]
    for token in ("NaN", "Infinity", "-Infinity"):
        raw = json.dumps(frames_body(3)).replace('"t": [1.0', f'"t": [{token}')
        resp = client.post(
            "/api/v1/robots/arm/frames", content=raw, headers={"content-type": "application/json"}
        )
        assert resp.status_code == 422, token
        assert resp.json()["detail"][0]["loc"] == ["body", "t", 0]
    assert store.robot("arm") is None
    # Device sources are not held to it: a device clock may stamp its first samples a little before 0
    # (the sensing model's stamp jitter does), and those batches must not be lost.
    jittered = FrameBatch(
        "arm",
        np.array([0.0, 0.01]),
        ("j1",),
        np.zeros((3, 1)),
        ("imu0",),
        np.zeros((2, 1, 3)),
        np.zeros((2, 1, 3)),
        t_q=np.array([-0.0002, 0.004, 0.008]),
    )
    assert store.write(jittered) == 2


def test_a_jump_far_ahead_of_the_last_frame_is_422(store: Store) -> None:
    client = TestClient(
        create_app(store, settings=Settings(database_url="sqlite://", max_time_jump_seconds=10))
    )
    url = "/api/v1/robots/arm/frames"
    assert (
        client.post(url, json=frames_body(5, t0=1000.0)).status_code == 201
    )  # a new robot may start anywhere
    last = store.robot("arm").last_frame_t
    resp = client.post(url, json=frames_body(5, t0=last + 10.5))
    assert resp.status_code == 422
    assert resp.json()["detail"] == (
        "t jumps 10.54 s ahead of the robot's newest stored frame (t = 1000.04 s); "
        "at most max_time_jump_seconds = 10 s is accepted"
    )
    assert store.robot("arm").last_frame_t == last
    assert client.post(url, json=frames_body(5, t0=last + 9.0)).status_code == 201
    # earlier device time is no jump: a restarted clock is stored (a new epoch), and the bound then
    # counts from the new epoch's newest frame; overlaps within it are stored as before
    assert client.post(url, json=frames_body(5, t0=0.0)).status_code == 201
    assert store.robot("arm").epoch == 1
    assert client.post(url, json=frames_body(5, t0=1000.02)).status_code == 422
    assert client.post(url, json=frames_body(5, t0=0.02)).status_code == 201
    assert store.sample_count("arm") == 20


def test_default_jump_bound_is_a_million_seconds(client: TestClient, store: Store) -> None:
    assert SETTINGS.max_time_jump_seconds == 1e6
    url = "/api/v1/robots/arm/frames"
    assert client.post(url, json=frames_body(5, t0=0.0)).status_code == 201
    assert client.post(url, json=frames_body(5, t0=9e5)).status_code == 201
    resp = client.post(url, json=frames_body(5, t0=9e5 + 1.1e6))
    assert resp.status_code == 422 and "max_time_jump_seconds = 1e+06 s" in resp.json()["detail"]


def test_a_rejected_batch_loses_nothing_accepted_before(client: TestClient, store: Store) -> None:
    good = frames_body(50, t0=2.0, seed=7)
    assert client.post("/api/v1/robots/arm/frames", json=good).status_code == 201
    bads: list[tuple[dict[str, Any], int]] = []
    for change in (
        {"t": [3.0, -1.0, 3.5]},  # negative
        {"t": [3.0, 2.99, 3.5]},  # backwards within the batch
        {"t": [3.0, 3.01, 5e6]},  # a jump
        {"imu_names": ["imu0", "imu 1"]},  # a bad name
        {"acc": [[[0.0, 0.0]] * 2] * 3},  # a wrong shape
        {"q": [[0.0, 0.0], [0.0], [0.0, 0.0]]},  # ragged rows
        {"extra": 1},  # an unknown field
    ):
        bads.append(({**frames_body(3, t0=3.0, seed=8), **change}, 422))
    for body, code in bads:
        resp = client.post("/api/v1/robots/arm/frames", json=body)
        assert resp.status_code == code, (body, resp.text)
    form = client.post("/api/v1/robots/arm/frames", content=b"t=1", headers={"content-type": "text/plain"})
    assert form.status_code == 415
    rec = store.read_between("arm", 0.0, 1e7)
    np.testing.assert_array_equal(rec.t, good["t"])
    np.testing.assert_array_equal(rec.q, good["q"])
    np.testing.assert_array_equal(rec.acc, good["acc"])
    np.testing.assert_array_equal(rec.gyro, good["gyro"])
    assert store.sample_count("arm") == 50 and store.robot("arm").last_frame_t == good["t"][-1]


# --------------------------------------------------------------------------------- error bodies
CODE_NAME = re.compile(
    r"[A-Za-z_][\w.]*\(\)|Traceback|File \"|\bservice\.|\bsimulators\.|\bbodyschema\.|0x[0-9a-f]{6,}"
)
MALFORMED: list[bytes] = [
    b"{not json",
    b"[]",
    b"null",
    b'"text"',
    b"{}",
    b'{"t": "abc"}',
    b'{"kind": 5}',
    b'{"kind": "imu_dead", "to": "j1"}',
    b'{"kind": "imu_moved", "value": 1.0}',
    b'{"kind": "encoder_fault", "mode": "zero"}',
    b'{"t": [1, 2], "joint_names": ["j"], "q": [[0], [0, 1]], "imu_names": [], '
    b'"acc": [[], []], "gyro": [[], []]}',
    b'{"t": [1, 2], "joint_names": ["j"], "q": [[0], [1]], "imu_names": ["i"], '
    b'"acc": [[[1]], [[1]]], "gyro": 1}',
]


def test_error_bodies_name_fields_never_code(client: TestClient, store: Store) -> None:
    paths = [
        "/api/v1/robots/sim/frames",
        "/api/v1/robots/sim/simulate/damage",
        "/api/v1/robots/sim/baseline",
        "/api/v1/robots/sim/topology/retrain?method=magic",
        "/api/v1/alerts/abc/ack",
        "/api/v1/robots/sim/alerts/99999999999999999999/ack",
    ]
    seen: set[int] = set()
    for path in paths:
        for raw in MALFORMED:
            resp = client.post(path, content=raw, headers={"content-type": "application/json"})
            seen.add(resp.status_code)
            assert 400 <= resp.status_code < 500, (path, raw, resp.text)
            assert not CODE_NAME.search(resp.text), (path, raw, resp.text)
            detail = resp.json()["detail"]
            if resp.status_code == 422 and isinstance(detail, list):
                for e in detail:
                    assert set(e) == {"loc", "msg", "type"} and e["loc"][0] in ("path", "query", "body")
    assert seen == {409, 422}


def test_damage_arguments_the_simulator_does_not_take_are_422_with_the_kinds_list(
    client: TestClient, farm: StrictFarm
) -> None:
    resp = client.post("/api/v1/robots/sim/simulate/damage", json={"kind": "imu_dead", "to": "j1"})
    assert resp.status_code == 422
    (err,) = resp.json()["detail"]
    assert (
        err["loc"] == ["body"]
        and err["msg"] == "Value error, imu_dead takes imu, mode; to is not one of them"
    )
    resp = client.post("/api/v1/robots/sim/simulate/damage", json={"kind": "encoder_fault", "mode": "zero"})
    assert resp.json()["detail"][0]["msg"] == "Value error, encoder_fault mode must be one of stuck, offset"
    assert farm.calls == []
    # a farm message that names code is replaced, one that does not is passed on
    resp = client.post("/api/v1/robots/sim/simulate/damage", json={"kind": "link_lost"})
    assert resp.status_code == 422 and resp.json() == {"detail": "bad arguments for link_lost"}


def test_damage_parameters_match_the_simulator() -> None:
    from simulators.damage import _HANDLERS, DAMAGES, DRIFT_DAMAGES

    assert set(DAMAGE_PARAMS) == set(DAMAGES) | set(DRIFT_DAMAGES)
    for kind in DAMAGE_PARAMS:
        params = tuple(p for p in inspect.signature(_HANDLERS[kind]).parameters if p != "sim")
        assert sorted(DAMAGE_PARAMS[kind]) == sorted(params), kind
    assert set(DAMAGE_MODES) <= set(DAMAGE_PARAMS)


def test_real_farm_arguments_error_is_clean(store: Store) -> None:
    """The real simulator behind the route: a wrong argument used to come back as
    ``_imu_dead() got an unexpected keyword argument``."""
    from simulators.farm import Farm as SimFarm

    sim = SimFarm({"sim": "paper-3"}, seed=0)

    class Real:
        def simulates(self, robot: str) -> bool:
            return robot == "sim"

        def apply_damage(self, robot: str, kind: str, params: Mapping[str, Any]) -> dict[str, Any]:
            return sim.apply_damage(robot, kind, **params).to_json()

    c = TestClient(create_app(store, settings=SETTINGS, damage=Real()))
    for body in ({"kind": "imu_dead", "to": "j1"}, {"kind": "joint_locked", "tether": 0.1}):
        resp = c.post("/api/v1/robots/sim/simulate/damage", json=body)
        assert resp.status_code == 422 and not CODE_NAME.search(resp.text), resp.text
    resp = c.post("/api/v1/robots/sim/simulate/damage", json={"kind": "imu_dead", "imu": "imu999"})
    assert resp.status_code == 422 and resp.json() == {"detail": "unknown IMU 'imu999'"}
    resp = c.post("/api/v1/robots/sim/simulate/damage", json={"kind": "imu_dead", "imu": "imu3"})
    assert resp.status_code == 201 and resp.json()["truth"]["findings"][0]["imu"] == "imu3"


# ---------------------------------------------------------------------------------------- OpenAPI
EXPECTED: dict[tuple[str, str], set[str]] = {
    ("get", "/api/v1/robots"): {"401", "503"},
    ("get", "/api/v1/robots/{robot}"): {"401", "404", "422", "503"},
    ("post", "/api/v1/robots/{robot}/frames"): {"401", "403", "413", "415", "422", "503"},
    ("get", "/api/v1/robots/{robot}/status"): {"401", "404", "422", "503"},
    ("get", "/api/v1/robots/{robot}/topology"): {"401", "404", "422", "503"},
    ("get", "/api/v1/robots/{robot}/topology/history"): {"401", "404", "422", "503"},
    ("post", "/api/v1/robots/{robot}/topology/retrain"): {
        "401",
        "403",
        "404",
        "409",
        "413",
        "415",
        "422",
        "429",
        "503",
    },
    ("post", "/api/v1/robots/{robot}/baseline"): {"401", "403", "404", "409", "413", "415", "422", "503"},
    ("get", "/api/v1/alerts"): {"401", "422", "503"},
    ("get", "/api/v1/robots/{robot}/alerts"): {"401", "404", "422", "503"},
    ("post", "/api/v1/alerts/{alert_id}/ack"): {"401", "403", "404", "413", "415", "422", "503"},
    ("post", "/api/v1/robots/{robot}/alerts/{alert_id}/ack"): {
        "401",
        "403",
        "404",
        "413",
        "415",
        "422",
        "503",
    },
    ("post", "/api/v1/robots/{robot}/simulate/damage"): {
        "401",
        "403",
        "404",
        "409",
        "413",
        "415",
        "422",
        "503",
    },
    ("get", "/readyz"): {"503"},
}


def test_openapi_lists_the_error_statuses_of_each_route(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    ops = {(m, p): op for p, item in spec["paths"].items() for m, op in item.items()}
    assert set(EXPECTED) <= set(ops)
    for key, codes in EXPECTED.items():
        errors = {c for c in ops[key]["responses"] if c.startswith(("4", "5"))}
        assert errors == codes, (key, errors)
        for c in codes:
            assert ops[key]["responses"][c]["description"], (key, c)
    # every error body is {"detail": ...}
    schemas = spec["components"]["schemas"]
    assert set(schemas["ErrorOut"]["properties"]) == {"detail"}
    assert set(schemas["FieldError"]["properties"]) == {"loc", "msg", "type"}
    # the name pattern and the alert id bound are in the document too
    params = {
        p["name"]: p["schema"]
        for p in ops[("post", "/api/v1/robots/{robot}/alerts/{alert_id}/ack")]["parameters"]
    }
    assert params["robot"]["pattern"] == NAME_PATTERN
    assert (params["alert_id"]["minimum"], params["alert_id"]["maximum"]) == (1, 2**63 - 1)
