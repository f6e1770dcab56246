"""``GET /api/v1/robots/{robot}/status``: the monitoring answer — healthy, damaged or undetermined.

Computed here from what the store holds (newest topology, baseline, alerts) by
:func:`service.status.robot_status` (kept while only frames were committed:
:func:`service.api.cache.cached_status`), so the answer is the same whether or not a worker runs in
this process, and it is never more certain than the stored evidence (the rule is in
:mod:`service.status`, the two methods' verdict per part too).
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query, Request, Response

from service.api.cache import cached_floating, cached_status, read_cache
from service.api.deps import RobotName, get_store, known_robot
from service.api.errors import responses
from service.api.schemas import StatusOut
from service.api.topology import Method
from service.store import Store

__all__ = ["router"]

router = APIRouter(prefix="/api/v1/robots/{robot}", tags=["status"], responses=responses(401, 404, 422, 503))


@router.get(
    "/status",
    response_model=StatusOut,
    summary="healthy, damaged or undetermined, with the reasons, the trees that fit and what would decide",
    description="Also each joint's and IMU's verdict from the fast method and the sensor networks "
    "together (`parts`: agreed, unconfirmed while the networks have not answered, or undetermined, "
    "with both answers and the joints to move; `methods`: what that rests on). A part the two "
    "methods contradict keeps the robot from `healthy`.",
)
async def status(
    robot: RobotName,
    request: Request,
    store: Store = Depends(get_store),
    method: Method | None = Query(
        None, description="judge the newest topology of this method (default: fast)"
    ),
) -> Response:
    def render() -> StatusOut:
        name = known_robot(store, robot)
        return StatusOut.of(
            cached_status(request, store, name, method), cached_floating(request, store).get(name)
        )

    return await read_cache(request).respond(("status", robot, method), render)
