"""``/api/v1/robots/{robot}/kinematics``: the robot's learned geometry, its drift, and its URDF.

The worker estimates each robot's joint axes and IMU lever arms every ``kinematics_interval_cycles``
cycles (docs/service.md, docs/kinematics.md) and keeps two under the current topology baseline: the
first, which drift alerts compare with, and the newest. This route serves both and their comparison,
:func:`bodyschema.lever_pool.stored_drift` of the two as stored, the worker's own comparison (the
alerts are the same findings with the alert tracker's hysteresis); ``/kinematics/urdf`` the URDF of either
(:func:`bodyschema.urdf.to_urdf`, with the base joints' tilt from the specific force at q = 0 kept
in the JSON).
"""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response

from bodyschema.kinematics import Kinematics
from bodyschema.lever_pool import PoolOptions, stored_drift
from bodyschema.topology import Topology
from bodyschema.urdf import to_urdf
from service.api.cache import read_cache
from service.api.deps import RobotName, get_store, known_robot
from service.api.errors import responses
from service.api.schemas import KinematicsOut, KinematicsPair
from service.store import Store
from service.store.kinematics import StoredKinematics

__all__ = ["router"]

router = APIRouter(
    prefix="/api/v1/robots/{robot}", tags=["kinematics"], responses=responses(401, 404, 422, 503)
)


Kept = tuple[Topology | None, StoredKinematics | None, StoredKinematics | None]


def _kept(store: Store, robot: str) -> Kept:
    """The current topology baseline, and the first and newest geometry kept under it."""
    name = known_robot(store, robot)
    base = store.baseline(name)
    if base is None:
        return None, None, None
    return base.topology, store.kinematics_baseline(name, base.id), store.kinematics_latest(name, base.id)


def _pair(store: Store, robot: str, pools: PoolOptions) -> KinematicsPair:
    topo, first, newest = _kept(store, robot)
    drift = None
    if topo is not None and first is not None and newest is not None and newest.id != first.id:
        drift = [f.to_json() for f in stored_drift(first.data, newest.data, topo, pools)]
    return KinematicsPair(baseline=KinematicsOut.of(first), latest=KinematicsOut.of(newest), drift=drift)


@router.get(
    "/kinematics",
    response_model=KinematicsPair,
    summary="joint axes and IMU lever arms as learned under the baseline and as now, and their drift",
)
async def kinematics(robot: RobotName, request: Request, store: Store = Depends(get_store)) -> Response:
    pools = request.app.state.settings.pool_options
    return await read_cache(request).respond(("kinematics", robot), lambda: _pair(store, robot, pools))


@router.get(
    "/kinematics/urdf",
    response_class=Response,
    summary="the learned geometry as URDF (links, revolute joints, IMU frames as fixed links)",
    responses={
        200: {"content": {"application/xml": {}}, "description": "URDF XML"},
        **responses(404, s404="unknown robot, or no geometry learned yet"),
    },
)
def urdf(
    robot: RobotName,
    store: Store = Depends(get_store),
    which: Literal["latest", "baseline"] = Query("latest", description="the newest or the baseline's"),
) -> Response:
    topo, first, newest = _kept(store, robot)
    kept = newest if which == "latest" else first
    if topo is None or kept is None:
        raise HTTPException(status_code=404, detail=f"no geometry learned yet for robot {robot!r}")
    xml = to_urdf(Kinematics.from_json(kept.data, topo), name=robot)
    return Response(
        xml,
        media_type="application/xml",
        headers={"Content-Disposition": f'inline; filename="{robot}.urdf"'},
    )
