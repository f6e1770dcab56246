"""The retrain task under its former name (worker preloads name it): :mod:`service.retrain.task`."""

from __future__ import annotations

from service.retrain.task import (
    WARM_METHODS,
    RetrainJob,
    RetrainResult,
    WindowGone,
    job_key,
    lower_priority,
    run_retrain,
    shareable_url,
)

__all__ = [
    "WARM_METHODS",
    "RetrainJob",
    "RetrainResult",
    "WindowGone",
    "job_key",
    "lower_priority",
    "run_retrain",
    "shareable_url",
]
