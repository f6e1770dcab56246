"""What the tests of who may call the API share (tests/service/test_auth.py,
tests/service/test_security_origin.py): the tokens, a simulated farm and a worker that record what got
through, and every mutating route of the real app with a valid body, a concrete path and the status it
answers an authorized request with.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from fastapi import FastAPI
from fastapi.testclient import TestClient

from bodyschema.topology import Topology
from service.api.security import MUTATING_METHODS
from service.store import Store, TopologyRecord

WRITE, READ = "write-secret-0123", "read-secret-4567"
TOPO = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j2"}, method="fast")


def _frames_body(n: int = 5, t0: float = 1.0) -> dict[str, Any]:
    """A valid frames body: ``n`` frames of a still robot, gravity on its accelerometers."""
    return {
        "t": [t0 + k * 0.01 for k in range(n)],
        "joint_names": ["j1", "j2"],
        "q": [[0.0, 0.0]] * n,
        "imu_names": ["imu0", "imu1"],
        "acc": [[[0, 0, 9.81]] * 2] * n,
        "gyro": [[[0, 0, 0]] * 2] * n,
    }


class Farm:
    """Simulates robot ``sim``; records the damage requests that got through."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, str, dict[str, Any]]] = []

    def simulates(self, robot: str) -> bool:
        return robot == "sim"

    def apply_damage(self, robot: str, kind: str, params: Mapping[str, Any]) -> dict[str, Any]:
        self.calls.append((robot, kind, dict(params)))
        return {"changed": True, "findings": [{"kind": kind, "imu": "imu0", "confidence": 1.0}]}


class StrictFarm(Farm):
    """A :class:`Farm` that answers like the real farm does for arguments its simulator does not take."""

    def apply_damage(self, robot: str, kind: str, params: Mapping[str, Any]) -> dict[str, Any]:
        if kind == "link_lost":  # the message simulators.damage gives for a TypeError of its handler
            self.calls.append((robot, kind, dict(params)))
            raise ValueError(f"bad arguments for {kind}: _{kind}() got an unexpected keyword argument 'x'")
        return super().apply_damage(robot, kind, params)


class Worker:
    """A monitoring worker that records retrain requests and approves through the store."""

    def __init__(self, store: Store) -> None:
        self.store, self.requests = store, []
        self.running = True

    def request(self, robot: str, method: str) -> None:
        self.requests.append((robot, method))

    def approve_baseline(self, robot: str) -> TopologyRecord:
        return self.store.approve_baseline(robot, source="operator")


def routes(app: FastAPI) -> list[tuple[str, set[str]]]:
    """(path, methods) of every route the app serves, read from the app itself, so a route added later
    is checked without anyone adding it here. (FastAPI >= 0.16x keeps included routers as one entry
    each in ``app.routes``; ``iter_route_contexts`` opens them.)"""
    try:
        from fastapi.routing import iter_route_contexts
    except ImportError:  # older FastAPI: app.routes is flat
        return [(r.path, set(r.methods)) for r in app.routes if getattr(r, "methods", None)]
    return [(c.path, set(c.methods)) for c in iter_route_contexts(app.routes) if c.methods]


def mutating_routes(client: TestClient) -> list[tuple[str, str]]:
    """(method, path template) of every route that changes something."""
    return [(m, path) for path, methods in routes(client.app) for m in sorted(methods & MUTATING_METHODS)]


def read_routes(client: TestClient) -> list[str]:
    """Path template of every read of the API (``/api/v1``)."""
    return [path for path, methods in routes(client.app) if "GET" in methods and path.startswith("/api/v1")]


#: Valid bodies of the routes that take one; the others are posted without a body.
BODIES: dict[str, dict[str, Any]] = {
    "/api/v1/robots/{robot}/frames": _frames_body(),
    "/api/v1/robots/{robot}/simulate/damage": {"kind": "imu_dead", "imu": "imu0"},
}
#: What each mutating route answers to an authorized, valid request.
ACCEPTED = {
    "/api/v1/robots/{robot}/frames": 201,
    "/api/v1/robots/{robot}/simulate/damage": 201,
    "/api/v1/robots/{robot}/simulate/excite": 409,  # the robot's topology leaves nothing to excite
    "/api/v1/robots/{robot}/topology/retrain": 202,
    "/api/v1/robots/{robot}/baseline": 200,
    "/api/v1/alerts/{alert_id}/ack": 200,
    "/api/v1/robots/{robot}/alerts/{alert_id}/ack": 200,
}


def concrete(path: str, store: Store) -> str:
    """The template with real values: robot ``sim`` and a fresh alert of it."""
    alert = store.upsert_alert(
        "sim", "imu_dead", "imu:imu0", {"kind": "imu_dead", "imu": "imu0"}, "active", 5.0
    )
    values = {"robot": "sim", "alert_id": str(alert.id)}
    names = re.findall(r"{(\w+)}", path)
    missing = [n for n in names if n not in values]
    assert not missing, f"give the test a value for the path parameter(s) {missing} of {path}"
    return path.format(**{n: values[n] for n in names})
