"""FastAPI dependencies: the only way a route reaches the store, the ingest pipeline, the worker or the
farm. The worker and the farm are reached through the protocols of :mod:`service.control`.

Everything lives on ``app.state`` (set by :func:`service.api.create_app`), so one process may host
several apps (tests) and nothing is a module-level global. The getters are ``async``: they only read
``app.state``, and FastAPI would run a plain ``def`` dependency on a worker thread, a thread hop per
dependency per request.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import HTTPException, Path, Request

from service.control import DamageControl, MonitorControl
from service.frames import NAME_PATTERN, NAME_RULE
from service.ingest.pipeline import Pipeline
from service.metrics import Metrics
from service.settings import Settings
from service.store import RobotInfo, Store

__all__ = [
    "RobotName",
    "get_damage",
    "get_metrics",
    "get_pipeline",
    "get_robot",
    "get_settings_dep",
    "get_store",
    "get_worker",
    "known_robot",
    "lookup_robot",
]

#: The ``{robot}`` path parameter: a name as every ingest source must give it (service.frames).
RobotName = Annotated[
    str, Path(pattern=NAME_PATTERN, description=f"robot name: {NAME_RULE}", examples=["ur5e-1"])
]


async def get_store(request: Request) -> Store:
    return request.app.state.store


async def get_settings_dep(request: Request) -> Settings:
    return request.app.state.settings


async def get_pipeline(request: Request) -> Pipeline:
    return request.app.state.pipeline


async def get_worker(request: Request) -> MonitorControl | None:
    return request.app.state.worker


async def get_metrics(request: Request) -> Metrics:
    return request.app.state.metrics


async def get_damage(request: Request) -> DamageControl | None:
    return request.app.state.damage


def lookup_robot(store: Store, robot: str) -> RobotInfo:
    """Robot ``robot`` of ``store``, or 404."""
    info = store.robot(robot)
    if info is None:
        raise HTTPException(status_code=404, detail=f"unknown robot {robot!r}")
    return info


def known_robot(store: Store, robot: str) -> str:
    """The name ``robot``, or 404 when ``store`` never saw it: for routes that read by name and need
    nothing else of the robot (no query once the robot's id is known, where :func:`lookup_robot`
    reads its parts every time)."""
    if not store.knows(robot):
        raise HTTPException(status_code=404, detail=f"unknown robot {robot!r}")
    return robot


def get_robot(robot: RobotName, request: Request) -> RobotInfo:
    """The path's robot, or 404."""
    return lookup_robot(request.app.state.store, robot)
