"""``POST /api/v1/robots/{robot}/simulate/damage``: break a simulated robot on purpose.
``POST /api/v1/robots/{robot}/simulate/excite``: run the excitation plan (``GET .../excitation``) on a
simulated robot: the farm robot follows it from now for the plan's length, then its own motion again.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from typing import Any

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, Field

from service.api.deps import get_damage, get_robot, get_store
from service.api.errors import responses
from service.api.excitation import NOTHING_OPEN, excitation_request
from service.api.schemas import DamageIn, DamageOut
from service.control import DamageControl
from service.store import RobotInfo, Store

__all__ = ["router"]

log = logging.getLogger(__name__)

router = APIRouter(prefix="/api/v1/robots/{robot}/simulate", tags=["simulate"], responses=responses(503))

_CALLABLE = re.compile(r"[A-Za-z_][\w.]*\(\)")


def _public(err: Exception, kind: str) -> str:
    """The farm's message for a client, unless it names code (``_imu_dead() got an unexpected
    keyword ...``): how the simulator is written is none of the client's business."""
    msg = str(err)
    return f"bad arguments for {kind}" if _CALLABLE.search(msg) else msg


@router.post(
    "/damage",
    response_model=DamageOut,
    status_code=201,
    summary="damage a simulated robot (409 for a real one)",
    responses=responses(401, 404, 409, 413, 415, 422, s409="the robot is not simulated in this process"),
)
def damage(
    body: DamageIn,
    info: RobotInfo = Depends(get_robot),
    farm: DamageControl | None = Depends(get_damage),
) -> DamageOut:
    if not info.simulated or farm is None or not farm.simulates(info.name):
        raise HTTPException(
            status_code=409,
            detail=f"robot {info.name!r} is not simulated in this process; "
            "damage can only be applied to simulated robots",
        )
    params = body.model_dump(exclude={"kind"}, exclude_none=True)
    try:
        truth = farm.apply_damage(info.name, body.kind, params)
    except KeyError as err:
        raise HTTPException(
            status_code=409, detail=f"robot {info.name!r} is not simulated here: {err}"
        ) from None
    except (ValueError, TypeError) as err:
        raise HTTPException(status_code=422, detail=_public(err, body.kind)) from None
    log.warning("damage applied", extra={"robot": info.name, "kind": body.kind, "truth": truth})
    return DamageOut(robot=info.name, kind=body.kind, truth=truth)


class ExciteIn(BaseModel):
    """How long the simulated robot follows the plan."""

    seconds: float = Field(30.0, gt=0, le=600, description="length of the plan, s")


def _run_plan(control: Any, robot: str, joints: Sequence[str], seconds: float, groups: Any) -> dict[str, Any]:
    """The plan run by the farm that simulates ``robot`` (in this process or in its own: the farm
    process answers any farm method by name); ``KeyError`` when none does."""
    for src in getattr(control, "farms", ()):
        if robot in src.robot_names:
            farm = src.farm
            with src.lock:
                if hasattr(farm, "excite"):
                    return dict(farm.excite(robot, list(joints), seconds, groups))
                return dict(farm._call("excite", robot, list(joints), seconds, groups))
    raise KeyError(robot)


@router.post(
    "/excite",
    status_code=201,
    summary="run the excitation plan on a simulated robot (409 for a real one or nothing to plan)",
    responses=responses(
        401, 404, 409, 413, 415, 422, s409="not simulated in this process, or nothing undetermined to plan"
    ),
)
def excite(
    body: ExciteIn | None = None,
    info: RobotInfo = Depends(get_robot),
    farm: DamageControl | None = Depends(get_damage),
    store: Store = Depends(get_store),
) -> dict[str, Any]:
    if not info.simulated or farm is None or not farm.simulates(info.name):
        raise HTTPException(status_code=409, detail=f"robot {info.name!r} is not simulated in this process")
    joints, groups = excitation_request(store, info)
    if not joints:
        raise HTTPException(status_code=409, detail=NOTHING_OPEN)
    seconds = (body or ExciteIn()).seconds
    try:
        plan = _run_plan(farm, info.name, joints, seconds, groups)
    except KeyError:
        raise HTTPException(status_code=409, detail=f"robot {info.name!r} cannot be excited here") from None
    except ValueError as err:
        raise HTTPException(status_code=422, detail=_public(err, "excite")) from None
    log.warning("excitation started", extra={"robot": info.name, "joints": joints, "seconds": seconds})
    return {"robot": info.name, **plan}
