"""The iCub walking log as a floating-base robot's frames: the log, fed into a store in live-sized
batches, under a wall clock that follows the worker's cycles."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import pytest

from bodyschema.recording import Recording
from service.ingest.replay import recording_batch
from service.store import Store
from tests.robot_data import MAPS, ROBOTS

__all__ = ["LOG", "ROBOT", "feed", "icub_log", "no_fixed_fit", "ticking"]

LOG = ROBOTS / "icub-walking" / "sync-walkingFrontAndBackGoodTrial.mat"
ROBOT = "icub"


def icub_log() -> Recording:
    from sim2real.robot_logs import import_log

    if not LOG.is_file():
        pytest.skip(f"robot log missing: {LOG}")
    return import_log(LOG, MAPS / "icub-walking.toml", "mat")[0]


def feed(store: Store, rec: Recording, forces: bool = True) -> None:
    """``rec``'s frames into the store in 1 s batches (what a live source writes), with its foot
    forces as channels (``forces``) or without (a source that has none)."""
    n = round(rec.sample_rate)
    for s in range(0, rec.n_samples, n):
        batch = recording_batch(ROBOT, rec, slice(s, s + n))
        store.write(batch if forces else dataclasses.replace(batch, channel_names=(), channels=None))


def ticking(start: float = 1000.0, step: float = 1e-3) -> Callable[[], float]:
    """A wall clock that moves ``step`` s per reading (the worker's idle rule follows the cycles)."""
    now = [start]

    def clock() -> float:
        now[0] += step
        return now[0]

    return clock


def no_fixed_fit(rec: Recording, method: str) -> None:
    raise AssertionError("a floating-base robot must not reach the fixed-base estimator")
