"""FastAPI dependencies: the only way a route reaches the store, the worker or the damage injector.

Everything lives on ``app.state`` (set by :func:`service.api.create_app`), so one process may host
several apps (tests) and nothing is a module-level global.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import HTTPException, Request

from service.metrics import Metrics
from service.settings import Settings
from service.store import RobotInfo, Store
from service.worker import Worker

__all__ = [
    "DamageInjector",
    "get_injector",
    "get_metrics",
    "get_robot",
    "get_settings_dep",
    "get_store",
    "get_worker",
]

#: ``(robot, kind, params) -> diff JSON``; raises ``KeyError`` for a robot it does not simulate and
#: ``ValueError`` for arguments it cannot apply.
DamageInjector = Callable[[str, str, dict[str, Any]], dict[str, Any]]


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_settings_dep(request: Request) -> Settings:
    return request.app.state.settings


def get_worker(request: Request) -> Worker | None:
    return request.app.state.worker


def get_metrics(request: Request) -> Metrics:
    return request.app.state.metrics


def get_injector(request: Request) -> DamageInjector | None:
    return request.app.state.injector


def get_robot(robot: str, request: Request) -> RobotInfo:
    """The path's robot, or 404."""
    info = get_store(request).robot(robot)
    if info is None:
        raise HTTPException(status_code=404, detail=f"unknown robot {robot!r}")
    return info
