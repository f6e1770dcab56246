"""The API read mix of ``bench load`` and ``bench fleet``: what dashboards and REST clients ask, and how
often. One table for both load clients (locust's ``bench/locustfile.py`` and the threads of
:func:`bench.load.read_mix`).

Each entry is (weight, path, name): ``{robot}`` in the path stands for a robot drawn at random per
request, and requests are counted under ``name`` (per route, not per robot).

>>> sum(w for w, _, _ in READ_MIX)
15
>>> [name for _, path, name in READ_MIX if "{robot}" not in path]
['/api/v1/robots', '/api/v1/alerts', '/readyz']
"""

from __future__ import annotations

__all__ = ["READY", "READ_MIX"]

#: The readiness probe's path: an app without a monitoring worker answers it 503 by design, so a
#: client may leave it out.
READY = "/readyz"

#: (weight, path, name): the robot list (a dashboard's poll) most, then status, details, topology, alerts.
READ_MIX: tuple[tuple[int, str, str], ...] = (
    (4, "/api/v1/robots", "/api/v1/robots"),
    (3, "/api/v1/robots/{robot}/status", "/api/v1/robots/[robot]/status"),
    (2, "/api/v1/robots/{robot}", "/api/v1/robots/[robot]"),
    (2, "/api/v1/robots/{robot}/topology", "/api/v1/robots/[robot]/topology"),
    (2, "/api/v1/alerts", "/api/v1/alerts"),
    (1, "/api/v1/robots/{robot}/alerts", "/api/v1/robots/[robot]/alerts"),
    (1, READY, READY),
)
