"""The one abstract source every transport implements (it produces :class:`~service.frames.FrameBatch`).

Modelled on python-can's ``BusABC``: :meth:`Source.read` is a template that calls the transport's
:meth:`Source._read_raw`, validates what comes back, and keeps the counters; a transport implements
only the raw read (and decoding of its own wire format). Bad input never raises out of ``read``: it is
counted as malformed and dropped, and everything already accepted stays accepted.

A robot that logs its encoders on a clock of their own sends a *multi-rate* batch
(docs/recording-format.md): ``t_q`` stamps the encoder stream, ``q`` (and ``qd`` when the encoders
report velocity) lie on ``t_q``, and ``t`` stamps only the IMU stream. Nothing is resampled on the way
in: the estimators align the two streams themselves.

Example
-------
>>> import numpy as np
>>> from service.frames import FrameBatch
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
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from service.frames import FrameBatch, FrameError

__all__ = ["Counters", "Source"]

log = logging.getLogger(__name__)


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

    def simulated_robots(self) -> dict[str, str]:
        """Robots this source simulates, name -> catalog model (a real device: none). The pipeline
        registers them in the store when it starts, so the API knows which robots may be damaged on
        purpose; the source itself never writes the store."""
        return {}

    def resume_after(self, last_frame_t: Mapping[str, float]) -> None:  # noqa: B027 - optional hook
        """Told by the pipeline when it starts: the device time of the last stored frame of every robot
        the store holds. A source that can seek (a replay) starts after it; a live device ignores it."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the transport (port, bus, file)."""

    def __enter__(self) -> Source:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
