"""Ingest samples from a CAN bus through python-can and a DBC (cantools).

The bus is configuration: ``virtual`` (tests), ``slcan`` (a serial-line CAN adapter, or the slcan
emulator on a pty), ``socketcan`` (Linux), or any python-can interface. A ``can.Notifier`` owns the
receive thread and feeds :class:`_RegroupListener`, which in the style of cantools' tester listener
skips error and remote frames, counts unknown ids, decodes through the DBC and never lets one bad frame
stop the thread. Frames regroup into samples by the device counter (:mod:`can_regroup`).

Bus faults: an exception out of ``bus.recv`` (adapter unplugged, pty closed, socket down) or an error
frame reporting bus-off (``CAN_ERR_BUSOFF`` in the error class, linux/can/error.h) shuts the bus down and
reopens it from the factory with exponential backoff. Samples already released are kept; pending ones
are flushed with the usual incomplete-sample policy.

Counters (``source.counters.extra``): ``frames``, ``error_frames``, ``remote_frames``, ``unknown_ids``,
``decode_errors``, ``late_frames``, ``duplicate_frames``, ``frames_missing``, ``samples_incomplete``,
``samples_dropped``, ``bus_errors``, ``bus_off``, ``reconnects``, ``counter_resets``.

A multi-rate device (``"streams"`` in its config) sends its encoder and IMU samples as two streams with
their own counters and stamp frames; the source regroups each on its own and returns multi-rate
batches (:class:`~service.ingest.can_regroup.MultirateAssembler`, which adds ``samples_missing``,
``clock_jumps``, ``stale_stamps`` and ``samples_unpaired``).

Example
-------
>>> import can, numpy as np
>>> from service.ingest.can_layout import encode_samples
>>> from service.ingest.device import DeviceConfig
>>> cfg = DeviceConfig("r1", 0.01, ("j1",), ("imu0",))
>>> src = CanSource(cfg, lambda: can.Bus(interface="virtual", channel="doc"))
>>> tx = can.Bus(interface="virtual", channel="doc")
>>> ids, data = encode_samples(np.arange(3), np.zeros((3, 1)), np.zeros((3, 1, 3)), np.zeros((3, 1, 3)))
>>> for t in range(3):
...     for f in range(3):
...         tx.send(can.Message(arbitration_id=int(ids[f]), data=data[t, f].tobytes(), is_extended_id=False))
>>> tx.send(can.Message(arbitration_id=0x7FF, data=b"\\x00", is_extended_id=False))
>>> sum(b.n_samples for b in src.read(1.0)), src.counters.extra["unknown_ids"]
(3, 1)
>>> src.close(); tx.shutdown()
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any
from urllib.parse import parse_qs

import can
import serial
from can.exceptions import error_check
from can.interfaces.slcan import slcanBus
from can.util import CAN_FD_DLC

from service.frames import FrameBatch
from service.ingest.base import Source
from service.ingest.can_mapping import SignalMap, load_dbc
from service.ingest.can_regroup import MultirateAssembler, SampleAssembler
from service.ingest.device import Backoff, DeviceConfig
from service.ingest.serial import config_from_params

__all__ = ["CAN_ERR_BUSOFF", "BufferedSlcanBus", "CanSource", "open_bus", "open_from_spec"]

log = logging.getLogger(__name__)

#: Error-class bit for bus-off in an error frame's id (linux/can/error.h).
CAN_ERR_BUSOFF = 0x00000040

_LINE = re.compile(r"[^\r\a]*[\r\a]")


class BufferedSlcanBus(slcanBus):
    """python-can's slcan bus, reading whatever the port holds at once.

    The stock ``slcanBus._read`` calls ``serial.read(1)`` per byte (a ``select`` and a system call each,
    about 25 per frame), which caps it near ten thousand frames a second; this override reads the waiting
    bytes in one call and splits them on the slcan terminators (CR, BEL). Standard data frames (``t``,
    and CAN FD ``d``) are parsed in one step, and while lines are buffered and no filters are set,
    :meth:`recv` hands them out without the generic receive loop; everything else - commands, replies,
    extended and remote frames, ``send`` - is python-can's.
    """

    def __init__(self, channel: str, **kwargs: Any) -> None:
        self._lines: deque[str] = deque()
        self._rest = ""
        self.garbled_lines = 0
        super().__init__(channel, **kwargs)

    def _read(self, timeout: float | None) -> str | None:
        if self._lines:
            return self._lines.popleft()
        deadline = serial.Timeout(timeout)
        port = self.serialPortOrig
        with error_check("Could not read from serial device"):
            while True:
                waiting = port.in_waiting
                data = port.read(waiting if waiting else 1)
                if data:
                    buf = self._rest + data.decode("ascii", "replace")
                    lines = _LINE.findall(buf)
                    if lines:
                        self._rest = buf[max(buf.rfind("\r"), buf.rfind("\a")) + 1 :]
                        self._lines.extend(lines)
                        return self._lines.popleft()
                    self._rest = buf
                if deadline.expired():
                    return None

    @staticmethod
    def _parse(line: str) -> can.Message | None:
        """A standard data frame line as a Message, or None for anything else."""
        kind = line[0]
        if kind in "td" and len(line) >= 6:
            try:
                fd = kind == "d"
                n = CAN_FD_DLC[int(line[4], 16)] if fd else int(line[4])
                data = bytearray.fromhex(line[5 : 5 + 2 * n])
                if len(data) == n:
                    return can.Message(
                        arbitration_id=int(line[1:4], 16),
                        is_extended_id=False,
                        dlc=n,
                        data=data,
                        is_fd=fd,
                        timestamp=time.time(),
                        check=False,
                    )
            except (ValueError, IndexError):
                pass
        return None

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self._lines and self._filters is None and not self._queue.qsize():
            line = self._lines.popleft()
            msg = self._parse(line)
            if msg is not None:
                return msg
            self._queue.put_nowait(line)
        return super().recv(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if not self._queue.qsize():
            line = self._read(timeout)
            if line is None:
                return None, False
            msg = self._parse(line)
            if msg is not None:
                return msg, False
            self._queue.put_nowait(line)
        try:
            return super()._recv_internal(0)
        except (ValueError, IndexError) as err:  # a garbled line (line noise): skip it, keep the bus
            self.garbled_lines += 1
            log.debug("slcan: skipped a garbled line: %s", err)
            return None, False

    def flush(self) -> None:
        self._lines.clear()
        self._rest = ""
        super().flush()


def open_bus(interface: str, channel: str, **kwargs: Any) -> can.BusABC:
    """A python-can bus; ``slcan`` gets :class:`BufferedSlcanBus` (no 2 s sleep after open unless asked)."""
    if interface == "slcan":
        kwargs.setdefault("sleep_after_open", 0.0)
        return BufferedSlcanBus(channel, **kwargs)
    return can.Bus(interface=interface, channel=channel, **kwargs)


class _RegroupListener(can.Listener):
    """Runs in the notifier thread: error/remote frames counted and skipped, data frames queued for the
    reader, which decodes and regroups them in batches."""

    def __init__(self, source: CanSource) -> None:
        self.source = source

    def on_message_received(self, msg: can.Message) -> None:
        src = self.source
        try:
            if msg.is_error_frame:
                src.counters.add("error_frames")
                if msg.arbitration_id & CAN_ERR_BUSOFF:
                    src.counters.add("bus_off")
                    src._fail("bus-off reported by an error frame")
                return
            if msg.is_remote_frame:
                src.counters.add("remote_frames")
                return
            frames = src._frames
            frames.append((msg.arbitration_id, msg.data))  # deque.append is atomic: no lock per frame
            if len(frames) == src.wake_frames:
                with src._cond:
                    src._cond.notify()
        except Exception:  # one bad frame must never stop the receive thread
            src.counters.add("listener_errors")
            log.exception("CAN listener: frame 0x%x dropped", getattr(msg, "arbitration_id", -1))

    __call__ = on_message_received  # the notifier calls listeners: skip one indirection per frame

    def on_error(self, exc: Exception) -> None:
        self.source._fail(f"bus error: {exc}")
        time.sleep(0.01)  # the notifier retries recv at once; do not spin while the reader restarts


class CanSource(Source):
    """A :class:`~service.ingest.base.Source` decoding CAN frames from ``bus_factory()``.

    ``bus_factory`` opens the bus (called again on every reconnect); ``horizon`` is how many samples a
    frame may lag the newest before its sample is released without it; ``incomplete`` is the policy for
    such samples (``"drop"`` or ``"partial"``, see :mod:`can_regroup`); ``idle_flush_s`` releases pending
    samples when the bus has been silent that long (measured on the host clock, used for nothing else;
    long enough that a sender stalled by a busy host does not get its next frames counted as late);
    ``backoff`` is (first, max) seconds between reopen attempts. A multi-rate ``config`` takes a pair of
    maps (encoder stream, IMU stream; default :meth:`SignalMap.for_streams`) as ``signal_map``.
    """

    def __init__(
        self,
        config: DeviceConfig,
        bus_factory: Callable[[], can.BusABC],
        *,
        signal_map: SignalMap | tuple[SignalMap, SignalMap] | None = None,
        horizon: int = 4,
        incomplete: str = "drop",
        idle_flush_s: float = 2.0,
        backoff: tuple[float, float] = (0.05, 2.0),
        name: str | None = None,
    ) -> None:
        super().__init__(name or f"can:{config.robot}")
        self.config = config
        self._asm: SampleAssembler | MultirateAssembler
        if config.streams is not None:
            maps = signal_map if isinstance(signal_map, tuple) else SignalMap.for_streams(config)
            self.signal_maps: tuple[SignalMap, ...] = maps
            self._asm = MultirateAssembler(*maps, horizon=horizon, incomplete=incomplete)
        else:
            if isinstance(signal_map, tuple):
                raise ValueError("a pair of signal maps needs a multi-rate device config ('streams')")
            self.signal_maps = (signal_map or SignalMap.for_config(config),)
            self._asm = SampleAssembler(self.signal_maps[0], horizon=horizon, incomplete=incomplete)
        #: the single-stream map (a multi-rate device's: its encoder stream's)
        self.signal_map = self.signal_maps[0]
        self._cond = threading.Condition()
        self._frames: deque[tuple[int, bytearray]] = deque()
        #: queued frames that wake the reader before ``batch_s`` is up; batches amortise the numpy decode
        self.wake_frames = max(16 * sum(m.n_frames for m in self.signal_maps), 1024)
        #: longest a frame waits in the queue before the reader decodes it (latency bound)
        self.batch_s = 0.02
        self._factory = bus_factory
        self.idle_flush_s = idle_flush_s
        self.backoff = backoff
        self._retry = Backoff(*backoff)
        self._listener = _RegroupListener(self)
        self.bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._failed: str | None = None
        self._last_frame = time.monotonic()
        self._synced: dict[str, int] = {}
        self._closed = False
        self._start(first=True)

    # ------------------------------------------------------------------ bus lifecycle
    def _start(self, first: bool = False) -> bool:
        try:
            bus = self._factory()
        except (can.CanError, OSError, serial.SerialException) as err:
            log.warning("%s: cannot open bus (%s); retrying in %.2f s", self.name, err, self._retry.failed())
            return False
        self._failed = None
        self.bus = bus
        self._notifier = can.Notifier(bus, [self._listener], timeout=0.05)
        if not first:
            self.counters.add("reconnects")
            log.info("%s: bus reopened", self.name)
        self._retry.succeeded()
        return True

    def _fail(self, why: str) -> None:
        if self._failed is None and not self._closed:
            self._failed = why
            self.counters.add("bus_errors")
            log.warning("%s: %s; restarting the bus", self.name, why)
        with self._cond:
            self._cond.notify()

    def _stop_bus(self) -> None:
        notifier, bus = self._notifier, self.bus
        self._notifier, self.bus = None, None
        if notifier is not None:
            notifier.stop(timeout=1.0)
        if bus is not None:
            try:
                bus.shutdown()
            except Exception as err:  # a dead adapter may fail to close; it is gone either way
                log.debug("%s: shutdown after failure: %s", self.name, err)

    @property
    def connected(self) -> bool:
        return self.bus is not None and self._failed is None

    # ------------------------------------------------------------------ reading
    def _read_raw(self, timeout: float) -> Iterable[FrameBatch]:
        deadline = time.monotonic() + timeout
        if self._failed is not None and self.bus is not None:
            self._stop_bus()
            self._retry.failed()
            frames = self._drain()
            if frames:
                ids, datas = zip(*frames, strict=True)
                self._asm.add_many(ids, datas)
            batches = self._asm.take(flush=True)
            self._sync_counters()
            return batches
        if self._closed:
            return []
        if self.bus is None:
            if not self._retry.wait(timeout) or not self._start():
                return []
        while True:
            with self._cond:
                if len(self._frames) < self.wake_frames and self._failed is None:
                    left = deadline - time.monotonic()
                    if left > 0:
                        self._cond.wait(min(left, self.batch_s))
            frames = self._drain()
            if frames:
                self._last_frame = time.monotonic()
                ids, datas = zip(*frames, strict=True)
                self._asm.add_many(ids, datas)
            if self._asm.ready or self._failed is not None or time.monotonic() >= deadline:
                break
        idle = self._asm.pending and time.monotonic() - self._last_frame > self.idle_flush_s
        batches = self._asm.take(flush=bool(idle))
        self._sync_counters()
        return batches

    def _drain(self) -> list[tuple[int, bytearray]]:
        q = self._frames
        return [q.popleft() for _ in range(len(q))]

    def _sync_counters(self) -> None:
        now = dict(self._asm.counts)
        now["counter_resets"] = self._asm.resets
        for k, v in now.items():
            d = v - self._synced.get(k, 0)
            if d:
                self.counters.add(k, d)
            self._synced[k] = v

    def close(self) -> None:
        self._closed = True
        self._stop_bus()


def open_from_spec(rest: str) -> Source:
    """``can:INTERFACE:CHANNEL?config=PATH[&bitrate=N][&horizon=N][&incomplete=drop|partial]``.

    (The part after ``can:``.)

    Examples: ``virtual:bench?config=ur5e.json``, ``slcan:/dev/pts/7?config=ur5e.json``,
    ``socketcan:can0?config=robot.json``. Instead of ``config`` the names may be inline
    (``robot=NAME&period=0.01&joints=a,b&imus=x,y``; project DBC and layout), and ``dbc=PATH`` names a DBC
    when the config has none.

    >>> src = open_from_spec("virtual:spec-doc?robot=r1&joints=j1&imus=imu0")
    >>> src.config.robot, src.connected
    ('r1', True)
    >>> src.close()
    """
    spec, _, query = rest.partition("?")
    interface, _, channel = spec.partition(":")
    if not interface or not channel:
        raise ValueError("CAN source needs INTERFACE:CHANNEL, e.g. can:slcan:/dev/ttyACM0?config=robot.json")
    params = {k: v[-1] for k, v in parse_qs(query, keep_blank_values=True).items()}
    config = config_from_params(params)
    if "dbc" in params:
        config = DeviceConfig(
            config.robot,
            config.period_s,
            config.joints,
            config.imus,
            {**config.extra, "can": {**config.extra.get("can", {}), "dbc": params["dbc"]}},
        )
    kwargs: dict[str, Any] = {}
    if "bitrate" in params:
        kwargs["bitrate"] = int(params["bitrate"])
    if "sleep_after_open" in params:
        kwargs["sleep_after_open"] = float(params["sleep_after_open"])
    db = load_dbc(config.extra.get("can", {}).get("dbc"))
    signal_map: SignalMap | tuple[SignalMap, SignalMap] = (
        SignalMap.for_streams(config, db) if config.streams is not None else SignalMap.for_config(config, db)
    )
    can_section = config.extra.get("can", {})
    return CanSource(
        config,
        lambda: open_bus(interface, channel, **kwargs),
        signal_map=signal_map,
        horizon=int(params.get("horizon", can_section.get("horizon", 4))),
        incomplete=params.get("incomplete", can_section.get("incomplete", "drop")),
    )
