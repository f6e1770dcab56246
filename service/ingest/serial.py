"""Ingest samples from a serial port (UART, USB CDC, a pty) carrying :mod:`serial_frame` frames.

The port is opened with ``serial.serial_for_url``, so ``loop://`` works in tests, a pty path or
``/dev/ttyUSB0`` on a robot, and ``rfc2217://host:port`` over a network. When the port disappears (cable
pulled, emulator gone) the source closes it and reopens it with exponential backoff; nothing already
accepted is lost and ``read`` never raises for a transport fault.

Time stamps are ``counter × period`` from the device counter in each frame (never arrival time).
Frames whose counter does not advance (duplicates, a late retransmission) are dropped and counted.

Counters (``source.counters.extra``): ``crc_errors``, ``bad_headers``, ``bytes_discarded``,
``sequence_gaps`` (frames lost between accepted ones), ``sequence_resets`` (the sequence number jumped
back: the device restarted), ``stale_frames``, ``counter_resets``, ``disconnects``, ``reconnects``
(every successful open after the first attempt, including a port that was absent at start).

A multi-rate device (``"streams"`` in its description) sends encoder and IMU stream frames, each stream
with its own sequence number and time stamps (``stamp × tick_s``); the source returns multi-rate batches
(``t`` for the IMU samples, ``t_q`` for the encoder samples, :class:`~service.ingest.device.StreamJoiner`).
``sequence_gaps`` and ``sequence_resets`` then count per stream, and further: ``clock_jumps`` (a stamp
that leapt ahead of what the sequence number explains: kept), ``counter_resets`` (a stamp far behind:
the clock restarted, time carries on), ``stale_frames`` (a stamp that did not advance: dropped),
``samples_unpaired`` (samples dropped while the other stream stayed silent).

Example
-------
>>> from service.ingest.device import DeviceConfig
>>> from service.ingest.serial_frame import FrameEncoder
>>> cfg = DeviceConfig("r1", 0.01, ("j1",), ("imu0",))
>>> src = SerialSource("loop://", cfg)
>>> enc = FrameEncoder(1, 1)
>>> src.port.write(b"".join(enc.encode(c, [0.1], [[0, 0, 9.81]], [[0, 0, 0]]) for c in (100, 101)))
64
>>> [b.t.tolist() for b in src.read(0.2)]
[[1.0, 1.01]]
>>> src.close()
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from urllib.parse import parse_qs

import numpy as np
import serial

from service.frames import FrameBatch
from service.ingest.base import Source
from service.ingest.device import (
    STREAMS,
    Backoff,
    DeviceClock,
    DeviceConfig,
    DeviceConfigError,
    StreamClock,
    StreamJoiner,
)
from service.ingest.serial_frame import STREAM_ENCODERS, STREAM_IMUS, FrameDecoder, decode_payloads

__all__ = ["SerialSource", "open_from_spec"]

log = logging.getLogger(__name__)


class SerialSource(Source):
    """A :class:`~service.ingest.base.Source` reading :mod:`serial_frame` frames from ``url``.

    ``backoff`` is (first, max) seconds between reopen attempts; it doubles after each failure and
    resets once a frame is accepted. ``open_port`` is injectable (default ``serial.serial_for_url``).
    """

    def __init__(
        self,
        url: str,
        config: DeviceConfig,
        *,
        baudrate: int = 921600,
        backoff: tuple[float, float] = (0.05, 2.0),
        read_size: int = 65536,
        open_port: Callable[..., serial.SerialBase] | None = None,
        name: str | None = None,
    ) -> None:
        super().__init__(name or f"serial:{url}")
        self.url, self.config, self.baudrate = url, config, baudrate
        self.backoff = backoff
        self.read_size = read_size
        self._open_port = open_port or serial.serial_for_url
        streams = config.streams
        self._decoder = FrameDecoder(len(config.joints), len(config.imus), streams=streams is not None)
        self._clock = DeviceClock(bits=32)
        #: multi-rate: per stream tag, the stamp clock and the last sequence number
        self._stream_clocks: dict[int, StreamClock] = {}
        self._stream_seq: dict[int, int] = {}
        self._joiner: StreamJoiner | None = None
        if streams is not None:
            self._stream_clocks = {
                tag: StreamClock(streams[name])
                for tag, name in zip((STREAM_ENCODERS, STREAM_IMUS), STREAMS, strict=True)
            }
            self._joiner = StreamJoiner(config.robot, config.joints, config.imus)
        self._last_seq: int | None = None
        self._last_idx: int | None = None
        self._retry = Backoff(*backoff)
        self._synced: dict[str, int] = {}
        self._closed = False
        self.port: serial.SerialBase | None = None
        self._connect(first=True)

    # ------------------------------------------------------------------ connection
    def _connect(self, first: bool = False) -> bool:
        try:
            self.port = self._open_port(self.url, baudrate=self.baudrate, timeout=0.1)
        except (serial.SerialException, OSError, ValueError) as err:
            if first and not isinstance(err, serial.SerialException | OSError):
                raise
            log.warning("%s: cannot open port (%s); retrying in %.2f s", self.name, err, self._retry.failed())
            self.port = None
            return False
        if not first:
            self.counters.add("reconnects")
            log.info("%s: port reopened", self.name)
        return True

    def _lost(self, err: Exception) -> None:
        if self._closed:  # closed under a read in progress: not a fault
            self.port = None
            return
        log.warning("%s: port lost (%s); reconnecting", self.name, err)
        self.counters.add("disconnects")
        try:
            if self.port is not None:
                self.port.close()
        except (serial.SerialException, OSError):
            pass
        self.port = None
        self._decoder.reset()
        self._retry.failed()

    @property
    def connected(self) -> bool:
        return self.port is not None

    # ------------------------------------------------------------------ reading
    def _read_raw(self, timeout: float) -> Iterable[FrameBatch]:
        deadline = time.monotonic() + timeout
        if self._closed:
            return []
        if self.port is None:
            if not self._retry.wait(timeout) or not self._connect():
                return []
        port = self.port
        try:
            port.timeout = max(deadline - time.monotonic(), 0.0)
            data = port.read(1)
            if data:
                port.timeout = 0
                waiting = port.in_waiting
                if waiting:
                    data += port.read(min(waiting, self.read_size))
        except (serial.SerialException, OSError) as err:
            self._lost(err)
            self._sync_counters()
            return []
        return self.decode(data)

    def decode(self, data: bytes) -> list[FrameBatch]:
        """Decode ``data`` as if it had come from the port (used by ``read`` and by benchmarks)."""
        frames = self._decoder.feed(data)
        if self._joiner is not None:
            return self._decode_streams(frames)
        payloads, idxs = [], []
        for f in frames:
            if self._last_seq is not None:
                gap = (f.seq - self._last_seq - 1) & 0xFFFF
                if gap < 0x8000:
                    if gap:
                        self.counters.add("sequence_gaps", gap)
                else:
                    self.counters.add("sequence_resets")
            self._last_seq = f.seq
            idx = self._clock.index(f.counter)
            if self._last_idx is not None and idx <= self._last_idx:
                self.counters.add("stale_frames")
                continue
            self._last_idx = idx
            payloads.append(f.payload)
            idxs.append(idx)
        self._sync_counters()
        if not payloads:
            return []
        self._retry.succeeded()
        cfg = self.config
        q, acc, gyro = decode_payloads(payloads, len(cfg.joints), len(cfg.imus))
        t = np.asarray(idxs, dtype=np.float64) * cfg.period_s
        return [FrameBatch(cfg.robot, t, cfg.joints, q, cfg.imus, acc, gyro)]

    def _decode_streams(self, frames: list) -> list[FrameBatch]:
        """Stream frames of a multi-rate device -> multi-rate batches (each stream on its own stamps)."""
        assert self._joiner is not None
        cfg = self.config
        by_stream: dict[int, tuple[list[int], list[int], list[bytes]]] = {
            STREAM_ENCODERS: ([], [], []),
            STREAM_IMUS: ([], [], []),
        }
        for f in frames:
            step = 1
            last = self._stream_seq.get(f.stream)
            if last is not None:
                gap = (f.seq - last - 1) & 0xFFFF
                if gap < 0x8000:
                    if gap:
                        self.counters.add("sequence_gaps", gap)
                    step = gap + 1
                else:
                    self.counters.add("sequence_resets")
            self._stream_seq[f.stream] = f.seq
            stamps, steps, payloads = by_stream[f.stream]
            stamps.append(f.counter)
            steps.append(step)
            payloads.append(f.payload)
        got = False
        for tag, (stamps, steps, payloads) in by_stream.items():
            if not stamps:
                continue
            t, keep = self._stream_clocks[tag].times(stamps, steps)
            if not len(t):
                continue
            got = True
            kept = [p for p, k in zip(payloads, keep, strict=True) if k]
            if tag == STREAM_ENCODERS:
                q, _, _ = decode_payloads(kept, len(cfg.joints), 0)
                self._joiner.add_encoders(t, q)
            else:
                _, acc, gyro = decode_payloads(kept, 0, len(cfg.imus))
                self._joiner.add_imus(t, cfg.imus, acc, gyro)
        if got:
            self._retry.succeeded()
        out = self._joiner.take()
        self._sync_counters()
        return out

    def _sync_counters(self) -> None:
        """Mirror the decoder's and clock's totals into ``counters.extra`` (as increments)."""
        now = {
            "crc_errors": self._decoder.crc_errors,
            "bad_headers": self._decoder.bad_headers,
            "bytes_discarded": self._decoder.bytes_discarded,
            "counter_resets": self._clock.resets,
        }
        if self._joiner is not None:
            clocks = self._stream_clocks.values()
            now["counter_resets"] = sum(c.resets for c in clocks)
            now["stale_frames"] = sum(c.stale for c in clocks)
            now["clock_jumps"] = sum(c.jumps for c in clocks)
            now["samples_unpaired"] = self._joiner.unpaired
        for k, v in now.items():
            d = v - self._synced.get(k, 0)
            if d:
                self.counters.add(k, d)
            self._synced[k] = v

    def close(self) -> None:
        self._closed = True
        if self.port is not None:
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass
            self.port = None


def open_from_spec(rest: str) -> Source:
    """``serial:URL?config=PATH[&baud=N]`` -> a :class:`SerialSource` (the part after ``serial:``).

    ``config`` names a JSON device description (:class:`~service.ingest.device.DeviceConfig`); instead,
    ``robot=NAME&period=0.01&joints=a,b&imus=x,y`` may be given inline.

    >>> open_from_spec("loop://?robot=r1&period=0.01&joints=j1,j2&imus=").config.joints
    ('j1', 'j2')
    """
    url, _, query = rest.partition("?")
    if not url:
        raise ValueError("serial source needs a port, e.g. serial:/dev/ttyUSB0?config=robot.json")
    params = {k: v[-1] for k, v in parse_qs(query, keep_blank_values=True).items()}
    config = config_from_params(params)
    baud = int(params.get("baud", 921600))
    return SerialSource(url, config, baudrate=baud)


def config_from_params(params: dict[str, str]) -> DeviceConfig:
    """A device config from ``config=PATH`` or inline ``robot``/``period``/``joints``/``imus``."""
    if "config" in params:
        return DeviceConfig.load(params["config"])
    if "robot" not in params:
        raise DeviceConfigError(
            "give config=PATH (a JSON device description) or robot=NAME&joints=..&imus=.."
        )

    def names(key: str) -> tuple[str, ...]:
        return tuple(n for n in params.get(key, "").split(",") if n)

    return DeviceConfig(params["robot"], float(params.get("period", 0.01)), names("joints"), names("imus"))
