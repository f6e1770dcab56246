"""Mixed reads against a running bodyhealth service, as dashboards and REST clients make them (locust).

Used by ``bodyhealth bench load``; also runs on its own against any service::

    locust -f bench/locustfile.py --host http://127.0.0.1:8000 --headless -u 20 -r 20 -t 60s

Each user asks at ``BODYHEALTH_LOAD_USER_RPS`` requests per second (default 10), so users x that rate
is the offered load. Bearer token: ``BODYHEALTH_API_READ_TOKEN`` or ``BODYHEALTH_API_TOKEN`` when set.
Requests are named by route (``/api/v1/robots/[robot]/status``), not by robot, so the statistics group
them per route. Not collected by pytest (importing locust patches the standard library for gevent).
"""

from __future__ import annotations

import os
import random

import gevent
from locust import FastHttpUser, constant_throughput, task

__all__ = ["MixedReads"]


class MixedReads(FastHttpUser):
    """The read mix: the robot list (a dashboard's poll) most, then status, details, topology, alerts."""

    rate = float(os.environ.get("BODYHEALTH_LOAD_USER_RPS", "10"))
    wait_time = constant_throughput(rate)

    def on_start(self) -> None:
        # Independent clients are not in step. Users spawned together at a fixed rate each would
        # otherwise fire in the same few milliseconds of every period: the service would see bursts of
        # all users at once, and the percentiles would measure the queue of one burst.
        gevent.sleep(random.uniform(0.0, 1.0 / self.rate))
        token = os.environ.get("BODYHEALTH_API_READ_TOKEN") or os.environ.get("BODYHEALTH_API_TOKEN")
        self.headers = {"Authorization": f"Bearer {token}"} if token else {}
        resp = self.client.get("/api/v1/robots", headers=self.headers, name="/api/v1/robots")
        self.robots = [r["name"] for r in resp.json()] or ["none"]

    def _get(self, path: str, name: str) -> None:
        self.client.get(path, headers=self.headers, name=name)

    @task(4)
    def robots(self) -> None:
        self._get("/api/v1/robots", "/api/v1/robots")

    @task(3)
    def status(self) -> None:
        self._get(f"/api/v1/robots/{random.choice(self.robots)}/status", "/api/v1/robots/[robot]/status")

    @task(2)
    def robot(self) -> None:
        self._get(f"/api/v1/robots/{random.choice(self.robots)}", "/api/v1/robots/[robot]")

    @task(2)
    def topology(self) -> None:
        self._get(f"/api/v1/robots/{random.choice(self.robots)}/topology", "/api/v1/robots/[robot]/topology")

    @task(2)
    def alerts(self) -> None:
        self._get("/api/v1/alerts", "/api/v1/alerts")

    @task(1)
    def robot_alerts(self) -> None:
        self._get(f"/api/v1/robots/{random.choice(self.robots)}/alerts", "/api/v1/robots/[robot]/alerts")

    @task(1)
    def ready(self) -> None:
        self._get("/readyz", "/readyz")
