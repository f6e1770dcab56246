"""The cluster retrains' queue under its former name: :mod:`service.retrain` holds it."""

from __future__ import annotations

from service.retrain.options import RetrainLimits, TrainingOptions
from service.retrain.queue import RemoteRetrains, RetrainQueueEntry

__all__ = ["RemoteRetrains", "RetrainLimits", "RetrainQueueEntry", "TrainingOptions"]
