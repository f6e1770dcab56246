"""``GET /api/v1/robots/{robot}/diagnostics`` on a real SQLite store: the ROS DiagnosticArray shape, OK for
a healthy robot, STALE for a silent IMU (apart from damage), ERROR for an active alert, WARN for a
pending one and for an undetermined robot."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from bodyschema.topology import Topology
from service.api import create_app
from service.frames import FrameBatch
from service.settings import Settings
from service.store import Store, open_store

TOPO = Topology(
    {"j1": None, "j2": "j1"},
    {"imu0": "j1", "imu1": "j2"},
    method="fast",
    confidence={"imu:imu0": 0.99, "imu:imu1": 0.97, "joint:j2": 0.9},
    excitation={"j1": 0.4, "j2": 0.3},
)
SETTINGS = Settings(database_url="sqlite://", imu_silent_seconds=1.0)


def batch(t0: float, n: int = 20, imus: tuple[str, ...] = ("imu0", "imu1")) -> FrameBatch:
    t = t0 + np.arange(n) * 0.01
    k = len(imus)
    return FrameBatch(
        "arm", t, ("j1", "j2"), np.zeros((n, 2)), imus, np.full((n, k, 3), 9.81), np.zeros((n, k, 3))
    )


@pytest.fixture
def store(tmp_path: Path) -> Iterator[Store]:
    s = open_store(f"sqlite:///{tmp_path / 'diag.db'}", imu_silent_seconds=1.0)
    s.write(batch(0.0))
    s.save_topology("arm", TOPO, 100.0, 0.19)
    s.set_baseline("arm", TOPO, "auto")
    yield s
    s.close()


@pytest.fixture
def client(store: Store) -> TestClient:
    return TestClient(create_app(store, settings=SETTINGS))


def diag(client: TestClient, robot: str = "arm") -> dict[str, dict[str, Any]]:
    resp = client.get(f"/api/v1/robots/{robot}/diagnostics")
    assert resp.status_code == 200, resp.text
    body = resp.json()
    assert list(body) == ["status"]
    return {s["name"]: s for s in body["status"]}


def levels(d: dict[str, dict[str, Any]]) -> dict[str, int]:
    return {name: s["level"] for name, s in d.items()}


def values(s: dict[str, Any]) -> dict[str, str]:
    return {kv["key"]: kv["value"] for kv in s["values"]}


def test_healthy_robot_is_ok_in_the_diagnostic_array_shape(client: TestClient) -> None:
    d = diag(client)
    assert levels(d) == {
        "bodyhealth/arm": 0,
        "bodyhealth/arm/joint:j1": 0,
        "bodyhealth/arm/joint:j2": 0,
        "bodyhealth/arm/imu:imu0": 0,
        "bodyhealth/arm/imu:imu1": 0,
    }
    robot = d["bodyhealth/arm"]
    assert set(robot) == {"level", "name", "message", "hardware_id", "values"}
    assert robot["hardware_id"] == "arm"
    assert robot["message"].startswith("healthy: one tree fits the data")
    assert values(robot)["status"] == "healthy" and values(robot)["active_alerts"] == "0"
    assert values(d["bodyhealth/arm/imu:imu1"]) == {
        "joint": "j2",
        "confidence": "0.970",
        "baseline_joint": "j2",
        "silent": "false",
    }
    assert values(d["bodyhealth/arm/joint:j1"])["parent"] == "base"


def test_silent_imu_is_stale_and_the_others_stay_ok(client: TestClient, store: Store) -> None:
    store.write(batch(0.2, n=200, imus=("imu0",)))  # imu1 falls silent for 2 s of device time
    d = diag(client)
    assert levels(d) == {
        "bodyhealth/arm": 0,
        "bodyhealth/arm/joint:j1": 0,
        "bodyhealth/arm/joint:j2": 0,
        "bodyhealth/arm/imu:imu0": 0,
        "bodyhealth/arm/imu:imu1": 3,
    }
    assert d["bodyhealth/arm/imu:imu1"]["message"].startswith("silent")
    assert values(d["bodyhealth/arm/imu:imu1"])["silent"] == "true"
    assert values(d["bodyhealth/arm"])["silent_imus"] == "imu1"


def test_active_alert_is_error_pending_is_warn_and_silence_stays_apart(
    client: TestClient, store: Store
) -> None:
    store.write(batch(0.2, n=200, imus=("imu1",)))  # imu0 silent, imu1 damaged
    store.upsert_alert("arm", "imu_moved", "imu:imu1", {"kind": "imu_moved", "imu": "imu1"}, "active", 5.0)
    store.upsert_alert(
        "arm", "joint_locked", "joint:j2", {"kind": "joint_locked", "joint": "j2"}, "pending", 5.0
    )
    d = diag(client)
    assert levels(d) == {
        "bodyhealth/arm": 2,
        "bodyhealth/arm/joint:j1": 0,
        "bodyhealth/arm/joint:j2": 1,
        "bodyhealth/arm/imu:imu0": 3,
        "bodyhealth/arm/imu:imu1": 2,
    }
    assert d["bodyhealth/arm/imu:imu1"]["message"] == "imu_moved"
    assert d["bodyhealth/arm/joint:j2"]["message"] == "not yet confirmed: joint_locked"
    assert d["bodyhealth/arm"]["message"].startswith("damaged: 1 active alert: imu_moved on imu:imu1")


def test_undetermined_robot_warns_and_a_robot_without_frames_is_stale(tmp_path: Path) -> None:
    s = open_store(f"sqlite:///{tmp_path / 'new.db'}")
    try:
        s.write(batch(0.0))  # frames, nothing learned yet
        s.mark_simulated("idle", "ur5e")  # registered, never sent a frame
        c = TestClient(create_app(s, settings=SETTINGS))
        d = diag(c)
        assert d["bodyhealth/arm"]["level"] == 1
        assert d["bodyhealth/arm"]["message"].startswith("undetermined: nothing learned yet")
        assert {n: v["level"] for n, v in d.items() if n != "bodyhealth/arm"} == dict.fromkeys(
            [
                "bodyhealth/arm/joint:j1",
                "bodyhealth/arm/joint:j2",
                "bodyhealth/arm/imu:imu0",
                "bodyhealth/arm/imu:imu1",
            ],
            0,
        )
        idle = diag(c, "idle")
        assert idle == {
            "bodyhealth/idle": {
                "level": 3,
                "name": "bodyhealth/idle",
                "message": "no frame received yet",
                "hardware_id": "idle",
                "values": idle["bodyhealth/idle"]["values"],
            }
        }
    finally:
        s.close()


def test_unknown_robot_is_404_and_the_read_token_is_needed(store: Store) -> None:
    c = TestClient(create_app(store, settings=SETTINGS))
    assert c.get("/api/v1/robots/nope/diagnostics").status_code == 404
    assert c.get("/api/v1/robots/bad%20name/diagnostics").status_code == 422
    guarded = TestClient(
        create_app(
            store, settings=Settings(database_url="sqlite://", api_token="w" * 32, api_read_token="r" * 32)
        )
    )
    assert guarded.get("/api/v1/robots/arm/diagnostics").status_code == 401
    ok = guarded.get("/api/v1/robots/arm/diagnostics", headers={"Authorization": "Bearer " + "r" * 32})
    assert ok.status_code == 200
    assert "/api/v1/robots/{robot}/diagnostics" in c.get("/openapi.json").json()["paths"]
