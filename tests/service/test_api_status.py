"""The three-valued monitoring answer over the REST API, on real SQLite and PostgreSQL stores.

Topologies come from :func:`bodyschema.estimate.topology_from_dependency` on dependency matrices: a
robot whose middle link carries no IMU gives two fitting trees (the estimator cannot tell which of the
two joints above the IMU comes first), a fully instrumented one gives one.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from fastapi.testclient import TestClient

from bodyschema.estimate import topology_from_dependency
from bodyschema.topology import Topology
from service.api import create_app
from service.api.schemas import StatusOut
from service.frames import FrameBatch
from service.settings import Settings
from service.status import judge
from service.store import Store

#: Every read renders what the store holds now; the read cache has its own tests (test_read_cache.py).
SETTINGS = Settings(database_url="sqlite://", worker_interval_seconds=1.0, api_cache_seconds=0.0)
JOINTS = ["j1", "j2", "j3"]
# A serial chain j1 → j2 → j3. Fully instrumented: one IMU per link.
FULL = topology_from_dependency(
    np.array([[1, 0, 0], [1, 1, 0], [1, 1, 1]]), ["imu0", "imu1", "imu2"], JOINTS, method="fast"
)
# j2's link carries no IMU: imu0 follows j1 alone, imu2 all three, so j2 and j3 can come in either order.
SPARSE = topology_from_dependency(np.array([[1, 0, 0], [1, 1, 1]]), ["imu0", "imu2"], JOINTS, method="fast")
# The true body of the sparse robot, as an operator would approve it.
SPARSE_TRUE = Topology({"j1": None, "j2": "j1", "j3": "j2"}, {"imu0": "j1", "imu2": "j3"}, method="fast")


def frames(store: Store, robot: str, imus: list[str]) -> None:
    n = 20
    store.write(
        FrameBatch(
            robot,
            np.arange(n) * 0.01,
            tuple(JOINTS),
            np.zeros((n, 3)),
            tuple(imus),
            np.full((n, len(imus), 3), 9.81),
            np.zeros((n, len(imus), 3)),
        )
    )


def status(c: TestClient, robot: str, **params: str) -> dict:
    r = c.get(f"/api/v1/robots/{robot}/status", params=params)
    assert r.status_code == 200, r.text
    body = r.json()
    if not params:  # the robot resource carries the same answer
        assert c.get(f"/api/v1/robots/{robot}").json()["status"] == body
    return body


def test_the_topologies_used_here_are_what_they_claim() -> None:
    assert FULL.unique and not FULL.candidates
    assert not SPARSE.unique and len(SPARSE.candidates) == 1
    # one of the two fitting trees is the true body
    fitting = [SPARSE, *SPARSE.candidates]
    assert sum(t.same_structure(SPARSE_TRUE) for t in fitting) == 1


def test_several_trees_fit_is_undetermined_even_when_one_matches_the_baseline(store: Store) -> None:
    frames(store, "arm", ["imu0", "imu2"])
    store.save_topology("arm", SPARSE_TRUE, 100.0, 0.19)
    store.set_baseline("arm", SPARSE_TRUE, "operator")
    store.save_topology("arm", SPARSE, 101.0, 0.19)
    c = TestClient(create_app(store, settings=SETTINGS))
    body = status(c, "arm")
    assert body["status"] == "undetermined"
    assert body["trees_fit"] == 2
    assert body["decide_by"] == ["j1", "j2", "j3"]
    assert body["has_baseline"] is True and body["alerts"] == []
    assert body["reasons"][0].startswith("2 trees fit the data; they differ in joint j2 (parent j1 or j3)")
    assert body["reasons"][1] == (
        "to decide, move each of these joints on its own with the others still: j1, j2, j3"
    )
    (alt,) = body["alternatives"]
    assert alt == {
        "joints": {"j1": {"parent": None}, "j2": {"parent": "j1"}, "j3": {"parent": "j2"}},
        "imus": {"imu0": "j1", "imu2": "j3"},
    }
    assert body["diff"]["changed"] is None and body["diff"]["reasons"] == body["reasons"]
    assert (body["method"], body["wall_time"], body["timing"], body["training"]) == (
        "fast",
        101.0,
        None,
        None,
    )
    # the list of robots says the same
    (r,) = c.get("/api/v1/robots").json()
    assert r["status"]["status"] == "undetermined" and r["status"]["trees_fit"] == 2


def test_healthy_only_when_unique_placed_and_matching(store: Store) -> None:
    frames(store, "arm", ["imu0", "imu1", "imu2"])
    c = TestClient(create_app(store, settings=SETTINGS))
    # nothing learned yet
    body = status(c, "arm")
    assert body["status"] == "undetermined" and body["trees_fit"] is None
    assert body["reasons"][0].startswith("nothing learned yet")
    assert body["reasons"][1].startswith("no baseline yet")
    # learned, unique, but no baseline to compare with
    store.save_topology("arm", FULL, 100.0, 0.19)
    body = status(c, "arm")
    assert (body["status"], body["trees_fit"], body["has_baseline"]) == ("undetermined", 1, False)
    assert len(body["reasons"]) == 1 and body["reasons"][0].startswith("no baseline yet")
    # baseline set, the newest estimate is unique and matches it
    store.set_baseline("arm", FULL, "auto")
    store.save_topology("arm", FULL, 101.0, 0.19)
    body = status(c, "arm")
    assert body["status"] == "healthy"
    assert (body["trees_fit"], body["decide_by"], body["alternatives"]) == (1, [], [])
    assert body["diff"] == {"changed": False, "findings": []}
    assert body["reasons"] == ["one tree fits the data, every joint is placed, and it matches the baseline"]
    # a joint the window did not move: the diff finds no damage, the answer is still not "healthy"
    still = topology_from_dependency(
        np.array([[1, 0, 0], [1, 1, 0], [1, 1, 1]]),
        ["imu0", "imu1", "imu2"],
        JOINTS,
        undetermined=["j3"],
        method="fast",
    )
    assert still.unique
    store.save_topology("arm", still, 102.0, 0.19)
    body = status(c, "arm")
    assert body["status"] == "undetermined"
    assert (body["trees_fit"], body["insufficient_excitation"], body["decide_by"]) == (1, ["j3"], ["j3"])
    assert body["reasons"] == [
        "the window does not move joint j3 enough to place it; to decide, move each on its own "
        "with the others still"
    ]
    assert [f["kind"] for f in body["diff"]["findings"]] == ["insufficient_excitation"]


def test_unconfirmed_difference_is_undetermined_and_active_alerts_are_damage(store: Store) -> None:
    frames(store, "arm", ["imu0", "imu1", "imu2"])
    store.save_topology("arm", FULL, 100.0, 0.19)
    store.set_baseline("arm", FULL, "auto")
    moved = Topology(dict(FULL.joint_parent), {**FULL.imu_joint, "imu1": "j1"}, method="fast")
    store.save_topology("arm", moved, 101.0, 0.19)
    c = TestClient(create_app(store, settings=SETTINGS), headers={"X-Requested-With": "bodyhealth"})
    # the newest estimate differs, the worker has not confirmed it: neither healthy nor damaged
    body = status(c, "arm")
    assert body["status"] == "undetermined" and body["diff"]["changed"] is True
    assert body["reasons"] == [
        "the newest estimate differs from the baseline, not yet confirmed by the worker: "
        "imu_moved imu1 (j2 → j1)"
    ]
    finding = {"kind": "imu_moved", "imu": "imu1", "from": "j2", "to": "j1", "confidence": 1.0}
    pend = store.upsert_alert("arm", "imu_moved", "imu:imu1", finding, "pending", 10.0)
    body = status(c, "arm")
    assert body["status"] == "undetermined"
    assert [a["id"] for a in body["pending_alerts"]] == [pend.id] and body["alerts"] == []
    assert body["reasons"] == [
        "seen but not yet confirmed (an alert needs several worker cycles in a row): "
        "imu_moved on imu:imu1 (j2 → j1)"
    ]
    act = store.upsert_alert("arm", "imu_moved", "imu:imu1", finding, "active", 11.0)
    assert act.id == pend.id
    body = status(c, "arm")
    assert body["status"] == "damaged"
    assert [(a["id"], a["kind"], a["imu"], a["state"]) for a in body["alerts"]] == [
        (act.id, "imu_moved", "imu1", "active")
    ]
    assert body["reasons"] == ["1 active alert: imu_moved on imu:imu1 (j2 → j1)"]
    assert c.get("/api/v1/robots/arm").json()["active_alerts"] == 1
    # an ack is not a repair
    assert c.post(f"/api/v1/alerts/{act.id}/ack").status_code == 200
    assert status(c, "arm")["status"] == "damaged"
    # a confirmed damage outranks an ambiguous newest estimate, which is still reported
    store.save_topology(
        "arm",
        topology_from_dependency(
            np.array([[1, 0, 0], [1, 1, 1], [1, 1, 1]]), ["imu0", "imu1", "imu2"], JOINTS, method="fast"
        ),
        102.0,
        0.19,
    )
    body = status(c, "arm")
    assert (body["status"], body["trees_fit"], body["decide_by"]) == ("damaged", 2, ["j1", "j2", "j3"])
    assert body["reasons"][0] == "1 active alert: imu_moved on imu:imu1 (j2 → j1)"
    assert body["reasons"][1].startswith("2 trees fit the data")
    # once resolved (here: an operator approves a body, which resolves the robot's alerts)
    store.save_topology("arm", FULL, 103.0, 0.19)
    assert c.post("/api/v1/robots/arm/baseline").status_code == 200
    body = status(c, "arm")
    assert (body["status"], body["alerts"], body["pending_alerts"]) == ("healthy", [], [])


def test_timing_and_training_of_the_judged_topology(store: Store) -> None:
    frames(store, "arm", ["imu0", "imu1", "imu2"])
    timing = {
        "lag_ms": 14.25,
        "lag_unc_ms": 0.31,
        "skew_ms": 12.5,
        "drift_ppm": 3.0,
        "band_hz": 10.0,
        "at_s": 5.0,
    }
    timed = dataclasses.replace(FULL, timing=dict(timing))
    store.save_topology("arm", timed, 100.0, 0.19)
    store.set_baseline("arm", FULL, "auto")
    trained = dataclasses.replace(
        FULL,
        method="network",
        training={"epochs": 137.0, "converged": 1.0, "loss": 0.0125, "warm": 1.0},
        seconds=21.5,
    )
    net_id = store.save_topology("arm", trained, 99.0, 0.19)  # older than the fast one
    c = TestClient(create_app(store, settings=SETTINGS))
    body = status(c, "arm")
    assert (body["status"], body["method"]) == ("healthy", "fast")
    assert body["timing"] == timing  # every field, the lag's uncertainty too
    assert body["training"] is None
    # the newest network retrain is reported next to the judged fast estimate
    assert body["network"] == {
        "topology_id": net_id,
        "method": "network",
        "wall_time": 99.0,
        "window_end_t": 0.19,
        "cpu_seconds": 21.5,
        "training": {"epochs": 137, "converged": True, "loss": 0.0125, "warm": True},
        "same_as_judged": True,
    }
    net = status(c, "arm", method="network")
    assert (net["status"], net["method"], net["timing"]) == ("healthy", "network", None)
    assert net["training"] == {"epochs": 137, "converged": True, "loss": 0.0125, "warm": True}
    # a method never run: nothing learned with it
    body = status(c, "arm", method="mlp")
    assert body["status"] == "undetermined" and body["reasons"][0].startswith("nothing learned yet")


def test_a_loss_that_is_not_finite_is_null() -> None:
    """JSON has no NaN: a diverged loss must not make the status unanswerable."""
    trained = dataclasses.replace(
        FULL, method="network", training={"epochs": 3.0, "converged": 0.0, "loss": np.nan}
    )
    out = json.loads(StatusOut.of(judge("arm", trained, FULL)).model_dump_json())
    assert out["training"] == {"epochs": 3, "converged": False, "loss": None, "warm": None}
    assert out["status"] == "healthy"


@pytest.mark.parametrize("path", ["/api/v1/robots/nope/status", "/api/v1/robots/arm/status?method=bogus"])
def test_status_errors(store: Store, path: str) -> None:
    frames(store, "arm", ["imu0"])
    c = TestClient(create_app(store, settings=SETTINGS))
    assert c.get(path).status_code == (404 if "nope" in path else 422)


def test_status_in_openapi(store: Store) -> None:
    spec = TestClient(create_app(store, settings=SETTINGS)).get("/openapi.json").json()
    assert "/api/v1/robots/{robot}/status" in spec["paths"]
    schemas = spec["components"]["schemas"]
    assert schemas["StatusOut"]["properties"]["status"]["enum"] == ["healthy", "damaged", "undetermined"]
    for field in ("reasons", "trees_fit", "alternatives", "decide_by", "alerts", "timing", "training"):
        assert field in schemas["StatusOut"]["properties"], field
    assert "status" in schemas["RobotOut"]["properties"]
