"""What a device on a wire is described by, and how its sample counter becomes time.

Both wire transports (CAN and serial) carry a *device sample counter* in every frame rather than a
clock: the device increments it once per sampling instant, so frames of one instant regroup by it and the
sample time is ``counter × period`` — never the arrival time, which jitters with USB, the kernel and the
host's load.

:class:`DeviceConfig` holds what the wire does not carry: the robot's name, the joint and IMU names in
wire order, and the sample period. It is read from a small JSON file (documented in
``docs/wire-formats.md``) or built in code.

:class:`DeviceClock` unwraps a counter of ``bits`` bits into a monotone index and notices device restarts.

A *multi-rate* device (its description has a ``"streams"`` section, :class:`StreamSpec`) sends its
encoder samples and its IMU samples as two streams, each with its own rate and its own time stamps,
because that is how real robots sample them: on different buses and clocks (docs/recording-format.md).
:class:`StreamClock` turns one stream's stamps into seconds and counts what the device's clock did
(jumps, restarts, repeats); :class:`StreamJoiner` pairs the two streams into multi-rate frame batches.

Example
-------
>>> clock = DeviceClock(bits=16)
>>> [clock.index(c) for c in (65534, 65535, 0, 1, 65535)]
[65534, 65535, 65536, 65537, 65535]
>>> clock.index(60000)  # far behind the newest: the device restarted, time carries on
65538
>>> clock.resets
1
>>> clock.index_many(np.array([60001, 60003, 60002])).tolist()
[65539, 65541, 65540]
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from service.frames import FrameBatch

__all__ = [
    "STREAMS",
    "Backoff",
    "DeviceClock",
    "DeviceConfig",
    "DeviceConfigError",
    "StreamClock",
    "StreamJoiner",
    "StreamSpec",
]

#: The two streams of a multi-rate device, in the order of the ``streams`` section.
STREAMS = ("encoders", "imus")


class DeviceConfigError(ValueError):
    """A device description that is incomplete or inconsistent."""


@dataclass(frozen=True)
class StreamSpec:
    """One stream of a multi-rate device: its nominal sample period and the LSB of its time stamps.

    The device stamps every sample of the stream (``stamp × tick_s`` seconds, on the stream's own
    clock); ``period_s`` is only the nominal spacing, used to count lost samples and clock jumps. A device
    that counts samples rather than time sets ``tick_s`` equal to ``period_s``.
    """

    period_s: float
    tick_s: float = 1e-6

    def __post_init__(self) -> None:
        for name in ("period_s", "tick_s"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0 < float(v) < 10):
                raise DeviceConfigError(f"streams: {name} must be a positive number of seconds, got {v!r}")
        if self.tick_s > self.period_s:
            raise DeviceConfigError("streams: tick_s must not exceed period_s (stamps finer than samples)")


@dataclass(frozen=True)
class DeviceConfig:
    """Robot name, names in wire order, sample period, and transport-specific extras.

    ``extra`` keeps transport sections untouched (``"can"``: DBC path and signal mapping). A
    ``"streams"`` section makes it a multi-rate device (:attr:`streams`).

    >>> cfg = DeviceConfig.from_dict({"robot": "r1", "period_s": 0.01, "joints": ["j1"], "imus": ["a"]})
    >>> cfg.joints, cfg.rate_hz
    (('j1',), 100.0)
    """

    robot: str
    period_s: float
    joints: tuple[str, ...]
    imus: tuple[str, ...]
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", tuple(str(j) for j in self.joints))
        object.__setattr__(self, "imus", tuple(str(i) for i in self.imus))
        if not self.robot or not isinstance(self.robot, str):
            raise DeviceConfigError("robot must be a non-empty string")
        if not (isinstance(self.period_s, int | float) and 0 < float(self.period_s) < 10):
            raise DeviceConfigError(f"period_s must be a positive number of seconds, got {self.period_s!r}")
        for kind, names in (("joint", self.joints), ("imu", self.imus)):
            if len(set(names)) != len(names):
                raise DeviceConfigError(f"{kind} names must be unique")
            if any(not n for n in names):
                raise DeviceConfigError(f"{kind} names must be non-empty")
        if not self.joints and not self.imus:
            raise DeviceConfigError("a device needs at least one joint or IMU")
        if "streams" in self.extra:
            self.streams  # noqa: B018 - validates the section now, not at the first frame

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.period_s

    @property
    def streams(self) -> dict[str, StreamSpec] | None:
        """``{"encoders": StreamSpec, "imus": StreamSpec}`` for a multi-rate device, else None.

        >>> DeviceConfig("r", 0.01, ("j",), ("i",), {"streams": {"encoders": {"period_s": 0.004},
        ...     "imus": {"period_s": 0.01}}}).streams["encoders"]
        StreamSpec(period_s=0.004, tick_s=1e-06)
        """
        sec = self.extra.get("streams")
        if sec is None:
            return None
        if not isinstance(sec, dict) or set(sec) != set(STREAMS):
            raise DeviceConfigError(f"streams must be an object with exactly the keys {list(STREAMS)}")
        if not self.joints or not self.imus:
            raise DeviceConfigError("a multi-rate device (streams) needs at least one joint and one IMU")
        out = {}
        for name in STREAMS:
            d = sec[name]
            if not isinstance(d, dict) or "period_s" not in d or set(d) - {"period_s", "tick_s"}:
                raise DeviceConfigError(f"streams.{name} must be {{'period_s': s[, 'tick_s': s]}}, got {d!r}")
            out[name] = StreamSpec(float(d["period_s"]), float(d.get("tick_s", 1e-6)))
        return out

    def with_streams(self, encoders: StreamSpec, imus: StreamSpec) -> DeviceConfig:
        """This device described as multi-rate (``period_s`` becomes the IMU stream's period)."""
        sec = {
            n: {"period_s": s.period_s, "tick_s": s.tick_s}
            for n, s in zip(STREAMS, (encoders, imus), strict=True)
        }
        return DeviceConfig(self.robot, imus.period_s, self.joints, self.imus, {**self.extra, "streams": sec})

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DeviceConfig:
        missing = [k for k in ("robot", "period_s") if k not in d]
        if missing:
            raise DeviceConfigError(f"device config misses {missing}")
        known = {"robot", "period_s", "joints", "imus"}
        return cls(
            robot=d["robot"],
            period_s=float(d["period_s"]),
            joints=tuple(d.get("joints", ())),
            imus=tuple(d.get("imus", ())),
            extra={k: v for k, v in d.items() if k not in known},
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "robot": self.robot,
            "period_s": self.period_s,
            "joints": list(self.joints),
            "imus": list(self.imus),
            **self.extra,
        }

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> DeviceConfig:
        """Read a JSON device description; relative paths inside it resolve against its folder."""
        p = Path(path)
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            raise DeviceConfigError(f"{p}: not a readable JSON device config ({err})") from err
        if not isinstance(d, dict):
            raise DeviceConfigError(f"{p}: a device config is a JSON object")
        can = d.get("can")
        if isinstance(can, dict) and isinstance(can.get("dbc"), str) and not os.path.isabs(can["dbc"]):
            d["can"] = {**can, "dbc": str(p.parent / can["dbc"])}
        return cls.from_dict(d)

    def save(self, path: str | os.PathLike[str]) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1), encoding="utf-8")


class DeviceClock:
    """Unwrap a ``bits``-bit device counter into a monotone sample index.

    A counter value within half the range of the newest one is read as the nearest unwrapped index
    (late frames land behind the newest, gaps ahead of it). A value more than ``reset_after`` samples
    *behind* the newest means the device restarted: the index carries on from the newest + 1 so time
    never goes backwards, and :attr:`resets` counts it.
    """

    def __init__(self, bits: int = 16, reset_after: int = 256) -> None:
        if not 2 <= bits <= 64:
            raise ValueError("bits must be in 2..64")
        self.modulo = 1 << bits
        self.reset_after = min(int(reset_after), self.modulo // 2 - 1)
        self.resets = 0
        self._last_raw: int | None = None
        self._last_idx = 0

    @property
    def newest(self) -> int | None:
        """The highest index seen so far (None before the first counter)."""
        return None if self._last_raw is None else self._last_idx

    def index_many(self, raw: np.ndarray) -> np.ndarray:
        """:meth:`index` of each counter in arrival order, vectorised (same results)."""
        raw = np.asarray(raw, dtype=np.int64) % self.modulo
        if raw.size == 0:
            return raw
        if self._last_raw is None:
            self._last_raw = self._last_idx = int(raw[0])
        prev = np.empty_like(raw)
        prev[0] = self._last_raw
        prev[1:] = raw[:-1]
        d = (raw - prev) % self.modulo
        d[d >= self.modulo // 2] -= self.modulo
        idx = self._last_idx + np.cumsum(d)
        running = np.maximum.accumulate(np.concatenate([[self._last_idx], idx[:-1]]))
        if np.any(idx < running - self.reset_after) or np.any(idx > running + self.modulo // 2 - 1):
            return np.array([self.index(int(r)) for r in raw], dtype=np.int64)  # restarts: go one by one
        top = int(np.argmax(idx))
        if idx[top] > self._last_idx:
            self._last_raw, self._last_idx = int(raw[top]), int(idx[top])
        return idx

    def index(self, raw: int) -> int:
        raw = int(raw) % self.modulo
        if self._last_raw is None:
            self._last_raw, self._last_idx = raw, raw
            return raw
        d = (raw - self._last_raw) % self.modulo
        if d >= self.modulo // 2:
            d -= self.modulo
        if d < -self.reset_after:
            self.resets += 1
            d = 1
        idx = self._last_idx + d
        if d > 0:
            self._last_raw, self._last_idx = raw, idx
        return idx


class Backoff:
    """Exponential reconnect backoff shared by the transports: ``first`` seconds after the first failure,
    doubling up to ``maximum``, back to ``first`` after a success.

    >>> b = Backoff(0.05, 0.2)
    >>> [b.failed() for _ in range(4)]
    [0.05, 0.1, 0.2, 0.2]
    >>> b.succeeded(); b.delay
    0.05
    """

    def __init__(self, first: float, maximum: float) -> None:
        self.first, self.maximum = first, maximum
        self.delay = first
        self.next_attempt = 0.0

    def failed(self) -> float:
        """Schedule the next attempt ``delay`` seconds from now and double the delay; returns the wait."""
        wait = self.delay
        self.next_attempt = time.monotonic() + wait
        self.delay = min(self.delay * 2, self.maximum)
        return wait

    def succeeded(self) -> None:
        self.delay = self.first

    def wait(self, timeout: float) -> bool:
        """Sleep until the next attempt is due, at most ``timeout``; True when an attempt is due now."""
        left = self.next_attempt - time.monotonic()
        if left > 0:
            time.sleep(min(left, timeout))
            if left > timeout:
                return False
        return True


class StreamClock:
    """One stream's device stamps (``bits`` wide, in ``tick_s``) -> seconds, watching the device clock.

    ``steps`` says how many samples the stream's own counter (or frame sequence number) advanced since the
    previous sample (1 when nothing was lost). The stamp is then expected to advance by about
    ``steps × period_s``:

    - a stamp that does not advance (a repeat, a late retransmission) is dropped: ``stale``;
    - one more than 256 periods (at least 1 s) *behind* the newest means the clock restarted or jumped
      back: the sample is kept, time carries on just after the newest stamp (``resets``), and the stamps
      after it keep their spacing;
    - one that leaps ahead of the expectation by more than ``jump_periods`` periods (at least 0.1 s) is
      kept as stamped and counted in ``jumps``: the host cannot tell a clock step from a pause, but the
      counter says which it was when nothing was lost in between.

    >>> c = StreamClock(StreamSpec(0.01, 1e-3))
    >>> c.times([1000, 1010, 1010, 1020, 5000], [1, 1, 1, 1, 1])
    (array([1.  , 1.01, 1.02, 5.  ]), array([ True,  True, False,  True,  True]))
    >>> c.stale, c.jumps, c.resets
    (1, 1, 0)
    """

    def __init__(self, spec: StreamSpec, bits: int = 32, jump_periods: float = 10.0) -> None:
        self.spec = spec
        reset = math.ceil(max(256 * spec.period_s, 1.0) / spec.tick_s)
        self.clock = DeviceClock(bits=bits, reset_after=reset)
        self.jump_ticks = max(jump_periods * spec.period_s, 0.1) / spec.tick_s
        self.stale = 0
        self.jumps = 0
        self._last: int | None = None

    @property
    def resets(self) -> int:
        return self.clock.resets

    def times(
        self, stamps: list[int] | np.ndarray, steps: list[int] | np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Seconds of the kept samples, and which of ``stamps`` were kept (in arrival order)."""
        per = self.spec.period_s / self.spec.tick_s
        out: list[int] = []
        keep = np.zeros(len(stamps), dtype=bool)
        for i, (raw, step) in enumerate(zip(stamps, steps, strict=True)):
            resets = self.clock.resets
            idx = self.clock.index(int(raw))
            last = self._last
            if last is not None and idx <= last:
                self.stale += 1
                continue
            if (
                last is not None
                and self.clock.resets == resets
                and idx - last - int(step) * per > self.jump_ticks
            ):
                self.jumps += 1
            self._last = idx
            out.append(idx)
            keep[i] = True
        ticks = np.asarray(out, dtype=np.float64)
        per_s = round(1.0 / self.spec.tick_s)
        if abs(per_s * self.spec.tick_s - 1.0) < 1e-12:  # 1e-6 s: divide by 1e6, correctly rounded
            return ticks / per_s, keep
        return ticks * self.spec.tick_s, keep


class StreamJoiner:
    """Pairs an encoder stream and an IMU stream into multi-rate :class:`FrameBatch` es.

    A multi-rate batch needs at least one sample of each stream, so samples of one stream wait until
    the other has some. IMU samples arrive in *runs* with one set of IMUs present (a CAN sample may
    miss an IMU); each run becomes one batch with the encoder samples stamped before the next run (at
    least one). A stream that waits alone for more than ``hold_s`` of its own device time loses its
    oldest samples (``unpaired``): the other stream has gone silent, and a batch without it cannot be
    formed.

    >>> j = StreamJoiner("r", ("j",), ("i",))
    >>> j.add_encoders(np.array([0.0, 0.004]), np.zeros((2, 1)))
    >>> j.take()
    []
    >>> j.add_imus(np.array([0.008]), ("i",), np.zeros((1, 1, 3)), np.zeros((1, 1, 3)))
    >>> [(b.t.tolist(), b.t_q.tolist()) for b in j.take()]
    [([0.008], [0.0, 0.004])]
    """

    def __init__(
        self, robot: str, joints: tuple[str, ...], imus: tuple[str, ...], hold_s: float = 2.0
    ) -> None:
        self.robot, self.joints, self.imus = robot, joints, imus
        self.hold_s = hold_s
        self.unpaired = 0
        self._tq: list[np.ndarray] = []
        self._q: list[np.ndarray] = []
        #: IMU runs: (t, names, acc, gyro)
        self._runs: list[tuple[np.ndarray, tuple[str, ...], np.ndarray, np.ndarray]] = []

    @property
    def pending(self) -> tuple[int, int]:
        """(encoder samples, IMU samples) waiting for the other stream."""
        return sum(len(t) for t in self._tq), sum(len(r[0]) for r in self._runs)

    def add_encoders(self, t_q: np.ndarray, q: np.ndarray) -> None:
        if len(t_q):
            self._tq.append(np.asarray(t_q, dtype=np.float64))
            self._q.append(np.asarray(q, dtype=np.float64))

    def add_imus(self, t: np.ndarray, names: tuple[str, ...], acc: np.ndarray, gyro: np.ndarray) -> None:
        if not len(t):
            return
        if self._runs and self._runs[-1][1] == names:
            pt, _, pa, pg = self._runs[-1]
            self._runs[-1] = (
                np.concatenate([pt, t]),
                names,
                np.concatenate([pa, acc]),
                np.concatenate([pg, gyro]),
            )
        else:
            self._runs.append((np.asarray(t, dtype=np.float64), names, acc, gyro))

    def take(self) -> list[FrameBatch]:
        """The batches that can be formed now; the rest waits."""
        out: list[FrameBatch] = []
        tq = np.concatenate(self._tq) if self._tq else np.zeros(0)
        q = np.concatenate(self._q) if self._q else np.zeros((0, len(self.joints)))
        j = 0
        while self._runs and j < len(tq):
            t, names, acc, gyro = self._runs[0]
            if len(self._runs) == 1:
                stop = len(tq)
            else:
                stop = max(int(np.searchsorted(tq, self._runs[1][0][0], side="left")), j + 1)
            out.append(FrameBatch(self.robot, t, self.joints, q[j:stop], names, acc, gyro, t_q=tq[j:stop]))
            self._runs.pop(0)
            j = stop
        tq, q = tq[j:], q[j:]
        if len(tq) and tq[-1] - tq[0] > self.hold_s:
            cut = int(np.searchsorted(tq, tq[-1] - self.hold_s, side="left"))
            self.unpaired += cut
            tq, q = tq[cut:], q[cut:]
        self._tq, self._q = ([tq], [q]) if len(tq) else ([], [])
        if self._runs:
            t_all = np.concatenate([r[0] for r in self._runs])
            if t_all[-1] - t_all[0] > self.hold_s:
                limit = t_all[-1] - self.hold_s
                while self._runs and self._runs[0][0][-1] < limit:
                    self.unpaired += len(self._runs.pop(0)[0])
                if self._runs and self._runs[0][0][0] < limit:
                    t, names, acc, gyro = self._runs[0]
                    k = int(np.searchsorted(t, limit, side="left"))
                    self.unpaired += k
                    self._runs[0] = (t[k:], names, acc[k:], gyro[k:])
        return out
