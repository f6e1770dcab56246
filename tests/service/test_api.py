"""The REST API on a real store: resources, error codes (404/409/413/422), OpenAPI, readiness, metrics."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from bodyschema.topology import Topology
from service.api import create_app
from service.control import DamageControl
from service.frames import FrameBatch
from service.ingest.base import Counters
from service.metrics import Metrics
from service.settings import Settings
from service.store import Store, open_store
from service.worker import Worker
from tests.service.builders import batch
from tests.service.geometry import geometry_json

TOPO = Topology(
    {"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j2"}, method="fast", excitation={"j1": 0.4, "j2": 0.3}
)
MOVED = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j1"}, method="fast")


class RecordingFarm:
    """A :class:`~service.control.DamageControl` that simulates robot ``sim`` and records what the API
    passed through (the real farm behind the same protocol is tested in test_pipeline_sources.py)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, str, dict[str, Any]]] = []

    def simulates(self, robot: str) -> bool:
        return robot == "sim"

    def apply_damage(self, robot: str, kind: str, params: Mapping[str, Any]) -> dict[str, Any]:
        params = dict(params)
        if params.get("imu") == "nope":
            raise ValueError("no IMU named 'nope' on this robot")
        self.calls.append((robot, kind, params))
        return {"changed": True, "findings": [{"kind": kind, **params, "confidence": 1.0}]}


#: Every read renders what the store holds now; the read cache has its own tests (test_read_cache.py).
SETTINGS = Settings(
    database_url="sqlite://", max_request_bytes=20_000, worker_interval_seconds=1.0, api_cache_seconds=0.0
)


@pytest.fixture
def sstore(tmp_path: Path) -> Iterator[Store]:
    s = open_store(f"sqlite:///{tmp_path / 'api.db'}")
    yield s
    s.close()


@pytest.fixture
def farm() -> RecordingFarm:
    return RecordingFarm()


@pytest.fixture
def client(sstore: Store, farm: RecordingFarm) -> Iterator[TestClient]:
    sstore.write(batch("arm"))
    sstore.write(batch("sim"))
    sstore.mark_simulated("sim", "ur5e")
    app = create_app(sstore, settings=SETTINGS, damage=farm)
    with TestClient(app, headers={"X-Requested-With": "bodyhealth"}) as c:
        yield c


def test_robots_topology_alerts_on_each_database(store: Store) -> None:
    store.write(batch("arm"))
    c = TestClient(create_app(store, settings=SETTINGS))
    (r,) = c.get("/api/v1/robots").json()
    assert (r["name"], r["joints"], r["imus"], r["last_frame_t"]) == (
        "arm",
        ["j1", "j2"],
        ["imu0", "imu1"],
        pytest.approx(0.19),
    )
    assert r["has_baseline"] is False and r["simulated"] is False
    assert c.get("/api/v1/robots/arm/topology").json()["current"] is None
    store.save_topology("arm", TOPO, 100.0, 0.19)
    store.set_baseline("arm", TOPO, "auto")
    store.save_topology("arm", MOVED, 101.0, 0.19)
    body = c.get("/api/v1/robots/arm/topology").json()
    assert body["baseline"]["imus"] == {"imu0": "j1", "imu1": "j2"}
    assert body["current"]["imus"] == {"imu0": "j1", "imu1": "j1"}
    assert body["diff"]["findings"][0]["kind"] == "imu_moved"
    hist = c.get("/api/v1/robots/arm/topology/history").json()
    assert [h["wall_time"] for h in hist] == [101.0, 100.0]
    a = store.upsert_alert(
        "arm", "imu_moved", "imu:imu1", {"kind": "imu_moved", "imu": "imu1"}, "active", 5.0
    )
    (got,) = c.get("/api/v1/alerts", params={"active": "true"}).json()
    assert (got["id"], got["kind"], got["imu"], got["joint"], got["state"], got["raised_at"]) == (
        a.id,
        "imu_moved",
        "imu1",
        None,
        "active",
        5.0,
    )


def test_robot_detail_and_unknown_robot(client: TestClient) -> None:
    r = client.get("/api/v1/robots/sim").json()
    assert r["simulated"] is True and r["catalog"] == "ur5e"
    # nothing learned yet: the robot resource says so instead of a verdict
    assert r["status"]["status"] == "undetermined" and r["status"]["trees_fit"] is None
    for path in (
        "/api/v1/robots/nope",
        "/api/v1/robots/nope/topology",
        "/api/v1/robots/nope/alerts",
        "/api/v1/robots/nope/topology/history",
    ):
        resp = client.get(path)
        assert resp.status_code == 404, path
        assert "nope" in resp.json()["detail"]
    assert client.post("/api/v1/robots/nope/baseline").status_code == 404


def test_operator_baseline(client: TestClient, sstore: Store) -> None:
    resp = client.post("/api/v1/robots/arm/baseline")
    assert resp.status_code == 409 and "no topology" in resp.json()["detail"]
    sstore.save_topology("arm", MOVED, 100.0, 0.19)
    sstore.upsert_alert("arm", "imu_moved", "imu:imu1", {"kind": "imu_moved", "imu": "imu1"}, "active", 1.0)
    resp = client.post("/api/v1/robots/arm/baseline")
    assert resp.status_code == 200 and resp.json()["source"] == "operator"
    assert sstore.baseline("arm").topology.same_structure(MOVED)
    assert [a.state for a in sstore.alerts("arm")] == ["resolved"]


def test_operator_baseline_through_worker_resolves_alerts(sstore: Store) -> None:
    sstore.write(batch("arm"))
    sstore.save_topology("arm", MOVED, 100.0, 0.19)
    a = sstore.upsert_alert("arm", "imu_moved", "imu:imu1", {"kind": "imu_moved", "imu": "imu1"}, "active", 1)
    w = Worker(sstore, SETTINGS, estimator=lambda rec, m: TOPO)
    c = TestClient(
        create_app(sstore, settings=SETTINGS, worker=w), headers={"X-Requested-With": "bodyhealth"}
    )
    assert c.post("/api/v1/robots/arm/baseline").status_code == 200
    assert c.get("/api/v1/robots/arm/alerts?active=true").json() == []
    assert [x["state"] for x in c.get("/api/v1/robots/arm/alerts").json()] == ["resolved"]
    assert c.post("/api/v1/robots/arm/topology/retrain", params={"method": "mlp"}).status_code == 202
    assert w._requests == {"arm": {"mlp"}}
    assert c.post("/api/v1/robots/arm/topology/retrain", params={"method": "magic"}).status_code == 422
    assert a.id > 0


def test_alert_filters_and_ack(client: TestClient, sstore: Store) -> None:
    a1 = sstore.upsert_alert(
        "arm", "imu_dead", "imu:imu0", {"kind": "imu_dead", "imu": "imu0"}, "active", 1.0
    )
    a2 = sstore.upsert_alert("sim", "joint_locked", "joint:j2", {"kind": "joint_locked"}, "active", 2.0)
    sstore.upsert_alert("sim", "joint_locked", "joint:j2", {"kind": "joint_locked"}, "resolved", 3.0)
    assert [a["id"] for a in client.get("/api/v1/alerts?active=true").json()] == [a1.id]
    assert [a["state"] for a in client.get("/api/v1/robots/sim/alerts").json()] == ["resolved"]
    assert client.get("/api/v1/robots/sim/alerts?active=true").json() == []
    resp = client.post(f"/api/v1/alerts/{a1.id}/ack")
    assert resp.status_code == 200 and resp.json()["acked"] is True
    assert client.post("/api/v1/alerts/99999/ack").status_code == 404
    # an alert id of another robot is not this robot's
    assert client.post(f"/api/v1/robots/arm/alerts/{a2.id}/ack").status_code == 404
    assert client.post(f"/api/v1/robots/sim/alerts/{a2.id}/ack").json()["acked"] is True
    assert client.get("/api/v1/alerts?active=maybe").status_code == 422
    assert client.post("/api/v1/alerts/abc/ack").status_code == 422


def test_damage_on_a_simulated_robot(client: TestClient, farm: RecordingFarm) -> None:
    assert isinstance(farm, DamageControl)
    resp = client.post(
        "/api/v1/robots/sim/simulate/damage", json={"kind": "imu_moved", "imu": "imu1", "to": "j1"}
    )
    assert resp.status_code == 201, resp.text
    assert resp.json()["truth"]["findings"][0]["kind"] == "imu_moved"
    assert farm.calls == [("sim", "imu_moved", {"imu": "imu1", "to": "j1"})]
    # a real robot: 409; unknown robot: 404; unknown kind, NaN, extra field, bad part: 422
    assert client.post("/api/v1/robots/arm/simulate/damage", json={"kind": "imu_dead"}).status_code == 409
    assert client.post("/api/v1/robots/nope/simulate/damage", json={"kind": "imu_dead"}).status_code == 404
    bad = client.post("/api/v1/robots/sim/simulate/damage", json={"kind": "melted"})
    assert bad.status_code == 422 and "imu_moved" in bad.text
    nan = client.post(
        "/api/v1/robots/sim/simulate/damage",
        content=b'{"kind": "encoder_fault", "value": NaN}',
        headers={"content-type": "application/json"},
    )
    assert nan.status_code == 422
    inf = client.post(
        "/api/v1/robots/sim/simulate/damage",
        content=b'{"kind": "encoder_fault", "value": Infinity}',
        headers={"content-type": "application/json"},
    )
    assert inf.status_code == 422
    assert (
        client.post(
            "/api/v1/robots/sim/simulate/damage", json={"kind": "imu_dead", "colour": "red"}
        ).status_code
        == 422
    )
    part = client.post("/api/v1/robots/sim/simulate/damage", json={"kind": "imu_dead", "imu": "nope"})
    assert part.status_code == 422 and "nope" in part.json()["detail"]
    assert (
        client.post(
            "/api/v1/robots/sim/simulate/damage",
            content=b"{not json",
            headers={"content-type": "application/json"},
        ).status_code
        == 422
    )
    assert len(farm.calls) == 1


def test_drift_damage_takes_its_magnitude(client: TestClient, farm: RecordingFarm) -> None:
    """The geometry drifts are injectable with their magnitudes; each kind refuses another's."""
    url = "/api/v1/robots/sim/simulate/damage"
    bodies = [
        {"kind": "imu_rotated", "imu": "imu1", "angle_deg": 2.0, "about": [0.0, 1.0, 0.0]},
        {"kind": "imu_shifted", "imu": "imu0", "meters": 0.005},
        {"kind": "axis_changed", "joint": "j2", "angle_deg": 2.5},
        {"kind": "backlash", "joint": "j1", "deg": 1.0},
    ]
    for body in bodies:
        r = client.post(url, json=body)
        assert r.status_code == 201, r.text
    assert farm.calls == [("sim", b.pop("kind"), b) for b in [dict(b) for b in bodies]]
    for body, words in [
        ({"kind": "imu_shifted", "angle_deg": 2.0}, "imu_shifted takes imu, meters"),
        ({"kind": "backlash", "deg": 0.0}, "greater than 0"),
        ({"kind": "imu_rotated", "angle_deg": 91.0}, "less than or equal to 90"),
        ({"kind": "imu_rotated", "about": [0.0, 0.0, 0.0]}, "nonzero"),
        ({"kind": "imu_rotated", "about": [1.0, 0.0]}, "at least 3"),
        ({"kind": "imu_shifted", "meters": 0.5}, "less than or equal to 0.2"),
    ]:
        r = client.post(url, json=body)
        assert r.status_code == 422 and words in r.text, (body, r.text)
    assert len(farm.calls) == len(bodies)
    schema = client.get("/openapi.json").json()["components"]["schemas"]["DamageIn"]
    assert {"imu_rotated", "imu_shifted", "axis_changed", "backlash"} <= set(
        schema["properties"]["kind"]["enum"]
    )


def test_drift_damage_reaches_the_simulated_robot(sstore: Store) -> None:
    """Through the real farm: each drift changes the running simulation by the magnitude asked."""
    import math

    from service.ingest.farm import FarmDamage, FarmSource
    from simulators.farm import Farm

    farm = Farm({"ur5e-1": "ur5e"}, seed=0, sensing="robot")
    sstore.write(batch("ur5e-1"))
    sstore.mark_simulated("ur5e-1", "ur5e")
    c = TestClient(create_app(sstore, settings=SETTINGS, damage=FarmDamage([FarmSource(farm)])))
    sim = farm.simulation("ur5e-1")
    url = "/api/v1/robots/ur5e-1/simulate/damage"
    before = sim.robot.model.site("imu3").quat.copy()
    r = c.post(url, json={"kind": "imu_rotated", "imu": "imu3", "angle_deg": 2.5})
    assert r.status_code == 201, r.text
    assert r.json()["truth"]["findings"][0]["detail"] == "turned 2.5 deg"
    turn = 2 * math.degrees(math.acos(min(1.0, abs(float(before @ sim.robot.model.site("imu3").quat)))))
    assert turn == pytest.approx(2.5, abs=1e-6)
    pos = sim.robot.model.site("imu5").pos.copy()
    r = c.post(url, json={"kind": "imu_shifted", "imu": "imu5", "meters": 0.004})
    assert r.status_code == 201 and r.json()["truth"]["findings"][0]["detail"] == "slid 4 mm"
    assert float(np.linalg.norm(sim.robot.model.site("imu5").pos - pos)) == pytest.approx(0.004, abs=1e-9)
    r = c.post(url, json={"kind": "backlash", "joint": "wrist_2", "deg": 0.5})
    assert r.status_code == 201
    assert sim.encoder_faults["wrist_2"] == ("backlash", pytest.approx(math.radians(0.5)))
    axis = sim.robot.model.joint("wrist_1").axis.copy()
    r = c.post(url, json={"kind": "axis_changed", "joint": "wrist_1", "angle_deg": 3.0})
    assert r.status_code == 201 and r.json()["truth"]["findings"][0]["detail"] == "bent 3 deg"
    bent = math.degrees(math.acos(float(axis @ sim.robot.model.joint("wrist_1").axis)))
    assert bent == pytest.approx(3.0, abs=1e-4)
    r = c.post(url, json={"kind": "backlash", "joint": "nope", "deg": 0.5})
    assert r.status_code == 422


def test_kinematics_before_and_after_geometry_is_learned(client: TestClient, sstore: Store) -> None:
    """No baseline: nothing to serve (200 with nulls; the URDF 404). With a kept geometry and a newer
    estimate whose IMU axis turned 90°, the drift names that IMU; the URDF is served from either."""
    empty = client.get("/api/v1/robots/arm/kinematics")
    assert empty.status_code == 200 and empty.json() == {"baseline": None, "latest": None, "drift": None}
    assert client.get("/api/v1/robots/arm/kinematics/urdf").status_code == 404
    assert client.get("/api/v1/robots/nope/kinematics").status_code == 404
    assert client.get("/api/v1/robots/arm/kinematics/urdf?which=first").status_code == 422

    base_id = sstore.set_baseline("arm", TOPO, "operator", wall_time=1.0)

    sstore.save_kinematics("arm", base_id, geometry_json(TOPO), wall_time=2.0, window_end_t=30.0)
    only = client.get("/api/v1/robots/arm/kinematics").json()
    assert only["baseline"]["id"] == only["latest"]["id"] and only["drift"] is None
    sstore.save_kinematics(
        "arm",
        base_id,
        geometry_json(TOPO, {"imu1": [0.0, 1.0, 0.0]}),
        wall_time=3.0,
        window_end_t=60.0,
        latest=True,
    )
    body = client.get("/api/v1/robots/arm/kinematics").json()
    assert body["baseline"]["baseline_id"] == body["latest"]["baseline_id"] == base_id
    assert (body["baseline"]["window_end_t"], body["latest"]["window_end_t"]) == (30.0, 60.0)
    assert body["latest"]["kinematics"]["imus"]["imu1"]["axis"] == [0.0, 1.0, 0.0]
    assert [(f["kind"], f.get("imu")) for f in body["drift"]] == [("imu_rotated", "imu1")]
    urdf = client.get("/api/v1/robots/arm/kinematics/urdf")
    assert urdf.status_code == 200 and urdf.headers["content-type"].startswith("application/xml")
    assert '<robot name="arm">' in urdf.text and urdf.text.count('type="revolute"') == 2
    assert '<axis xyz="0 1 0"/>' in urdf.text
    first = client.get("/api/v1/robots/arm/kinematics/urdf", params={"which": "baseline"}).text
    assert '<axis xyz="0 1 0"/>' not in first and '<axis xyz="0 0 1"/>' in first


def test_kinematics_drift_judges_slides_on_the_kept_pools(client: TestClient, sstore: Store) -> None:
    """The kept rows carry their lever-arm pools: the drift served is the worker's comparison of both
    (a slide of imu1 the single estimates cannot tell), and the pools themselves are not served, only
    how many estimates each holds."""
    rng = np.random.default_rng(0)

    def pool(n: int, slide: float) -> list[dict[str, list[float]]]:
        return [
            {
                name: (
                    np.array([0.1, slide if name == "imu1" else 0.0, 0.0]) + rng.normal(0, 0.002, 3)
                ).tolist()
                for name in TOPO.imu_joint
            }
            for _ in range(n)
        ]

    base_id = sstore.set_baseline("arm", TOPO, "operator", wall_time=1.0)
    first = {**geometry_json(TOPO), "lever_arm_pool": pool(80, 0.0)}
    sstore.save_kinematics("arm", base_id, first, wall_time=2.0, window_end_t=30.0)
    latest = {**geometry_json(TOPO), "lever_arm_pool": pool(40, 0.008)}
    sstore.save_kinematics("arm", base_id, latest, wall_time=3.0, window_end_t=60.0, latest=True)
    body = client.get("/api/v1/robots/arm/kinematics").json()
    assert [(f["kind"], f.get("imu")) for f in body["drift"]] == [("imu_shifted", "imu1")]
    assert "mean of the last 40 estimates but the farthest against 80" in body["drift"][0]["detail"]
    assert (body["baseline"]["pooled_estimates"], body["latest"]["pooled_estimates"]) == (80, 40)
    assert "lever_arm_pool" not in body["baseline"]["kinematics"]
    assert "lever_arm_pool" not in body["latest"]["kinematics"]


def test_damage_without_a_farm_is_409(sstore: Store) -> None:
    sstore.write(batch("sim"))
    sstore.mark_simulated("sim", "ur5e")
    c = TestClient(create_app(sstore, settings=SETTINGS))
    assert c.post("/api/v1/robots/sim/simulate/damage", json={"kind": "imu_dead"}).status_code == 409


def _frames_body(n: int, robot_value: float = 0.0) -> dict[str, Any]:
    return {
        "t": [10 + k * 0.01 for k in range(n)],
        "joint_names": ["j1", "j2"],
        "q": [[robot_value, 0.0]] * n,
        "imu_names": ["imu0", "imu1"],
        "acc": [[[0, 0, 9.81]] * 2] * n,
        "gyro": [[[0, 0, 0]] * 2] * n,
    }


def test_frames_push_and_bad_frames(client: TestClient, sstore: Store) -> None:
    before = sstore.sample_count("arm")
    resp = client.post("/api/v1/robots/arm/frames", json=_frames_body(10))
    assert resp.status_code == 201 and resp.json() == {"stored": 10}
    assert sstore.sample_count("arm") == before + 10
    # NaN in a value, a wrong shape, time going backwards: 422, and nothing stored
    nan = json.dumps(_frames_body(3)).replace("9.81", "NaN", 1)
    assert (
        client.post(
            "/api/v1/robots/arm/frames", content=nan, headers={"content-type": "application/json"}
        ).status_code
        == 422
    )
    bad = _frames_body(3)
    bad["acc"] = [[[0, 0]] * 2] * 3
    r = client.post("/api/v1/robots/arm/frames", json=bad)
    assert r.status_code == 422
    back = _frames_body(3)
    back["t"] = [3.0, 2.0, 1.0]
    r = client.post("/api/v1/robots/arm/frames", json=back)
    assert r.status_code == 422 and "increasing" in r.json()["detail"]
    assert sstore.sample_count("arm") == before + 10


def test_frames_with_channels_are_stored_and_bad_channels_refused(client: TestClient, sstore: Store) -> None:
    body = {**_frames_body(4), "channel_names": ["lf_force_z"], "channels": [[0.0], [120.5], [300.0], [2.0]]}
    assert client.post("/api/v1/robots/walker/frames", json=body).status_code == 201
    w = sstore.read_between("walker", -math.inf, math.inf)
    assert w is not None and list(w.extra["lf_force_z"]) == [0.0, 120.5, 300.0, 2.0]
    later = [10.04 + k * 0.01 for k in range(4)]
    for change, status in [
        ({"channels": None}, 422),  # names without values
        ({"channel_names": []}, 422),  # values without names
        ({"channels": [[0.0, 1.0]] * 4}, 422),  # a column too many
        ({"channels": [[2e6]] * 4}, 422),  # beyond the bound
        ({"channel_names": ["lf force"]}, 422),
    ]:
        r = client.post("/api/v1/robots/walker/frames", json={**body, "t": later, **change})
        assert r.status_code == status, (change, r.text)
    assert sstore.sample_count("walker") == 4


def test_oversized_body_is_413(client: TestClient, sstore: Store) -> None:
    before = sstore.sample_count()
    big = _frames_body(400)  # ~30 kB > 20 kB limit
    resp = client.post("/api/v1/robots/arm/frames", json=big)
    assert resp.status_code == 413 and "20000" in resp.json()["detail"]

    def chunks() -> Iterator[bytes]:  # no Content-Length: the streamed size is counted
        data = json.dumps(big).encode()
        for k in range(0, len(data), 4096):
            yield data[k : k + 4096]

    resp = client.post(
        "/api/v1/robots/arm/frames", content=chunks(), headers={"content-type": "application/json"}
    )
    assert resp.status_code == 413
    assert sstore.sample_count() == before
    assert client.post("/api/v1/robots/arm/frames", json=_frames_body(5)).status_code == 201


def test_openapi_and_docs(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    for path in (
        "/api/v1/robots",
        "/api/v1/robots/{robot}",
        "/api/v1/robots/{robot}/status",
        "/api/v1/robots/{robot}/topology",
        "/api/v1/robots/{robot}/topology/history",
        "/api/v1/robots/{robot}/baseline",
        "/api/v1/robots/{robot}/alerts",
        "/api/v1/alerts",
        "/api/v1/alerts/{alert_id}/ack",
        "/api/v1/robots/{robot}/simulate/damage",
        "/api/v1/robots/{robot}/kinematics",
        "/api/v1/robots/{robot}/kinematics/urdf",
        "/livez",
        "/readyz",
        "/metrics",
    ):
        assert path in spec["paths"], path
    kinds = spec["components"]["schemas"]["DamageIn"]["properties"]["kind"]["enum"]
    assert "link_lost" in kinds and "insufficient_excitation" not in kinds
    docs = client.get("/docs")
    assert docs.status_code == 200 and "swagger" in docs.text.lower()


def test_livez_readyz(client: TestClient, sstore: Store) -> None:
    assert client.get("/livez").json() == {"status": "ok"}
    r = client.get("/readyz")
    assert r.status_code == 503 and r.json()["checks"]["database"] is True
    assert r.json()["checks"]["worker"] is False
    sstore.heartbeat("worker", time.time())
    r = client.get("/readyz")
    assert r.status_code == 200 and r.json()["status"] == "ready"
    sstore.heartbeat("worker", time.time() - 3600)
    assert client.get("/readyz").status_code == 503


def test_metrics(sstore: Store) -> None:
    counters = Counters()
    counters.add("received", 120)
    counters.add("stored", 100)
    counters.add("dropped", 20)
    m = Metrics(counters=counters.as_dict)
    sstore.write(batch("arm"))
    w = Worker(sstore, SETTINGS, estimator=lambda rec, method: TOPO, metrics=m, min_samples=5)
    w.run_cycle()
    c = TestClient(create_app(sstore, settings=SETTINGS, worker=w))
    text = c.get("/metrics").text
    assert "bodyhealth_frames_received_total 120.0" in text
    assert "bodyhealth_frames_stored_total 100.0" in text
    assert "bodyhealth_frames_dropped_total 20.0" in text
    assert 'bodyhealth_retrain_seconds_count{method="fast"} 1.0' in text
    assert 'bodyhealth_alerts_active{robot="arm"} 0.0' in text


def test_dashboard_served(client: TestClient) -> None:
    r = client.get("/")
    assert r.status_code == 200 and "bodyhealth" in r.text


def test_pushed_frames_go_through_the_running_pipeline(
    sstore: Store, caplog: pytest.LogCaptureFixture
) -> None:
    """POST /frames is one more source of the pipeline: queued behind what the devices sent, written by
    its writer, counted under ``api``, seen by the commit log; what the store refuses is a 422 with the
    store's reason, counted malformed before the answer goes out, and tried once."""
    from service.ingest.pipeline import Pipeline

    committed: list[FrameBatch] = []
    with Pipeline(sstore, [], settings=SETTINGS, on_commit=committed.extend) as pipe:
        c = TestClient(create_app(sstore, settings=SETTINGS, pipeline=pipe))
        for k in range(3):
            body = _frames_body(10)
            body["t"] = [20 + k + i * 0.01 for i in range(10)]
            resp = c.post("/api/v1/robots/pushed/frames", json=body)
            assert resp.status_code == 201 and resp.json() == {"stored": 10}
        dup = _frames_body(4)
        dup["joint_names"] = ["j1", "j1"]
        resp = c.post("/api/v1/robots/pushed/frames", json=dup)
        assert resp.status_code == 422 and "unique" in resp.json()["detail"]
        assert pipe.counters()["api"] == {"received": 34, "stored": 30, "dropped": 0, "malformed": 4}
    assert [b.robot for b in committed] == ["pushed"] * 3
    assert len([r for r in caplog.records if "rejected batch" in r.getMessage()]) == 1
    assert sstore.sample_count("pushed") == 30
