"""Device emulators: a recording played out as a robot would send it, on the far end of a pty.

- :class:`SerialEmulator` writes :mod:`service.ingest.serial_frame` frames, one per sample.
- :class:`SlcanEmulator` behaves like an slcan (Lawicel) USB-CAN adapter on a bus where the robot sends
  the project CAN layout (:mod:`service.ingest.can_layout`): it answers the host's commands (``O``,
  ``C``, ``S6``, ``V``, ``N`` ...) and forwards frames as ``tIIILDD..\\r`` lines only while the channel is
  open, as a real adapter does.

Both take the sample counter from the recording's time stamps (``round(t / period)``), so the host's
times equal the recording's. ``speed`` 1.0 paces samples in real time; 0 sends as fast as the reader
takes them (the pty applies back-pressure).

A multi-rate recording (``t_q``: encoders on their own stamps, e.g. ``simulate(..., sensing="robot")``)
is played as a multi-rate device sends it (docs/wire-formats.md): encoder samples and IMU samples as two
streams, interleaved in time order, each sample stamped with its recording time in microseconds and
numbered by its stream's counter. A device clock never reads negative, so a recording that starts
before 0 (stamp jitter around the start) is stamped ``time_offset_s`` (whole seconds) later. The
counter advances by the number of nominal periods between stamps, so a sample the recording lost
(sensing ``drop``) shows up on the wire as a lost frame, as it would on a real line. ``streams=True``
sends a single-clock recording the same way (both streams on ``t``).

Example
-------
>>> import numpy as np, serial
>>> from bodyschema.recording import Recording
>>> from service.ingest.serial import SerialSource
>>> rec = Recording(t=np.arange(50) * 0.01, joint_names=["j1"], q=np.zeros((50, 1)),
...                 imu_names=["imu0"], acc=np.zeros((50, 1, 3)), gyro=np.zeros((50, 1, 3)))
>>> em = SerialEmulator(rec)
>>> src = SerialSource(em.port.name, em.device_config())
>>> em.start()
>>> n = 0
>>> while n < 50:
...     n += sum(b.n_samples for b in src.read(1.0))
>>> n, em.wait_done(5.0)
(50, True)
>>> src.close(); em.stop()
"""

from __future__ import annotations

import bisect
import itertools
import logging
import math
import select
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from can.util import len2dlc

from bodyschema.recording import Recording
from emulators.pty_port import PtyPort
from service.ingest.can_layout import encode_samples, encode_samples_fd, encode_stream
from service.ingest.device import DeviceConfig, StreamSpec
from service.ingest.serial_frame import FrameEncoder, StreamFrameEncoder

__all__ = ["STAMP_TICK_S", "SerialEmulator", "SlcanEmulator", "sample_counters", "stream_counters"]

#: Tick of the stamps the emulators send for a multi-rate recording: 1 µs.
STAMP_TICK_S = 1e-6

log = logging.getLogger(__name__)


def sample_counters(rec: Recording) -> tuple[np.ndarray, float]:
    """Device counters (T,) and the period, from the recording's time stamps."""
    period = 1.0 / rec.sample_rate if rec.n_samples > 1 else 0.01
    return np.rint(rec.t / period).astype(np.int64), period


def stream_counters(t: np.ndarray, period: float) -> np.ndarray:
    """A stream's device counter for stamps ``t``: the nominal periods elapsed since the first sample,
    strictly increasing (a stamp's jitter never repeats a counter; a lost sample leaves a gap).

    >>> stream_counters(np.array([0.0, 0.0041, 0.0079, 0.016]), 0.004).tolist()
    [0, 1, 2, 4]
    """
    c = np.rint((np.asarray(t, dtype=np.float64) - t[0]) / period).astype(np.int64)
    return _strictly_increasing(c)


def _strictly_increasing(c: np.ndarray) -> np.ndarray:
    """``c`` raised where needed so that every value exceeds the one before it."""
    k = np.arange(len(c))
    return np.maximum.accumulate(c - k) + k


def _stream_events(rec: Recording) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Play order of a multi-rate recording's samples: (stream 0 = encoders / 1 = IMUs, index in its
    stream, time) per event, sorted by time (encoders first on a tie)."""
    te, ti = rec.encoder_t, rec.t
    kind = np.concatenate([np.zeros(len(te), dtype=np.int64), np.ones(len(ti), dtype=np.int64)])
    index = np.concatenate([np.arange(len(te)), np.arange(len(ti))])
    t = np.concatenate([te, ti])
    order = np.lexsort((kind, t))
    return kind[order], index[order], t[order]


class _PtyEmulator:
    """Streams pre-encoded per-sample chunks into a :class:`PtyPort` from a thread."""

    #: Seconds a reader must have had the port open before data flows (pyserial flushes input on open).
    SETTLE_S = 0.1

    def __init__(
        self,
        rec: Recording,
        *,
        robot: str = "robot",
        speed: float = 0.0,
        link: str | None = None,
        port: PtyPort | None = None,
        streams: bool | None = None,
    ) -> None:
        self.rec = rec
        self.robot = robot
        self._replies = b""
        self.counters, self.period = sample_counters(rec)
        #: multi-rate: encoder and IMU samples as two streams (default: when the recording is multi-rate)
        self.streams = rec.is_multirate if streams is None else bool(streams)
        #: play time of each chunk relative to the first (multi-rate; None: one chunk per period)
        self._chunk_rel: np.ndarray | None = None
        self.time_offset_s = 0.0
        if self.streams:
            if rec.n_joints == 0 or rec.n_imus == 0:
                raise ValueError("a multi-rate device needs encoders and IMUs")
            first = min(float(rec.t[0]), float(rec.encoder_t[0]))
            #: added to the recording's times to make the stamps (a device clock never reads negative)
            self.time_offset_s = float(math.ceil(-first)) if first < 0 else 0.0
            self.encoder_period = 1.0 / rec.encoder_rate if len(rec.encoder_t) > 1 else self.period
            self.encoder_counters = stream_counters(rec.encoder_t, self.encoder_period)
            self.imu_counters = stream_counters(rec.t, self.period)
            self.events = _stream_events(rec)
            self._chunk_rel = self.events[2] - self.events[2][0]
        self.speed = speed
        self.port = port or PtyPort(link)
        self.chunks = self._encode()
        self.sent = 0  # samples fully written
        self._stop = threading.Event()
        self._done = threading.Event()
        self._thread: threading.Thread | None = None
        self.streaming = self._streams_at_once()

    # subclasses
    def _encode(self) -> list[bytes]:
        raise NotImplementedError

    def _streams_at_once(self) -> bool:
        return True

    def _on_input(self, data: bytes) -> None:
        """Bytes the host wrote (commands); the serial device ignores them."""

    def device_config(self) -> DeviceConfig:
        """What the host must be told: robot name, names in wire order, period (multi-rate: the streams'
        periods and stamp tick)."""
        cfg = DeviceConfig(self.robot, self.period, self.rec.joint_names, self.rec.imu_names)
        if self.streams:
            return cfg.with_streams(
                StreamSpec(self.encoder_period, STAMP_TICK_S), StreamSpec(self.period, STAMP_TICK_S)
            )
        return cfg

    def _stamps(self, t: np.ndarray) -> np.ndarray:
        """Stream stamps of recording times ``t``, in ticks."""
        return np.rint((np.asarray(t) + self.time_offset_s) / STAMP_TICK_S).astype(np.int64)

    # lifecycle
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=type(self).__name__, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self.port.close()

    def wait_done(self, timeout: float | None = None) -> bool:
        """True once every sample has been written into the pty."""
        return self._done.wait(timeout)

    def unplug(self) -> None:
        """Pull the cable: the pty goes away (a partly written sample is lost)."""
        self.port.unplug()

    def plug(self) -> None:
        self.streaming = self._streams_at_once()
        self.port.plug()

    def _run(self) -> None:
        cur = _Cursor(len(self.chunks))
        t0: float | None = None
        while not self._stop.is_set():
            fd = self.port.fileno()
            if fd < 0:
                self._drop_unplugged(cur)
                time.sleep(0.01)
                continue
            now = time.monotonic()
            if not self._reader_settled(cur, now):
                time.sleep(0.005)
                continue
            if t0 is None:
                t0 = now
            if not cur.out:
                self._refill(cur, t0)
            self._exchange(cur, fd)

    def _drop_unplugged(self, cur: _Cursor) -> None:
        """The cable was pulled: a partly written sample is lost on the wire, as are the whole ones still
        in the pty buffer; sending resumes after the last sample that went out whole."""
        if cur.out:
            done = bisect.bisect_right(cur.ends, cur.written)
            partial = done < len(cur.ends) and cur.written > (cur.ends[done - 1] if done else 0)
            cur.i = cur.group_start + done + int(partial)
            self.sent = min(cur.i, cur.n)
            cur.out, cur.ends = memoryview(b""), []
        cur.reader_since = None

    def _reader_settled(self, cur: _Cursor, now: float) -> bool:
        """Whether a reader has had the port open for :attr:`SETTLE_S` (nobody listening: a USB device
        would not be sending either). The presence poll runs at most every 20 ms: a poll per write
        would cost more than the write at full speed."""
        if now >= cur.next_check:
            cur.present = self.port.reader_present()
            cur.next_check = now + 0.02
        if not cur.present:
            cur.reader_since = None
            cur.next_check = 0.0
            return False
        if cur.reader_since is None:
            cur.reader_since = now
        return now - cur.reader_since >= self.SETTLE_S

    def _refill(self, cur: _Cursor, t0: float) -> None:
        """Nothing in flight: put the pending command replies in flight, else the next group of samples
        (when the device is sending and some are due)."""
        if self._replies:
            cur.out, self._replies = memoryview(self._replies), b""
            cur.ends, cur.group_start, cur.written = [], cur.i, 0
        elif cur.i < cur.n and self.streaming:
            j = self._group_end(cur, t0)
            if j > cur.i:
                cur.ends = list(itertools.accumulate(len(c) for c in self.chunks[cur.i : j]))
                cur.out = memoryview(b"".join(self.chunks[cur.i : j]))
                cur.group_start, cur.written = cur.i, 0

    def _group_end(self, cur: _Cursor, t0: float) -> int:
        """End (exclusive) of the next group: the samples due by now when paced, else up to 64 KiB."""
        if self.speed > 0:
            elapsed = (time.monotonic() - t0) * self.speed
            if self._chunk_rel is None:
                due = int(elapsed / self.period) + 1
            else:
                due = int(np.searchsorted(self._chunk_rel, elapsed, side="right"))
            return min(max(due, cur.i), cur.n)
        j = cur.i
        size = 0
        while j < cur.n and size < 65536:
            size += len(self.chunks[j])
            j += 1
        return j

    def _exchange(self, cur: _Cursor, fd: int) -> None:
        """One wait on the pty: hand the host's input to :meth:`_on_input`, write what it takes of the
        group in flight, and mark the end once every sample is out."""
        wait = 0.002 if (self.speed > 0 and not cur.out and cur.i < cur.n) else 0.05
        try:
            r, w, _ = select.select([fd], [fd] if cur.out else [], [], wait)
        except (OSError, ValueError):
            return
        if r:
            data = self.port.read_available()
            if data:
                self._on_input(data)
        if w and cur.out:
            self._write_some(cur)
        if cur.i >= cur.n and not cur.out:
            self._done.set()

    def _write_some(self, cur: _Cursor) -> None:
        k = self.port.write_some(cur.out)
        cur.out = cur.out[k:]
        cur.written += k
        if cur.ends:
            self.sent = cur.group_start + bisect.bisect_right(cur.ends, cur.written)
        if not cur.out:
            cur.i = cur.group_start + len(cur.ends)
            cur.ends = []


@dataclass
class _Cursor:
    """Where the writer thread stands: the group of bytes in flight, the next chunk, the reader's state."""

    n: int  # chunks in all
    i: int = 0  # next chunk to put in flight
    out: memoryview = field(default_factory=lambda: memoryview(b""))  # bytes in flight, not yet written
    ends: list[int] = field(default_factory=list)  # byte offset where each sample of the group in flight ends
    group_start: int = 0  # chunk index of the group in flight
    written: int = 0  # bytes of the group in flight written
    reader_since: float | None = None  # when a reader was first seen (this time round)
    next_check: float = 0.0  # when to poll for a reader next
    present: bool = False  # a reader had the port open at the last poll


class SerialEmulator(_PtyEmulator):
    """A robot streaming :mod:`serial_frame` frames on a pty (multi-rate: stream frames)."""

    def _encode(self) -> list[bytes]:
        rec = self.rec
        if self.streams:
            return self._encode_streams()
        enc = FrameEncoder(rec.n_joints, rec.n_imus)
        q = rec.q if rec.q is not None else np.zeros((rec.n_samples, 0))
        chunks = [enc.encode(int(c), q[i], rec.acc[i], rec.gyro[i]) for i, c in enumerate(self.counters)]
        self.clipped = enc.clipped
        return chunks

    def _encode_streams(self) -> list[bytes]:
        rec = self.rec
        assert rec.q is not None
        enc = StreamFrameEncoder(rec.n_joints, rec.n_imus)
        stamp_q, stamp_i = self._stamps(rec.encoder_t), self._stamps(rec.t)
        chunks = []
        for kind, i in zip(self.events[0].tolist(), self.events[1].tolist(), strict=True):
            if kind == 0:
                chunks.append(enc.encode_encoders(stamp_q[i], rec.q[i], seq=self.encoder_counters[i]))
            else:
                chunks.append(enc.encode_imus(stamp_i[i], rec.acc[i], rec.gyro[i], seq=self.imu_counters[i]))
        self.clipped = enc.clipped
        return chunks


class SlcanEmulator(_PtyEmulator):
    """An slcan adapter on a bus carrying the project CAN layout (``fd=True``: its CAN FD variant, sent
    as ``dIIIL..`` lines with the FD length code, as CANable 2.0 firmware does)."""

    VERSION = b"V1013\r"
    SERIAL = b"NBH01\r"

    def __init__(self, rec: Recording, *, fd: bool = False, **kw: object) -> None:
        self.fd = fd
        super().__init__(rec, **kw)  # type: ignore[arg-type]

    def _streams_at_once(self) -> bool:
        return False

    def device_config(self) -> DeviceConfig:
        cfg = super().device_config()
        if self.fd:
            return DeviceConfig(
                cfg.robot, cfg.period_s, cfg.joints, cfg.imus, {**cfg.extra, "can": {"layout": "fd"}}
            )
        return cfg

    def _encode(self) -> list[bytes]:
        rec = self.rec
        q = rec.q if rec.q is not None else np.zeros((rec.n_samples, 0))
        self._cmd = b""
        if self.streams:
            layout = "fd" if self.fd else "classic"
            enc = self._lines(
                *encode_stream(
                    "encoders", self.encoder_counters, self._stamps(rec.encoder_t), q=q, layout=layout
                )
            )
            imu = self._lines(
                *encode_stream(
                    "imus", self.imu_counters, self._stamps(rec.t), acc=rec.acc, gyro=rec.gyro, layout=layout
                )
            )
            return [
                (enc, imu)[k][i]
                for k, i in zip(self.events[0].tolist(), self.events[1].tolist(), strict=True)
            ]
        if self.fd:
            ids, lengths, data = encode_samples_fd(self.counters, q, rec.acc, rec.gyro)
        else:
            ids, data = encode_samples(self.counters, q, rec.acc, rec.gyro)
            lengths = np.full(len(ids), 8)
        return self._lines(ids, lengths, data)

    def _lines(self, ids: np.ndarray, lengths: np.ndarray, data: np.ndarray) -> list[bytes]:
        """slcan lines of each sample: a ``t`` line per 8-byte frame, a ``d`` line per longer one
        (CAN FD; a classic frame on an FD bus is still a ``t`` line)."""
        prefixes = [
            f"{'d' if n > 8 else 't'}{int(i):03X}{len2dlc(int(n)):X}".encode()
            for i, n in zip(ids, lengths, strict=True)
        ]
        width = data.shape[2]
        hexed = data.reshape(-1).tobytes().hex().upper().encode()
        spans = [(f * width * 2, f * width * 2 + int(n) * 2) for f, n in enumerate(lengths)]
        F = len(ids)
        chunks = []
        for s in range(data.shape[0]):
            base = s * F * width * 2
            chunks.append(
                b"".join(prefixes[f] + hexed[base + a : base + b] + b"\r" for f, (a, b) in enumerate(spans))
            )
        return chunks

    def _on_input(self, data: bytes) -> None:
        self._cmd += data
        *lines, self._cmd = self._cmd.split(b"\r")
        replies = []
        for line in lines:
            c = line[:1]
            if c in (b"O", b"L"):
                self.streaming = True
                replies.append(b"\r")
            elif c == b"C":
                self.streaming = False
                replies.append(b"\r")
            elif c == b"V":
                replies.append(self.VERSION)
            elif c == b"N":
                replies.append(self.SERIAL)
            elif c in (b"S", b"s", b"t", b"T", b"r", b"R", b"F", b"Z", b"M", b"m", b"Y"):
                replies.append(b"\r")
            elif line:
                replies.append(b"\a")
        self._replies += b"".join(replies)
