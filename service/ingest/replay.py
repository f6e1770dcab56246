"""Replay a recording (an ``.npz``, docs/design.md, 'Recording') as a live source, at N× real time, in
device-time chunks.

The recording's own time stamps are the device time of the frames. ``speed=1`` paces batches to the
wall clock, ``speed=10`` ten times faster, ``speed=math.inf`` as fast as the pipeline takes them.
``loop=True`` starts over at the end with time shifted on (device time keeps increasing). When the
pipeline starts, it tells the replay the last frame the store already has of this robot
(:meth:`ReplaySource.resume_after`), so a restarted ingest neither duplicates nor skips frames.

A multi-rate recording (encoders on stamps of their own, docs/recording-format.md) replays as
multi-rate batches: each chunk cuts both streams at the same device times, each by its own stamps, and
a chunk that would leave either stream empty joins the next one.

Example
-------
>>> import numpy as np
>>> from bodyschema.recording import Recording
>>> rec = Recording(t=np.arange(50) * 0.01, joint_names=["j1"], q=np.zeros((50, 1)), imu_names=["imu0"],
...                 acc=np.zeros((50, 1, 3)), gyro=np.zeros((50, 1, 3)))
>>> src = ReplaySource(rec, robot="arm", speed=math.inf, chunk_seconds=0.2)
>>> [b.n_samples for b in src.read()], src.exhausted
([20, 20, 10], True)
"""

from __future__ import annotations

import itertools
import math
import os
import re
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from bodyschema.recording import Recording
from service.frames import NAME_PATTERN, FrameBatch, FrameError, check_names
from service.ingest.base import Source
from simulators.recording_io import load_recording

_NAME = re.compile(NAME_PATTERN)

__all__ = ["ReplaySource", "recording_batch", "recording_channels"]


def recording_channels(rec: Recording) -> tuple[tuple[str, ...], np.ndarray | None]:
    """The extras of ``rec`` that run along its IMU stamps ``t``, as a batch's channels: names and a
    (T, E) array (None when there are none). A (T, k) extra becomes ``k`` channels ``name.0`` ...
    (a channel is one scalar series); extras of other lengths (flags, calibrations), with NaN or Inf,
    or with names a channel may not have stay with the file.

    >>> rec = Recording(t=np.arange(3) * 0.01, joint_names=["j"], q=np.zeros((3, 1)), imu_names=["i"],
    ...                 acc=np.zeros((3, 1, 3)), gyro=np.zeros((3, 1, 3)),
    ...                 extra={"foot_force": np.ones((3, 2)), "floating_base": np.array([1])})
    >>> recording_channels(rec)[0]
    ('foot_force.0', 'foot_force.1')
    """
    names: list[str] = []
    cols: list[np.ndarray] = []
    for key in sorted(rec.extra):
        v = np.asarray(rec.extra[key])
        if v.dtype.kind not in "fiub" or v.shape[:1] != rec.t.shape or v.ndim > 2:
            continue
        v = v.reshape(v.shape[0], -1).astype(float)
        keys = (
            [key]
            if v.shape[1] == 1 and rec.extra[key].ndim == 1
            else [f"{key}.{i}" for i in range(v.shape[1])]
        )
        if not all(_NAME.fullmatch(k) for k in keys) or not np.isfinite(v).all():
            continue
        names += keys
        cols += [v[:, i] for i in range(v.shape[1])]
    return tuple(names), (np.stack(cols, axis=1) if cols else None)


def recording_batch(
    robot: str,
    rec: Recording,
    index: slice = slice(None),
    t_offset: float = 0.0,
    qindex: slice | None = None,
    channels: tuple[tuple[str, ...], np.ndarray | None] | None = None,
) -> FrameBatch:
    """Samples ``index`` of ``rec`` as a frame batch of ``robot`` (a recording without encoders gives
    N = 0 joints). A multi-rate recording gives a multi-rate batch: ``index`` picks IMU samples and
    ``qindex`` (default: all) encoder samples; the encoders' own ``qd`` travels along, and so do the
    extras along ``t`` (``channels``: :func:`recording_channels` of ``rec``, which a caller cutting one
    recording into many batches computes once)."""
    t = rec.t[index]
    cn, ch = recording_channels(rec) if channels is None else channels
    extra = {"channel_names": cn, "channels": None if ch is None else ch[index]}
    if rec.t_q is not None:
        assert rec.q is not None  # a multi-rate recording always has encoders
        qi = slice(None) if qindex is None else qindex
        t_q = rec.t_q[qi]
        return FrameBatch(
            robot,
            t + t_offset if t_offset else t,
            rec.joint_names,
            rec.q[qi],
            rec.imu_names,
            rec.acc[index],
            rec.gyro[index],
            t_q=t_q + t_offset if t_offset else t_q,
            qd=None if rec.qd is None else rec.qd[qi],
            **extra,
        )
    q = rec.q[index] if rec.q is not None else np.zeros((t.shape[0], 0))
    names = rec.joint_names if rec.q is not None else ()
    return FrameBatch(
        robot,
        t + t_offset if t_offset else t,
        names,
        q,
        rec.imu_names,
        rec.acc[index],
        rec.gyro[index],
        **extra,
    )


def _chunk_bounds(t: np.ndarray, t0: float, chunk_seconds: float, dt: float, span: float) -> np.ndarray:
    """Indices into ``t`` where chunks of ``chunk_seconds`` from ``t0`` start (with 0 and len(t))."""
    # Chunk k holds t0 + k*chunk <= t < t0 + (k+1)*chunk; the slack keeps a sample that sits on an
    # edge (up to float rounding) at the start of the next chunk.
    edges = t0 + chunk_seconds * np.arange(1, int(np.ceil(span / chunk_seconds)) + 2)
    return np.concatenate([[0], np.searchsorted(t, edges - 1e-6 * dt, side="left"), [t.shape[0]]])


class ReplaySource(Source):
    """A recording played back as :class:`FrameBatch` es of ``chunk_seconds`` device time each.

    ``recording`` is a :class:`Recording` or a path to an ``.npz``; ``robot`` defaults to the file's
    stem. ``max_batches_per_read`` bounds one unpaced read so the reader thread stays responsive.
    """

    def __init__(
        self,
        recording: Recording | str | os.PathLike[str],
        robot: str | None = None,
        *,
        speed: float = 1.0,
        chunk_seconds: float = 0.1,
        loop: bool = False,
        resume: bool = True,
        max_batches_per_read: int = 50,
        name: str | None = None,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if isinstance(recording, Recording):
            rec, stem = recording, "replay"
        else:
            rec, stem = load_recording(recording), Path(recording).stem
        if not speed > 0:
            raise ValueError(f"speed must be positive (math.inf = as fast as possible), got {speed}")
        if not chunk_seconds > 0:
            raise ValueError(f"chunk_seconds must be positive, got {chunk_seconds}")
        self.robot = robot or stem
        try:  # refuse at start, not batch by batch once the pipeline runs
            check_names(self.robot, tuple(rec.joint_names), tuple(rec.imu_names))
        except FrameError as err:
            hint = "" if robot is not None else " (a file name is the default robot name: give ?robot=NAME)"
            raise ValueError(f"cannot replay {stem!r}: {err}{hint}") from err
        super().__init__(name or f"replay:{self.robot}")
        self.recording = rec
        self._channels = recording_channels(rec)  # once, not per batch: they span the whole file
        self.speed = float(speed)
        self.loop = bool(loop)
        self.resume = bool(resume)
        self.max_batches_per_read = int(max_batches_per_read)
        self._clock, self._sleep = clock, sleep
        t = rec.t
        dt = float(np.median(np.diff(t))) if t.shape[0] > 1 else chunk_seconds
        te = rec.encoder_t
        t0, t1 = min(float(t[0]), float(te[0])), max(float(t[-1]), float(te[-1]))
        cuts = _chunk_bounds(t, t0, chunk_seconds, dt, t1 - t0)
        #: per chunk: (IMU start, IMU stop, encoder start, encoder stop) indices
        self._bounds: list[tuple[int, int, int, int]] = []
        if rec.t_q is None:
            bounds = np.unique(cuts)
            self._bounds = [(int(a), int(b), int(a), int(b)) for a, b in itertools.pairwise(bounds) if b > a]
        else:
            dtq = float(np.median(np.diff(te))) if te.shape[0] > 1 else chunk_seconds
            qcuts = _chunk_bounds(te, t0, chunk_seconds, min(dt, dtq), t1 - t0)
            a = aq = 0
            for b, bq in zip(cuts[1:], qcuts[1:], strict=True):
                if b > a and bq > aq:  # both streams have samples: a chunk of its own
                    self._bounds.append((a, int(b), aq, int(bq)))
                    a, aq = int(b), int(bq)
            if a < t.shape[0] or aq < te.shape[0]:  # a tail with one stream only joins the last chunk
                if self._bounds:
                    pa, _, pq, _ = self._bounds.pop()
                    a, aq = pa, pq
                self._bounds.append((a, t.shape[0], aq, te.shape[0]))
        self._period = t1 - t0 + dt  # device-time shift per loop
        self._next = 0  # index into _bounds
        self._offset = 0.0  # device-time shift of the current pass
        self._start_after = -math.inf
        self._origin: tuple[float, float] | None = None  # (wall, device) at the first batch
        self.exhausted = False

    def resume_after(self, last_frame_t: Mapping[str, float]) -> None:
        """Resume after the last stored frame of this robot (when ``resume``)."""
        if self.resume and self.robot in last_frame_t:
            self.skip_until(last_frame_t[self.robot])

    def skip_until(self, t: float) -> None:
        """Deliver only frames with device time after ``t``."""
        self._start_after = float(t)
        if self.loop and t >= self.recording.t[0]:
            self._offset = math.floor((t - self.recording.t[0]) / self._period) * self._period
        while self._next < len(self._bounds) and self._chunk_end(self._next) + self._offset <= t:
            self._next += 1
        self._roll_over()

    def _chunk_end(self, k: int) -> float:
        """Last device time (before the loop offset) of chunk ``k``, both streams."""
        _, b, _, bq = self._bounds[k]
        return max(float(self.recording.t[b - 1]), float(self.recording.encoder_t[bq - 1]))

    def _roll_over(self) -> None:
        if self._next >= len(self._bounds):
            if self.loop:
                self._next, self._offset = 0, self._offset + self._period
            else:
                self.exhausted = True

    def _due(self, t_dev: float) -> float:
        """Wall time at which the frame of device time ``t_dev`` is due."""
        assert self._origin is not None
        return self._origin[0] + (t_dev - self._origin[1]) / self.speed

    def _read_raw(self, timeout: float) -> list[FrameBatch]:
        out: list[FrameBatch] = []
        while not self.exhausted and len(out) < self.max_batches_per_read:
            a, b, aq, bq = self._bounds[self._next]
            t_end = self._chunk_end(self._next) + self._offset
            if self._origin is None:
                start = min(float(self.recording.t[a]), float(self.recording.encoder_t[aq]))
                self._origin = (self._clock(), start + self._offset)
            if math.isfinite(self.speed):
                wait = self._due(t_end) - self._clock()
                if wait > 0:
                    if out or wait > timeout:
                        if not out:
                            self._sleep(timeout)
                        break
                    self._sleep(wait)
            batch = recording_batch(
                self.robot, self.recording, slice(a, b), self._offset, slice(aq, bq), self._channels
            )
            if min(batch.t[0], batch.encoder_t[0]) <= self._start_after:  # the first chunk after a resume
                batch = _after(batch, self._start_after)
            if batch is not None:
                out.append(batch)
            self._next += 1
            self._roll_over()
        return out


def _after(b: FrameBatch, t: float) -> FrameBatch | None:
    """The samples of ``b`` after device time ``t`` (each stream by its own stamps); None when a
    stream would be left empty."""
    keep = b.t > t
    keep_q = keep if b.t_q is None else b.t_q > t
    if not keep.any() or not keep_q.any():
        return None
    return FrameBatch(
        b.robot,
        b.t[keep],
        b.joint_names,
        b.q[keep_q],
        b.imu_names,
        b.acc[keep],
        b.gyro[keep],
        t_q=None if b.t_q is None else b.t_q[keep_q],
        qd=None if b.qd is None else b.qd[keep_q],
        channel_names=b.channel_names,
        channels=None if b.channels is None else b.channels[keep],
    )
