"""Liveness, readiness and Prometheus metrics.

Readiness follows what happens to the data, not only whether the database answers a ping: the store's
SQLite file must still be the one it opened (:meth:`Store.storage_fault`), the ingest writer's newest
write must have succeeded (:meth:`Pipeline.write_health`: a full disk answers pings and refuses every
commit) and the worker must be alive. A 503 names each reason in ``reasons`` (and all of them joined
in ``reason``), so an operator reads the cause off the probe.

Readiness means the service can take frames and answer. A worker in this process whose thread runs but
whose heartbeat is old is *slow*, not dead (a loaded machine stretches its cycles; ingest and the API go
on): it is answered 200 with its lag in ``degraded`` and ``checks.worker_lag``. A worker thread that
died, or, with no worker in this process, a heartbeat older than a few intervals, is a 503.

A training cluster that cannot be reached (:mod:`service.cluster`) is a *degraded* state, not a
reason to be unready: ingest, the API and the fast monitoring every cycle go on without it, and a
load balancer that took the service out would lose frames for a fault that only delays retrains. It
is answered 200 with the cluster named in ``degraded`` (and under ``checks.training``).
"""

from __future__ import annotations

import time

from fastapi import APIRouter, Depends, Response
from fastapi.responses import JSONResponse, PlainTextResponse
from sqlalchemy.exc import SQLAlchemyError

from service.api.deps import get_metrics, get_pipeline, get_settings_dep, get_store, get_worker
from service.control import MonitorControl, TrainingStatus
from service.ingest.pipeline import Pipeline
from service.metrics import CONTENT_TYPE_LATEST, Metrics
from service.settings import Settings
from service.store import Store
from service.worker import HEARTBEAT_COMPONENT

__all__ = ["router"]

router = APIRouter(tags=["health"])


@router.get("/livez", summary="the process answers")
def livez() -> dict[str, str]:
    return {"status": "ok"}


@router.get(
    "/readyz",
    summary="database reachable and unchanged, writes succeeding, worker alive (503 otherwise; a slow "
    "worker is degraded)",
    responses={
        503: {
            "description": "not ready: the same body, with `reason` naming why (database unreachable, "
            "database file deleted or replaced, writes failing, worker thread stopped, or no worker in "
            "this process and its heartbeat stale)"
        },
        200: {
            "description": "ready; `degraded` names what works less well (training cluster unreachable, "
            "worker slow: its lag in `checks.worker_lag`)"
        },
    },
)
def readyz(
    store: Store = Depends(get_store),
    settings: Settings = Depends(get_settings_dep),
    worker: MonitorControl | None = Depends(get_worker),
    pipeline: Pipeline = Depends(get_pipeline),
) -> JSONResponse:
    reasons: list[str] = []
    checks: dict[str, object] = {}
    fault = store.storage_fault()
    checks["storage_fault"] = fault
    checks["database"] = store.ping()
    if fault is not None:
        reasons.append(fault)
    elif not checks["database"]:
        reasons.append("database unreachable")
    health = pipeline.write_health()
    checks["writes"] = health.as_dict()
    if health.failing:
        reasons.append(f"writes failing: {health.reason}")
    degraded: list[str] = []
    _check_worker(store, settings, worker, checks, reasons, degraded)
    if isinstance(worker, TrainingStatus):
        training = worker.training_fault()
        checks["training"] = training or "ok"
        if training is not None:
            degraded.append(f"training cluster: {training}")
    ok = not reasons
    body = {
        "status": "ready" if ok else "not ready",
        "reason": "; ".join(reasons),
        "reasons": reasons,
        "degraded": degraded,
    }
    return JSONResponse({**body, "checks": checks}, status_code=200 if ok else 503)


def _check_worker(
    store: Store,
    settings: Settings,
    worker: MonitorControl | None,
    checks: dict[str, object],
    reasons: list[str],
    degraded: list[str],
) -> None:
    """The worker's heartbeat (and thread, when there is one) into ``checks``; why not ready, into
    ``reasons``; a slow but running worker, into ``degraded`` (module doc)."""
    beat = None
    if checks["database"]:
        try:
            beat = store.last_heartbeat(HEARTBEAT_COMPONENT)
        except SQLAlchemyError:  # the database went away between the ping and here
            beat = None
    # A cycle over many robots can take longer than the interval: allow a few intervals and 30 s.
    max_age = max(3 * settings.worker_interval_seconds, 30.0)
    age = None if beat is None else time.time() - beat
    checks["worker_heartbeat_age_s"] = None if age is None else round(age, 3)
    checks["worker"] = age is not None and age <= max_age
    progress = getattr(worker, "progress", None)
    if callable(progress):
        checks["worker_lag"] = progress()
    if worker is not None:
        checks["worker_thread"] = worker.running
        if getattr(worker, "died", not worker.running):
            reasons.append("worker thread not running")
            return
        if not checks["worker"] and age is not None and worker.running:
            degraded.append(f"worker slow: heartbeat {age:.0f} s old (allowed {max_age:.0f} s)")
            return
    if not checks["worker"] and checks["database"]:
        reasons.append("no worker heartbeat" if age is None else f"worker heartbeat {age:.0f} s old")


@router.get(
    "/metrics",
    summary="Prometheus metrics",
    response_class=PlainTextResponse,
    responses={200: {"description": "Prometheus text exposition format"}},
)
def metrics(m: Metrics = Depends(get_metrics)) -> Response:
    return Response(m.render(), media_type=CONTENT_TYPE_LATEST)
