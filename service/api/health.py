"""Liveness, readiness and Prometheus metrics."""

from __future__ import annotations

import time

from fastapi import APIRouter, Depends, Response
from fastapi.responses import JSONResponse

from service.api.deps import get_metrics, get_settings_dep, get_store, get_worker
from service.control import MonitorControl
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
    summary="database reachable and worker heartbeat fresh (503 otherwise)",
    responses={503: {"description": "database unreachable or worker heartbeat stale (same body)"}},
)
def readyz(
    store: Store = Depends(get_store),
    settings: Settings = Depends(get_settings_dep),
    worker: MonitorControl | None = Depends(get_worker),
) -> JSONResponse:
    checks: dict[str, object] = {"database": store.ping()}
    beat = store.last_heartbeat(HEARTBEAT_COMPONENT) if checks["database"] else None
    # A cycle over many robots can take longer than the interval: allow a few intervals and 30 s.
    max_age = max(3 * settings.worker_interval_seconds, 30.0)
    age = None if beat is None else time.time() - beat
    checks["worker_heartbeat_age_s"] = None if age is None else round(age, 3)
    checks["worker"] = age is not None and age <= max_age
    if worker is not None:
        checks["worker_thread"] = worker.running
    ok = bool(checks["database"]) and bool(checks["worker"])
    return JSONResponse(
        {"status": "ready" if ok else "not ready", "checks": checks}, status_code=200 if ok else 503
    )


@router.get("/metrics", summary="Prometheus metrics")
def metrics(m: Metrics = Depends(get_metrics)) -> Response:
    return Response(m.render(), media_type=CONTENT_TYPE_LATEST)
