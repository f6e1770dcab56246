"""``GET /api/v1/robots/{robot}/excitation`` and ``POST .../simulate/excite``: token rules, the plan's
limits, 409 when there is nothing to plan, and the loop undetermined -> plan -> motion -> unique."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from bodyschema.estimate import estimate_topology
from bodyschema.excitation_plan import finite_differences
from bodyschema.topology import Topology
from service.api import create_app
from service.frames import FrameBatch
from service.ingest.farm import FarmDamage, FarmSource
from service.settings import Settings
from service.store import Store, open_store
from simulators.excitation import Observable
from simulators.farm import Farm
from simulators.limits import model_limits

WRITE, READ = "write-secret-0123", "read-secret-4567"
JOINTS = ("j1", "j2", "j3", "j4", "j5")
INTENT = {"X-Requested-With": "bodyhealth"}
TRUTH = {"j1": None, "j2": "j1", "j3": "j2", "j4": "j1", "j5": "j4"}  # paper-2


class OneStill(Observable):
    """The farm's default motion with joint j3 held: the data cannot decide j3."""

    def _bind(self, robot: Any, rng: np.random.Generator) -> None:
        super()._bind(robot, rng)
        self.a_[2] = 0.0
        self.center_[2] = self.q0_[2]


def _register(store: Store, robot: str) -> None:
    n = 5
    store.write(
        FrameBatch(
            robot,
            np.arange(n) * 0.01,
            JOINTS,
            np.zeros((n, 5)),
            ("imu0",),
            np.full((n, 1, 3), 9.81),
            np.zeros((n, 1, 3)),
        )
    )
    store.mark_simulated(robot, "paper-2")


@pytest.fixture
def store(tmp_path: Path) -> Iterator[Store]:
    s = open_store(f"sqlite:///{tmp_path / 'excite.db'}")
    _register(s, "p")
    yield s
    s.close()


def _client(store: Store, damage: Any = None, **settings: Any) -> TestClient:
    return TestClient(
        create_app(store, settings=Settings(database_url="sqlite://", **settings), damage=damage)
    )


def _open(undetermined: tuple[str, ...] = ("j3",)) -> Topology:
    return Topology(dict(TRUTH), {"imu0": "j5"}, undetermined=undetermined, method="fast")


def test_plan_needs_the_read_token_and_respects_the_model_limits(store: Store) -> None:
    store.save_topology("p", _open(), 1.0, 1.0)
    client = _client(store, api_token=WRITE, api_read_token=READ)
    url = "/api/v1/robots/p/excitation?seconds=8"
    assert client.get(url).status_code == 401
    assert client.get(url, headers={"Authorization": "Bearer nope"}).status_code == 401
    resp = client.get(url, headers={"Authorization": f"Bearer {READ}"})
    assert resp.status_code == 200, resp.text
    plan = resp.json()
    assert plan["joints"] == list(JOINTS) and plan["rate"] == 100.0 and plan["excited"] == ["j3"]
    q = np.array(plan["samples"])
    assert q.shape == (801, 5)
    assert np.ptp(q[:, 2]) > 0.3 and np.ptp(q[:, [0, 1, 3, 4]]) == 0.0  # j3 alone, the others still
    lim = model_limits("paper-2")
    v, a = finite_differences(q, 100.0)
    # samples are rounded to 1e-6 rad for JSON: the differences may move by 2e-6 rad per sample
    assert (np.abs(v) <= lim.velocity + 2e-6 * 100).all() and (
        np.abs(a) <= lim.acceleration + 4e-6 * 1e4
    ).all()
    csv = client.get(url + "&format=csv", headers={"Authorization": f"Bearer {WRITE}"})
    assert csv.status_code == 200 and csv.headers["content-type"].startswith("text/csv")
    rows = csv.text.splitlines()
    assert rows[0] == "time,j1,j2,j3,j4,j5" and len(rows) == 802


def test_nothing_to_plan(store: Store) -> None:
    client = _client(store)
    assert client.get("/api/v1/robots/p/excitation").status_code == 409  # no topology yet
    assert client.get("/api/v1/robots/nope/excitation").status_code == 404
    store.save_topology("p", _open(undetermined=()), 1.0, 1.0)
    plan = client.get("/api/v1/robots/p/excitation").json()
    assert plan["excited"] == [] and plan["samples"] == [] and "nothing to excite" in plan["reason"]
    farm = Farm({"p": "paper-2"}, seed=0, imu_model="ideal")
    client = _client(store, damage=FarmDamage([FarmSource(farm)]), api_token=WRITE)
    auth = {**INTENT, "Authorization": f"Bearer {WRITE}"}
    resp = client.post("/api/v1/robots/p/simulate/excite", headers=auth)
    assert resp.status_code == 409 and "nothing to excite" in resp.json()["detail"]
    assert client.post("/api/v1/robots/p/simulate/excite", headers=INTENT).status_code == 401


@pytest.mark.slow
def test_the_loop_undetermined_plan_motion_unique(store: Store) -> None:
    farm = Farm({"p": "paper-2"}, seed=0, imu_model="mpu6050", overrides={"p": {"excitation": OneStill()}})
    before = farm.advance(20.0)["p"]
    topo = estimate_topology(before)
    assert topo.undetermined == ("j3",)
    store.save_topology("p", topo, 1.0, 20.0)
    client = _client(store, damage=FarmDamage([FarmSource(farm)]), api_token=WRITE)
    auth = {**INTENT, "Authorization": f"Bearer {WRITE}"}
    resp = client.post("/api/v1/robots/p/simulate/excite", json={"seconds": 10.0}, headers=auth)
    assert resp.status_code == 201, resp.text
    started = resp.json()
    assert (
        started["excited"] == ["j3"] and started["start"] == pytest.approx(20.0) and "samples" not in started
    )
    during = farm.advance(10.0)["p"]  # well within 60 s of simulated motion
    assert np.sqrt(np.mean(during.qd[:, 2] ** 2)) > 0.3  # j3 follows the plan
    after = estimate_topology(during)
    assert after.unique and after.undetermined == () and not after.candidates
    assert after.joint_parent == TRUTH
    assert after.imu_joint == during.truth_imu_map
    # then the robot's own motion again, from where the plan left it: no jump in the servo target
    rest = farm.advance(3.0)["p"]
    assert np.abs(np.diff(rest.q, axis=0)).max() < 1.5 / 100
