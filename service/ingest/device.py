"""What a device on a wire is described by, and how its sample counter becomes time.

Both wire transports (CAN and serial) carry a *device sample counter* in every frame rather than a
clock: the device increments it once per sampling instant, so frames of one instant regroup by it and the
sample time is ``counter × period`` — never the arrival time, which jitters with USB, the kernel and the
host's load.

:class:`DeviceConfig` holds what the wire does not carry: the robot's name, the joint and IMU names in
wire order, and the sample period. It is read from a small JSON file (documented in
``docs/wire-formats.md``) or built in code.

:class:`DeviceClock` unwraps a counter of ``bits`` bits into a monotone index and notices device restarts.

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
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Backoff", "DeviceClock", "DeviceConfig", "DeviceConfigError"]


class DeviceConfigError(ValueError):
    """A device description that is incomplete or inconsistent."""


@dataclass(frozen=True)
class DeviceConfig:
    """Robot name, names in wire order, sample period, and transport-specific extras.

    ``extra`` keeps transport sections untouched (``"can"``: DBC path and signal mapping).

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

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.period_s

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
