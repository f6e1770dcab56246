"""``/api/v1/robots``: the robots the store knows, each with its monitoring answer, and frames pushed
over HTTP."""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter, Depends, HTTPException

from service.api.deps import get_pipeline, get_robot, get_store
from service.api.schemas import FramesIn, RobotOut, StatusOut
from service.frames import FrameBatch, FrameError
from service.ingest.pipeline import IngestUnavailable, Pipeline
from service.status import robot_status
from service.store import RobotInfo, Store

__all__ = ["router"]

router = APIRouter(prefix="/api/v1/robots", tags=["robots"])


def _out(store: Store, info: RobotInfo) -> RobotOut:
    # The status read already fetches the baseline and the active alerts: the counts come from it.
    st = robot_status(store, info.name)
    return RobotOut.of(
        info, has_baseline=st.baseline is not None, active_alerts=len(st.alerts), status=StatusOut.of(st)
    )


@router.get("", response_model=list[RobotOut], summary="every robot with its parts, alert count and status")
def list_robots(store: Store = Depends(get_store)) -> list[RobotOut]:
    return [_out(store, r) for r in store.robots()]


@router.get(
    "/{robot}",
    response_model=RobotOut,
    summary="one robot: joints, IMUs, excitation, last frame, status (healthy/damaged/undetermined)",
)
def robot_detail(info: RobotInfo = Depends(get_robot), store: Store = Depends(get_store)) -> RobotOut:
    return _out(store, info)


@router.post("/{robot}/frames", status_code=201, summary="push frames of one robot (registers it when new)")
def push_frames(robot: str, body: FramesIn, pipeline: Pipeline = Depends(get_pipeline)) -> dict[str, int]:
    """Frames go through the ingest pipeline like a device's (validated, queued behind what was read,
    written by its writer, counted under the ``api`` source); the answer waits for the commit."""
    try:
        batch = FrameBatch(
            robot,
            np.asarray(body.t, float),
            tuple(body.joint_names),
            np.asarray(body.q, float).reshape(len(body.t), len(body.joint_names)),
            tuple(body.imu_names),
            np.asarray(body.acc, float),
            np.asarray(body.gyro, float),
        )
        return {"stored": pipeline.submit(batch)}
    except (FrameError, ValueError) as err:
        raise HTTPException(status_code=422, detail=str(err)) from None
    except IngestUnavailable as err:
        raise HTTPException(status_code=503, detail=f"frames not stored: {err}") from None
