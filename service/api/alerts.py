"""Alerts: per robot and across robots, and acknowledging them.

``state=pending`` lists what the fast screen saw and the worker has not raised yet (waiting for more
cycles, or for the sensor networks' confirmation: its ``note`` says which); an active alert's
``confirmed`` says whether the networks confirmed it. Acknowledging writes one row in its own
transaction: it never waits for the worker.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request, Response

from service.api.cache import read_cache
from service.api.deps import RobotName, get_robot, get_store, known_robot
from service.api.errors import responses
from service.api.schemas import AlertOut
from service.store import ALERT_STATES, RobotInfo, Store

__all__ = ["router"]

router = APIRouter(prefix="/api/v1", tags=["alerts"], responses=responses(401, 422, 503))

#: Alert ids are the database's 64-bit keys: anything outside is a 422, never an overflow further down.
AlertId = Annotated[int, Path(ge=1, le=2**63 - 1, description="alert id (a signed 64-bit key)")]

ACTIVE = Query(None, description="true: active only; false: pending and resolved only; absent: all")
STATE = Query(
    None, description=f"one state only: {', '.join(ALERT_STATES)}", pattern="^(pending|active|resolved)$"
)


@router.get("/alerts", response_model=list[AlertOut], summary="alerts of every robot, newest first")
async def all_alerts(
    request: Request,
    store: Store = Depends(get_store),
    active: bool | None = ACTIVE,
    state: str | None = STATE,
    limit: int = Query(500, ge=1, le=10000),
) -> Response:
    return await read_cache(request).respond(
        ("alerts", active, state, limit),
        lambda: [AlertOut.of(a) for a in store.alerts(active=active, state=state, limit=limit)],
    )


@router.get(
    "/robots/{robot}/alerts",
    response_model=list[AlertOut],
    summary="one robot's alerts",
    responses=responses(404),
)
async def robot_alerts(
    robot: RobotName,
    request: Request,
    store: Store = Depends(get_store),
    active: bool | None = ACTIVE,
    state: str | None = STATE,
    limit: int = Query(500, ge=1, le=10000),
) -> Response:
    def render() -> list[AlertOut]:
        name = known_robot(store, robot)
        return [AlertOut.of(a) for a in store.alerts(name, active=active, state=state, limit=limit)]

    return await read_cache(request).respond(("robot_alerts", robot, active, state, limit), render)


def _ack(store: Store, alert_id: int, robot: str | None) -> AlertOut:
    if robot is not None and not any(a.id == alert_id for a in store.alerts(robot)):
        raise HTTPException(status_code=404, detail=f"robot {robot!r} has no alert {alert_id}")
    a = store.ack_alert(alert_id)
    if a is None:
        raise HTTPException(status_code=404, detail=f"unknown alert {alert_id}")
    return AlertOut.of(a)


@router.post(
    "/alerts/{alert_id}/ack",
    response_model=AlertOut,
    summary="acknowledge an alert",
    responses=responses(404, 413, 415),
)
def ack(alert_id: AlertId, store: Store = Depends(get_store)) -> AlertOut:
    return _ack(store, alert_id, None)


@router.post(
    "/robots/{robot}/alerts/{alert_id}/ack",
    response_model=AlertOut,
    summary="acknowledge one of this robot's alerts",
    responses=responses(404, 413, 415),
)
def ack_robot(
    alert_id: AlertId, info: RobotInfo = Depends(get_robot), store: Store = Depends(get_store)
) -> AlertOut:
    return _ack(store, alert_id, info.name)
