"""``GET /api/v1/robots/{robot}/diagnostics``: the robot's health as a ROS diagnostic_msgs/DiagnosticArray.

The levels and names are :mod:`service.diagnostics`'s; docs/service.md shows how to publish the answer on
a ROS 2 ``/diagnostics`` topic.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request, Response

from service.api.cache import cached_status, read_cache
from service.api.deps import RobotName, get_store, lookup_robot
from service.api.errors import responses
from service.api.schemas import DiagnosticArrayOut, DiagnosticStatusOut
from service.diagnostics import diagnose
from service.store import Store

__all__ = ["router"]

router = APIRouter(prefix="/api/v1/robots/{robot}", tags=["status"], responses=responses(401, 404, 422, 503))


@router.get(
    "/diagnostics",
    response_model=DiagnosticArrayOut,
    summary="ROS diagnostics: one status per robot, joint and IMU (0 OK, 1 WARN, 2 ERROR, 3 STALE)",
)
async def diagnostics(robot: RobotName, request: Request, store: Store = Depends(get_store)) -> Response:
    def render() -> DiagnosticArrayOut:
        info = lookup_robot(store, robot)
        st = cached_status(request, store, info.name)
        return DiagnosticArrayOut(status=[DiagnosticStatusOut.of(d) for d in diagnose(info, st)])

    return await read_cache(request).respond(("diagnostics", robot), render)
