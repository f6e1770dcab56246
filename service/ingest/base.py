"""The one abstract source every transport implements, and the frame batch it produces.

Modelled on python-can's ``BusABC``: :meth:`Source.read` is a template that calls the transport's
:meth:`Source._read_raw`, validates what comes back, and keeps the counters; a transport implements
only the raw read (and decoding of its own wire format). Bad input never raises out of ``read``: it is
counted as malformed and dropped, and everything already accepted stays accepted.

Example
-------
>>> import numpy as np
>>> class Const(Source):
...     def _read_raw(self, timeout):
...         return [FrameBatch("r1", np.array([0.0]), ("j1",), np.zeros((1, 1)), ("imu0",),
...                            np.zeros((1, 1, 3)), np.full((1, 1, 3), np.nan))]
>>> src = Const("const")
>>> src.read(0.1), src.counters.malformed
([], 1)
"""

from __future__ import annotations

import logging
import threading
from abc import ABC, abstractmethod
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Counters", "FrameBatch", "FrameError", "Source"]

log = logging.getLogger(__name__)


class FrameError(ValueError):
    """A frame batch that breaks the contract (shapes, NaN/Inf, time going backwards)."""


@dataclass(frozen=True)
class FrameBatch:
    """``T`` consecutive samples of one robot (T may be 1).

    ``t`` (T,) device time in s (never arrival time); ``q`` (T,N) rad; ``acc`` (T,K,3) m/s² specific
    force and ``gyro`` (T,K,3) rad/s in each sensor frame. An IMU that fell silent is simply absent from
    ``imu_names``; a robot without encoders has N = 0.
    """

    robot: str
    t: np.ndarray
    joint_names: tuple[str, ...]
    q: np.ndarray
    imu_names: tuple[str, ...]
    acc: np.ndarray
    gyro: np.ndarray

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def n_imu_samples(self) -> int:
        return self.n_samples * len(self.imu_names)

    def validate(self) -> None:
        """Raise :class:`FrameError` naming what is wrong."""
        if not self.robot or not isinstance(self.robot, str):
            raise FrameError("robot name must be a non-empty string")
        T, N, K = self.t.shape[0] if self.t.ndim == 1 else -1, len(self.joint_names), len(self.imu_names)
        if T < 1:
            raise FrameError(f"t must have shape (T,) with T >= 1, got {self.t.shape}")
        if self.q.shape != (T, N):
            raise FrameError(f"q must have shape {(T, N)}, got {self.q.shape}")
        for name in ("acc", "gyro"):
            v = getattr(self, name)
            if v.shape != (T, K, 3):
                raise FrameError(f"{name} must have shape {(T, K, 3)}, got {v.shape}")
        for name in ("t", "q", "acc", "gyro"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise FrameError(f"{name} contains NaN or Inf")
        if T > 1 and not np.all(np.diff(self.t) > 0):
            raise FrameError("t must be strictly increasing within a batch")


@dataclass
class Counters:
    """What a source and its pipeline saw. ``extra`` holds transport-specific counters
    (e.g. ``crc_errors``, ``sequence_gaps``, ``unknown_ids``, ``error_frames``)."""

    received: int = 0
    stored: int = 0
    dropped: int = 0
    malformed: int = 0
    extra: dict[str, int] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def add(self, name: str, n: int = 1) -> None:
        with self._lock:
            if name in ("received", "stored", "dropped", "malformed"):
                setattr(self, name, getattr(self, name) + n)
            else:
                self.extra[name] = self.extra.get(name, 0) + n

    def as_dict(self) -> dict[str, int]:
        with self._lock:
            return {
                "received": self.received,
                "stored": self.stored,
                "dropped": self.dropped,
                "malformed": self.malformed,
                **self.extra,
            }


class Source(ABC):
    """A stream of :class:`FrameBatch` from one transport. Counts are in samples (not batches)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.counters = Counters()

    def read(self, timeout: float = 0.1) -> list[FrameBatch]:
        """Up to ``timeout`` seconds of waiting; returns the valid batches, counts the rest."""
        out: list[FrameBatch] = []
        for batch in self._read_raw(timeout):
            n = max(int(getattr(batch.t, "shape", (1,))[0] or 1), 1)
            self.counters.add("received", n)
            try:
                batch.validate()
            except FrameError as err:
                self.counters.add("malformed", n)
                log.warning("source %s: dropped malformed batch: %s", self.name, err)
                continue
            out.append(batch)
        return out

    @abstractmethod
    def _read_raw(self, timeout: float) -> Iterable[FrameBatch]:
        """Transport-specific read and decode; may return an empty iterable on timeout."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the transport (port, bus, file)."""

    def __enter__(self) -> Source:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
