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
from collections.abc import Callable

import gevent
from locust import FastHttpUser, constant_throughput

from bench.read_mix import READ_MIX

__all__ = ["MixedReads"]


def _task(path: str, name: str) -> Callable[[MixedReads], None]:
    return lambda user: user._get(path, name)


class MixedReads(FastHttpUser):
    """The read mix of :data:`bench.read_mix.READ_MIX`."""

    rate = float(os.environ.get("BODYHEALTH_LOAD_USER_RPS", "10"))
    wait_time = constant_throughput(rate)
    # locust draws a user's next task with these weights (``tasks`` as a callable -> weight mapping)
    tasks = {_task(path, name): weight for weight, path, name in READ_MIX}  # noqa: RUF012 - locust's API

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
        self.client.get(path.format(robot=random.choice(self.robots)), headers=self.headers, name=name)
