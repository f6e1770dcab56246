"""API conformance: schemathesis generates requests for every operation of the OpenAPI document (valid
and invalid ones) and runs all its checks on the answers: no 5xx that is not declared, every status,
content type, header and body as the document declares it, invalid input refused and valid input
accepted. Real app, real SQLite store seeded with robots that have frames, a topology, a baseline and
alerts, a real Worker (not started) and a farm that simulates one robot. Deterministic: hypothesis is
derandomized and runs a fixed number of examples per operation."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error, positive_data_acceptance
from schemathesis.config import SchemathesisConfig

from bodyschema.topology import Topology
from service.api import create_app
from service.frames import FrameBatch
from service.settings import Settings
from service.store import Store, open_store
from service.worker import HEARTBEAT_COMPONENT, Worker

MAX_EXAMPLES = 25
TOPO = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j2"}, method="fast")
MOVED = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j1"}, method="fast")
#: Names the generator draws often (the shortest matches of the name pattern) and the usual ones.
ROBOTS = ("0", "A", "a", "arm")
#: The robot name the OpenAPI document gives as the example: simulated here, so damage applies to it.
SIMULATED = "ur5e-1"


def batch(robot: str, n: int = 60) -> FrameBatch:
    t = np.arange(n) * 0.01
    rng = np.random.default_rng(0)
    return FrameBatch(
        robot,
        t,
        ("j1", "j2"),
        rng.normal(size=(n, 2)),
        ("imu0", "imu1"),
        rng.normal(size=(n, 2, 3)),
        rng.normal(size=(n, 2, 3)),
    )


class Farm:
    """Simulates robot :data:`SIMULATED`; refuses IMUs and joints it does not have, like the real farm."""

    def simulates(self, robot: str) -> bool:
        return robot == SIMULATED

    def apply_damage(self, robot: str, kind: str, params: Mapping[str, Any]) -> dict[str, Any]:
        for part, known in (("imu", ("imu0", "imu1")), ("joint", ("j1", "j2")), ("to", ("j1", "j2"))):
            if part in params and params[part] not in known:
                raise ValueError(f"unknown {part} {params[part]!r}")
        return {"changed": True, "findings": [{"kind": kind, **params, "confidence": 1.0}]}


def seed(store: Store) -> None:
    for name in (*ROBOTS, SIMULATED):
        store.write(batch(name))
    store.mark_simulated(SIMULATED, "ur5e")
    for name in ("arm", "0"):
        store.save_topology(name, TOPO, 100.0, 0.59)
        store.set_baseline(name, TOPO, "auto")
        store.save_topology(name, MOVED, 101.0, 0.59)
        for k in range(3):
            store.upsert_alert(name, "imu_moved", f"imu:imu{k}", {"kind": "imu_moved"}, "active", 1.0 + k)
    store.save_topology(SIMULATED, TOPO, 100.0, 0.59)


# The schema is read from the app when the module is imported (that makes one test per operation); the
# store behind it lives in a directory of its own, seeded before the first case and removed after the last.
_DIR = tempfile.TemporaryDirectory(prefix="bodyhealth-conformance-")
STORE = open_store(f"sqlite:///{Path(_DIR.name) / 'api.db'}")
SETTINGS = Settings(database_url="sqlite://", retrain_min_interval_seconds=0)
APP = create_app(
    STORE,
    settings=SETTINGS,
    worker=Worker(STORE, SETTINGS, estimator=lambda rec, method: TOPO),
    damage=Farm(),
)
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)
#: The same store behind an app with a token configured, as an operator sets one: every /api/v1 route,
#: reads included (read_token_required defaults to on), needs a bearer token.
WRITE_TOKEN = "conformance-write-0123"
TOKEN_SETTINGS = Settings(database_url="sqlite://", retrain_min_interval_seconds=0, api_token=WRITE_TOKEN)
TOKEN_APP = create_app(
    STORE,
    settings=TOKEN_SETTINGS,
    worker=Worker(STORE, TOKEN_SETTINGS, estimator=lambda rec, method: TOPO),
    damage=Farm(),
)
# The generator knows the scheme's token: it sends it, and leaves it out or spoils it where it tests that
# a request without the right one is refused.
token_schema = schemathesis.openapi.from_asgi(
    "/openapi.json",
    TOKEN_APP,
    config=SchemathesisConfig.from_dict({"auth": {"openapi": {"bearer": {"bearer": WRITE_TOKEN}}}}),
)

#: Operations whose bodies have rules JSON Schema cannot state, refused with a 422 whose ``detail`` is a
#: sentence (a schema violation is a list of fields instead). Frames: q is (T, N) and acc, gyro (T, K, 3)
#: for the lengths of t, joint_names and imu_names, t strictly increasing and within
#: max_time_jump_seconds of the robot's stored frames. Damage: the joint or IMU named must be one the
#: simulated robot has. For those answers only, a schema-valid body may be refused, as the route's 422
#: documents; every other check still runs on them.
CONTRACT_422 = {
    ("POST", "/api/v1/robots/{robot}/frames"),
    ("POST", "/api/v1/robots/{robot}/simulate/damage"),
}


@pytest.fixture(scope="module", autouse=True)
def seeded() -> Iterator[Store]:
    seed(STORE)
    yield STORE
    STORE.close()
    _DIR.cleanup()


HYPOTHESIS = settings(
    max_examples=MAX_EXAMPLES,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    database=None,
)


def check(case: Any) -> None:
    if case.path == "/readyz":  # the heartbeat of a worker that runs
        STORE.heartbeat(HEARTBEAT_COMPONENT, time.time())
    response = case.call()
    excluded = []
    if (case.method, case.path) in CONTRACT_422 and response.status_code == 422:
        if isinstance(response.json().get("detail"), str):
            excluded.append(positive_data_acceptance)
    if case.path == "/readyz" and response.status_code == 503:
        # the probe's designed and documented answer for a worker that is not running (this one is
        # never started), not a server error
        assert response.json()["status"] == "not ready"
        excluded.append(not_a_server_error)
    case.validate_response(response, excluded_checks=excluded)


@pytest.mark.slow
@schema.parametrize()
@HYPOTHESIS
def test_api_conforms_to_its_openapi_document(case: Any) -> None:
    """No token configured: no operation needs one."""
    check(case)


@pytest.mark.slow
@token_schema.parametrize()
@HYPOTHESIS
def test_api_with_tokens_conforms_to_its_openapi_document(case: Any) -> None:
    """A token configured; it is sent, and left out or wrong where auth is tested."""
    check(case)
