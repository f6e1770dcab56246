"""``GET /api/v1/robots/{robot}/excitation``: the motion that would decide what a robot's data left open.

The joints are those the robot's latest topology names as undetermined (its undetermined reasons'
"move ... each on its own": :func:`bodyschema.excitation_plan.undecided_joints`); the plan
(:mod:`bodyschema.excitation_plan`, docs/excitation.md) moves them within the joints' limits (the
catalog model's for a simulated robot, the defaults of :mod:`simulators.limits` otherwise) from the
plan's ``start`` pose. JSON (``joints``, ``rate``, ``samples`` rows of positions in rad, and the plan's
figures) or CSV (``?format=csv``: ``time`` and one column per joint). When nothing is undetermined the
plan is empty (no samples) and ``reason`` says so; before any topology is learned it is 409.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Query, Response

from bodyschema.excitation_plan import (
    ExcitationPlan,
    JointLimits,
    PlanOptions,
    groups_from_topology,
    plan_excitation,
    undecided_joints,
)
from service.api.deps import get_robot, get_store
from service.api.errors import responses
from service.store import RobotInfo, Store

__all__ = ["NOTHING_OPEN", "excitation_request", "router"]

router = APIRouter(
    prefix="/api/v1/robots/{robot}", tags=["excitation"], responses=responses(401, 404, 422, 503)
)

#: The reason of an empty plan.
NOTHING_OPEN = "nothing to excite: the latest topology leaves no joint undetermined"


def _limits(info: RobotInfo) -> JointLimits:
    from simulators.catalog import CATALOG
    from simulators.limits import DEFAULT_ACCELERATION, DEFAULT_VELOCITY, model_limits

    if info.catalog in CATALOG:
        lim = model_limits(str(info.catalog))
        if set(info.joints) <= set(lim.names):
            return lim
    n = len(info.joints)
    inf = np.full(n, np.inf)
    return JointLimits(
        tuple(info.joints), -inf, inf, np.full(n, DEFAULT_VELOCITY), np.full(n, DEFAULT_ACCELERATION)
    )


def excitation_request(store: Store, info: RobotInfo) -> tuple[list[str], list[list[str]]]:
    """The joints to excite and the gyros' joint sets, from ``info``'s latest topology; 409 without one."""
    rec = store.latest_topology(info.name)
    if rec is None:
        raise HTTPException(status_code=409, detail=f"robot {info.name!r} has no learned topology yet")
    topo = rec.topology
    return list(undecided_joints(topo)), groups_from_topology(topo)


def _csv(plan: ExcitationPlan) -> str:
    rows = np.column_stack([plan.t, plan.q]) if plan.excited else np.zeros((0, len(plan.joint_names) + 1))
    lines = [",".join(["time", *plan.joint_names])]
    lines += [",".join(f"{x:.9g}" for x in row) for row in rows]
    return "\n".join(lines) + "\n"


@router.get(
    "/excitation",
    summary="the joint motion that decides what the latest topology left undetermined (JSON or CSV)",
    responses={
        200: {"content": {"application/json": {}, "text/csv": {}}, "description": "the plan"},
        **responses(409, s409="no topology learned yet"),
    },
)
def excitation(
    seconds: float = Query(30.0, gt=0, le=600, description="length of the plan, s"),
    rate: float = Query(100.0, ge=10, le=1000, description="sample rate of the plan, Hz"),
    format: Literal["json", "csv"] = Query("json", description="json or csv"),
    info: RobotInfo = Depends(get_robot),
    store: Store = Depends(get_store),
) -> Any:
    joints, groups = excitation_request(store, info)
    limits = _limits(info)
    q0 = np.clip(np.zeros(len(limits.names)), limits.lower, limits.upper)
    plan = plan_excitation(limits, q0, seconds, joints, groups or None, PlanOptions(rate=rate))
    if not joints:
        plan = ExcitationPlan(
            plan.joint_names, plan.rate, plan.t[:0], plan.q[:0], (), "none", None, plan.cond, 0, NOTHING_OPEN
        )
    if format == "csv":
        return Response(_csv(plan), media_type="text/csv")
    return {"robot": info.name, "start": q0.tolist(), **plan.to_json()}
