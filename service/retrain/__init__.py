"""The sensor-network retrains on the Dask cluster: what they are told, the task, and the queue.

* :mod:`service.retrain.options`: :class:`TrainingOptions` (how the networks train, the training
  thread's priority; mapped from the settings in one place) and :class:`RetrainLimits` (admission);
* :mod:`service.retrain.task`: one retrain as a task in a worker process (:func:`run_retrain` on a
  :class:`RetrainJob`);
* :mod:`service.retrain.queue`: :class:`RemoteRetrains`, the worker's queue of them (wanting,
  admission, submission, collection).
"""

from __future__ import annotations

from service.retrain.options import NetworkOptions, RetrainLimits, TrainingOptions
from service.retrain.queue import RemoteRetrains, RetrainQueueEntry
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
    "NetworkOptions",
    "RemoteRetrains",
    "RetrainJob",
    "RetrainLimits",
    "RetrainQueueEntry",
    "RetrainResult",
    "TrainingOptions",
    "WindowGone",
    "job_key",
    "lower_priority",
    "run_retrain",
    "shareable_url",
]
