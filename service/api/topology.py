"""``/api/v1/robots/{robot}/topology`` and ``/baseline``: learned bodies and the baseline.

A retrain runs an estimator (the sensor networks: seconds of CPU each) from the worker's next cycle —
as a task on the Dask cluster when the service has one (:mod:`service.retrain`), never on the
request's thread — so each robot accepts at most one retrain request per
``retrain_min_interval_seconds``; more are 429 with ``Retry-After`` (:class:`RetrainLimiter`, one per
app on ``app.state.retrain_limiter``). A cluster retrain is also 429 while the training queue is full
(``max_retrains_queued``, :meth:`service.retrain.RemoteRetrains.admit`), with ``Retry-After`` the
expected seconds until a retrain in it finishes; a request for one already waiting or in flight is
answered by that one.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any, Literal, Protocol, runtime_checkable

from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response

from bodyschema.diff import diff_bodies
from service.api.cache import read_cache
from service.api.deps import RobotName, get_robot, get_store, get_worker, known_robot
from service.api.errors import responses
from service.api.schemas import TopologyOut, TopologyPair
from service.control import MonitorControl
from service.store import RobotInfo, Store

__all__ = ["RetrainLimiter", "RetrainQueue", "router"]

_LIMITER_LOCK = threading.Lock()

router = APIRouter(
    prefix="/api/v1/robots/{robot}", tags=["topology"], responses=responses(401, 404, 422, 503)
)

Method = Literal["fast", "network", "network-paper", "mlp"]


class RetrainLimiter:
    """At most one accepted request per ``interval`` seconds per robot (0: no limit), on ``clock``
    (monotonic by default, so a wall-clock step neither opens nor closes the limit)."""

    def __init__(self, interval: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.interval = float(interval)
        self.clock = clock
        self._last: dict[str, float] = {}
        self._lock = threading.Lock()

    def wait(self, robot: str) -> float:
        """Seconds until ``robot`` may ask again (0: now), counting nothing."""
        with self._lock:
            last = self._last.get(robot)
            elapsed = None if last is None else self.clock() - last
            if self.interval > 0 and elapsed is not None and elapsed < self.interval:
                return self.interval - elapsed
            return 0.0

    def admit(self, robot: str) -> float:
        """Seconds until ``robot`` may ask again: 0 means this request is accepted (and counted)."""
        with self._lock:
            now = self.clock()
            last = self._last.get(robot)
            if self.interval > 0 and last is not None and now - last < self.interval:
                return self.interval - (now - last)
            self._last[robot] = now
            return 0.0


@runtime_checkable
class RetrainQueue(Protocol):
    """The worker's cluster retrains (:class:`service.retrain.RemoteRetrains`), as the route sees them."""

    def admit(self, robot: str, method: str) -> float:
        """0 when the retrain is wanted now, else the seconds until the queue has room for it."""
        ...

    def capacity(self) -> int:
        """Retrains in flight at most."""
        ...


def _queue_of(worker: MonitorControl) -> RetrainQueue | None:
    """The worker's retrain queue; None when its retrains run in its own thread."""
    remote = getattr(worker, "remote", None)
    return remote if isinstance(remote, RetrainQueue) else None


def get_retrain_limiter(request: Request) -> RetrainLimiter:
    """The app's limiter, made from its settings on first use unless the app was given one."""
    state = request.app.state
    with _LIMITER_LOCK:
        limiter = getattr(state, "retrain_limiter", None)
        if limiter is None:
            limiter = RetrainLimiter(request.app.state.settings.retrain_min_interval_seconds)
            state.retrain_limiter = limiter
    return limiter


@router.get(
    "/topology",
    response_model=TopologyPair,
    summary="the newest learned topology and the baseline (docs/design.md, 'Topology JSON')",
)
async def topology(
    robot: RobotName,
    request: Request,
    store: Store = Depends(get_store),
    method: Method | None = Query(None, description="newest of this method (default: fast)"),
) -> Response:
    return await read_cache(request).respond(
        ("topology", robot, method), lambda: _pair(store, known_robot(store, robot), method)
    )


def _pair(store: Store, robot: str, method: str | None) -> TopologyPair:
    cur = store.latest_topology(robot, method=method or "fast")
    if cur is None and method is None:
        cur = store.latest_topology(robot)
    base = store.baseline(robot)
    diff = None
    if cur is not None and base is not None:
        diff = diff_bodies(base.topology, cur.topology).to_json()
    return TopologyPair(
        current=cur.topology.to_json() if cur else None,
        baseline=base.topology.to_json() if base else None,
        current_meta=TopologyOut.of(cur) if cur else None,
        baseline_meta=TopologyOut.of(base) if base else None,
        diff=diff,
    )


@router.get("/topology/history", response_model=list[TopologyOut], summary="learned topologies, newest first")
async def history(
    robot: RobotName,
    request: Request,
    store: Store = Depends(get_store),
    limit: int = Query(50, ge=1, le=1000),
) -> Response:
    def render() -> list[TopologyOut]:
        return [TopologyOut.of(r) for r in store.topology_history(known_robot(store, robot), limit=limit)]

    return await read_cache(request).respond(("history", robot, limit), render)


def _retrain_responses() -> dict[int | str, dict[str, Any]]:
    out = responses(
        409,
        413,
        415,
        429,
        s409="no worker runs in this process",
        s429="this robot's last retrain request was accepted less than retrain_min_interval_seconds ago, "
        "or the training cluster's queue is full (max_retrains_queued retrains waiting or in flight); "
        "Retry-After: seconds until the next is accepted",
    )
    out[429]["headers"] = {
        "Retry-After": {
            "description": "whole seconds until a request is accepted: the rest of the robot's interval, "
            "or for a full queue the expected wall time until a retrain in it finishes (from the recent "
            "retrains' wall times on the cluster's threads)",
            "schema": {"type": "integer", "minimum": 1},
        }
    }
    return out


@router.post(
    "/topology/retrain",
    status_code=202,
    summary="learn with a method in the next worker cycle",
    responses=_retrain_responses(),
)
def retrain(
    info: RobotInfo = Depends(get_robot),
    worker: MonitorControl | None = Depends(get_worker),
    limiter: RetrainLimiter = Depends(get_retrain_limiter),
    method: Method = Query("network"),
) -> dict[str, str]:
    if worker is None:
        raise HTTPException(status_code=409, detail="no worker runs in this process")
    # the robot's interval is only looked at here, and counted once the queue took the request, so
    # a request the full queue refused does not hold the robot's next one back
    if (wait := limiter.wait(info.name)) > 0:
        raise _too_soon(info.name, limiter, wait)
    queue = _queue_of(worker) if method != "fast" else None
    if queue is not None and (full := queue.admit(info.name, method)) > 0:
        retry = max(1, math.ceil(full))
        raise HTTPException(
            status_code=429,
            detail=f"the training queue is full ({queue.capacity()} retrains); retry in {retry} s",
            headers={"Retry-After": str(retry)},
        )
    if (wait := limiter.admit(info.name)) > 0:  # another request of the robot came in meanwhile
        raise _too_soon(info.name, limiter, wait)
    worker.request(info.name, method)
    return {"robot": info.name, "method": method, "status": "queued"}


def _too_soon(robot: str, limiter: RetrainLimiter, wait: float) -> HTTPException:
    retry = max(1, math.ceil(wait))
    return HTTPException(
        status_code=429,
        detail=f"retrain of {robot!r} was requested less than {limiter.interval:g} s ago; retry in {retry} s",
        headers={"Retry-After": str(retry)},
    )


@router.post(
    "/baseline",
    response_model=TopologyOut,
    summary="approve the newest learned topology as the baseline (operator decision)",
    responses=responses(409, 413, 415, s409="no topology learned for this robot yet"),
)
def approve_baseline(
    robot: RobotName,
    store: Store = Depends(get_store),
    worker: MonitorControl | None = Depends(get_worker),
) -> TopologyOut:
    # The robot's name is all it needs (not its parts, which get_robot reads): on a loaded machine
    # each store read and each hop to a worker thread is time an operator waits for.
    name = known_robot(store, robot)
    try:
        # The worker also forgets what it tracked against the old baseline; without one the store
        # alone approves (and resolves the open alerts, in the same transaction).
        if worker is not None:
            base = worker.approve_baseline(name)
        else:
            base = store.approve_baseline(name, source="operator")
    except LookupError as err:
        raise HTTPException(status_code=409, detail=str(err)) from None
    return TopologyOut.of(base)
