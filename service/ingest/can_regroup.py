"""Regroup decoded CAN frames into samples by the device sample counter.

Frames of one sampling instant share a counter value. A sample is released when all its frames have
arrived, or when the newest counter seen is ``horizon`` samples ahead of it (its missing frames are taken
as lost), always in counter order so time never goes backwards.

What happens to an incomplete sample (documented policy):

- every joint frame present, some IMU frames missing: the sample is **used** without the IMUs that miss
  an accelerometer or gyroscope frame (``samples_incomplete``); the other IMUs and the joints are kept;
- a joint frame missing: the sample is **dropped** (``samples_dropped``), since a joint position cannot
  be left out of a sample.

``frames_missing`` counts the frames that never came. A frame for a sample already released is
``late_frames``; a repeat of a frame already held is ``duplicate_frames``; a frame the DBC cannot decode
(short DLC, bad multiplexer) is ``decode_errors``; an id the mapping does not use is ``unknown_ids``.

Example
-------
>>> import numpy as np
>>> from service.ingest.can_layout import encode_samples
>>> from service.ingest.can_mapping import SignalMap
>>> from service.ingest.device import DeviceConfig
>>> cfg = DeviceConfig("r1", 0.01, ("j1",), ("imu0",))
>>> asm = SampleAssembler(SignalMap.for_config(cfg))
>>> ids, data = encode_samples(np.array([5, 6]), np.array([[0.1], [0.2]]), np.ones((2, 1, 3)),
...                            np.zeros((2, 1, 3)))
>>> for t in range(2):
...     for f in range(3):
...         if (t, f) != (1, 2):  # the second sample loses its gyro frame
...             asm.add(int(ids[f]), data[t, f].tobytes())
>>> [(b.t.tolist(), b.imu_names) for b in asm.take(flush=True)]
[([0.05], ('imu0',)), ([0.06], ())]
>>> asm.counts["samples_incomplete"], asm.counts["frames_missing"]
(1, 1)
"""

from __future__ import annotations

import logging
from collections import Counter

import numpy as np

from service.ingest.base import FrameBatch
from service.ingest.can_mapping import ACC, Q, SignalMap
from service.ingest.device import DeviceClock

__all__ = ["SampleAssembler"]

log = logging.getLogger(__name__)


class _Pending:
    __slots__ = ("acc", "gyro", "q", "seen")

    def __init__(self, n: int, k: int) -> None:
        self.q = np.zeros(n)
        self.acc = np.zeros((k, 3))
        self.gyro = np.zeros((k, 3))
        self.seen: set[int] = set()


class SampleAssembler:
    """Frames in (``add``), :class:`~service.ingest.base.FrameBatch` out (``take``). Not thread-safe:
    the caller holds a lock around both."""

    def __init__(self, signal_map: SignalMap, horizon: int = 4, reset_after: int = 256) -> None:
        if horizon < 1:
            raise ValueError("horizon must be >= 1")
        self.map = signal_map
        self.horizon = horizon
        self.clock = DeviceClock(bits=signal_map.counter_bits, reset_after=reset_after)
        self.counts: Counter[str] = Counter()
        cfg = signal_map.config
        self._n, self._k = len(cfg.joints), len(cfg.imus)
        self._pending: dict[int, _Pending] = {}
        self._ready: list[tuple[int, _Pending, tuple[bool, ...]]] = []
        self._last_released: int | None = None
        self._newest: int | None = None
        self._routes = {fid: (r.message, r.targets) for fid, r in signal_map.by_id.items()}
        self._counter = signal_map.counter_signal
        self._all_imus = (True,) * self._k

    @property
    def ready(self) -> int:
        """Samples released and waiting to be taken."""
        return len(self._ready)

    @property
    def pending(self) -> int:
        return len(self._pending)

    def add(self, frame_id: int, data: bytes | bytearray) -> None:
        """Take one data frame; never raises for bad frames (they are counted)."""
        route = self._routes.get(frame_id)
        if route is None:
            self.counts["unknown_ids"] += 1
            return
        msg, targets = route
        try:
            values = msg.decode(bytes(data), decode_choices=False)
            raw = int(values[self._counter])
        except Exception as err:  # cantools raises several types; one bad frame must not stop ingest
            self.counts["decode_errors"] += 1
            log.debug("frame 0x%x: cannot decode %s: %s", frame_id, bytes(data).hex(), err)
            return
        idx = self.clock.index(raw)
        if self._last_released is not None and idx <= self._last_released:
            self.counts["late_frames"] += 1
            return
        p = self._pending.get(idx)
        if p is None:
            p = self._pending[idx] = _Pending(self._n, self._k)
        elif frame_id in p.seen:
            self.counts["duplicate_frames"] += 1
            return
        try:
            for name, kind, i, axis, factor in targets:
                v = float(values[name]) * factor
                if kind == Q:
                    p.q[i] = v
                elif kind == ACC:
                    p.acc[i, axis] = v
                else:
                    p.gyro[i, axis] = v
        except (KeyError, TypeError, ValueError) as err:
            self.counts["decode_errors"] += 1
            log.debug("frame 0x%x: unusable values: %s", frame_id, err)
            return
        p.seen.add(frame_id)
        self.counts["frames"] += 1
        advanced = self._newest is None or idx > self._newest
        if advanced:
            self._newest = idx
        if advanced or len(p.seen) == self.map.n_frames:
            self._release(force=False)

    def _release(self, force: bool) -> None:
        pend, newest, n_frames = self._pending, self._newest, self.map.n_frames
        while pend:
            idx = min(pend)
            p = pend[idx]
            complete = len(p.seen) == n_frames
            if not (complete or force or newest - idx >= self.horizon):
                break
            del pend[idx]
            self._last_released = idx
            if complete:
                self._ready.append((idx, p, self._all_imus))
                continue
            self.counts["frames_missing"] += n_frames - len(p.seen)
            if not self.map.joint_frames <= p.seen:
                self.counts["samples_dropped"] += 1
                continue
            present = tuple(f <= p.seen for f in self.map.imu_frames)
            self.counts["samples_incomplete"] += 1
            self._ready.append((idx, p, present))

    def take(self, flush: bool = False) -> list[FrameBatch]:
        """Released samples as batches (one per run of samples with the same IMUs present).

        ``flush`` releases every pending sample now (end of stream, or the bus went quiet)."""
        if flush:
            self._release(force=True)
        ready, self._ready = self._ready, []
        out: list[FrameBatch] = []
        cfg = self.map.config
        i = 0
        while i < len(ready):
            mask = ready[i][2]
            j = i + 1
            while j < len(ready) and ready[j][2] == mask:
                j += 1
            run = ready[i:j]
            t = np.array([r[0] for r in run], dtype=np.float64) * cfg.period_s
            q = np.stack([r[1].q for r in run]) if self._n else np.zeros((len(run), 0))
            sel = np.flatnonzero(mask)
            acc = np.stack([r[1].acc[sel] for r in run]) if self._k else np.zeros((len(run), 0, 3))
            gyro = np.stack([r[1].gyro[sel] for r in run]) if self._k else np.zeros((len(run), 0, 3))
            names = tuple(cfg.imus[s] for s in sel)
            out.append(FrameBatch(cfg.robot, t, cfg.joints, q, names, acc, gyro))
            i = j
        return out
