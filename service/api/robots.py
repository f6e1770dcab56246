"""``/api/v1/robots``: the robots the store knows, each with its monitoring answer, and frames pushed
over HTTP."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Request, Response

from service.api.cache import FLEET_STATUSES, cached_floating, cached_status, read_cache
from service.api.deps import RobotName, get_pipeline, get_settings_dep, get_store, lookup_robot
from service.api.errors import responses
from service.api.schemas import FramesIn, RobotOut, StatusOut
from service.frames import FrameBatch, FrameError
from service.ingest.pipeline import IngestUnavailable, Pipeline
from service.settings import Settings
from service.status import RobotStatus, robot_statuses
from service.store import RobotInfo, Store

__all__ = ["router"]

router = APIRouter(prefix="/api/v1/robots", tags=["robots"], responses=responses(401, 503))


def _out(request: Request, store: Store, info: RobotInfo, st: RobotStatus | None = None) -> RobotOut:
    # The status read already fetches the baseline and the active alerts: the counts come from it.
    st = st or cached_status(request, store, info.name)
    status = StatusOut.of(st, cached_floating(request, store).get(info.name))
    return RobotOut.of(info, has_baseline=status.has_baseline, active_alerts=len(st.alerts), status=status)


@router.get("", response_model=list[RobotOut], summary="every robot with its parts, alert count and status")
async def list_robots(request: Request, store: Store = Depends(get_store)) -> Response:
    def render() -> list[RobotOut]:
        infos = store.robots()
        names = tuple(r.name for r in infos)
        # every robot's status in one read of the fleet, kept as one robot's is (cached_status) while
        # it holds every robot listed
        cache = read_cache(request)
        statuses = cache.memo(
            FLEET_STATUSES,
            lambda: robot_statuses(store, names, judged=cache.judged),
            usable=lambda kept: set(names) <= kept.keys(),
        )
        return [_out(request, store, r, statuses.get(r.name)) for r in infos]

    return await read_cache(request).respond(("robots",), render)


@router.get(
    "/{robot}",
    response_model=RobotOut,
    summary="one robot: joints, IMUs, excitation, last frame, status (healthy/damaged/undetermined)",
    responses=responses(404, 422),
)
async def robot_detail(robot: RobotName, request: Request, store: Store = Depends(get_store)) -> Response:
    return await read_cache(request).respond(
        ("robot", robot), lambda: _out(request, store, lookup_robot(store, robot))
    )


def _array(name: str, rows: Sequence[object]) -> np.ndarray:
    """Nested lists as a float array; rows of unequal length are named, not left to numpy's message."""
    try:
        return np.asarray(rows, dtype=float)
    except ValueError:
        raise FrameError(f"{name} has rows of unequal length") from None


def _batch(robot: str, body: FramesIn) -> FrameBatch:
    T, N = len(body.t), len(body.joint_names)
    q = _array("q", body.q)
    if q.size == 0 and T * N == 0:  # no encoders: [] and [[], ...] both mean (T, 0)
        q = q.reshape(T, N)
    return FrameBatch(
        robot,
        np.asarray(body.t, dtype=float),
        tuple(body.joint_names),
        q,
        tuple(body.imu_names),
        _array("acc", body.acc),
        _array("gyro", body.gyro),
        channel_names=tuple(body.channel_names),
        channels=_array("channels", body.channels) if body.channels else None,
    )


def _check_jump(batch: FrameBatch, last_t: float | None, bound: float) -> None:
    """Refuse a batch that starts a robot's device time over anew far ahead of its stored frames.

    Device time is the robot's own clock, so it is never compared with the wall clock; but one batch
    stamped ``bound`` seconds past the robot's newest frame would move its window there and leave
    everything stored behind. Going backwards is allowed: a little is an overlap (a later write wins),
    more than ``clock_reset_seconds`` a restarted clock, which starts a new epoch
    (:mod:`service.store.frames`)."""
    if last_t is None:
        return
    end = max(float(batch.t[-1]), float(batch.encoder_t[-1]))
    if np.isfinite(end) and end - last_t > bound:
        raise FrameError(
            f"t jumps {end - last_t:.6g} s ahead of the robot's newest stored frame (t = {last_t:.6g} s); "
            f"at most max_time_jump_seconds = {bound:g} s is accepted"
        )


@router.post(
    "/{robot}/frames",
    status_code=201,
    summary="push frames of one robot (registers it when new)",
    responses=responses(
        413, 415, 422, 503, s503="frames not stored in time (ingest queue full, database down)"
    ),
)
def push_frames(
    robot: RobotName,
    body: FramesIn,
    pipeline: Pipeline = Depends(get_pipeline),
    store: Store = Depends(get_store),
    settings: Settings = Depends(get_settings_dep),
) -> dict[str, int]:
    """Frames go through the ingest pipeline like a device's (validated, queued behind what was read,
    written by its writer, counted under the ``api`` source); the answer waits for the commit."""
    try:
        batch = _batch(robot, body)
        info = store.robot(robot)
        try:
            _check_jump(batch, info.last_frame_t if info else None, settings.max_time_jump_seconds)
        except FrameError:
            pipeline.push_source.counters.add("received", batch.n_samples)
            pipeline.push_source.counters.add("malformed", batch.n_samples)
            raise
        return {"stored": pipeline.submit(batch)}
    except (FrameError, ValueError) as err:
        raise HTTPException(status_code=422, detail=str(err)) from None
    except IngestUnavailable as err:
        raise HTTPException(status_code=503, detail=f"frames not stored: {err}") from None
