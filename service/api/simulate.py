"""``POST /api/v1/robots/{robot}/simulate/damage``: break a simulated robot on purpose."""

from __future__ import annotations

import logging
import re

from fastapi import APIRouter, Depends, HTTPException

from service.api.deps import get_damage, get_robot
from service.api.errors import responses
from service.api.schemas import DamageIn, DamageOut
from service.control import DamageControl
from service.store import RobotInfo

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
