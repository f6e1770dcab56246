"""The frame batch: ``T`` consecutive samples of one robot, the unit every layer of the service passes.

It lives in a leaf module of its own (numpy only) because both ends of the data flow use it: the
ingest sources produce it, the store keeps it, and neither may import the other (the store sits
below ingest: source -> pipeline -> store). Validation happens here, once, so whatever reaches the
store already meets the recording contract (docs/recording-format.md), and the names every source
hands in match :data:`NAME_PATTERN` (docs/security.md). Stamps are only required to be finite and
increasing here: a device clock may stamp its first samples a little before 0 (jitter, an encoder
clock that starts early), so "not negative" is a rule of the REST API's input only.

>>> import numpy as np
>>> b = FrameBatch("r1", np.array([0.0, 0.01]), ("j1",), np.zeros((2, 1)), ("imu0",),
...                np.zeros((2, 1, 3)), np.zeros((2, 1, 3)))
>>> b.validate(); b.n_imu_samples
2
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

import numpy as np

__all__ = [
    "ACC_LIMIT",
    "CHANNEL_LIMIT",
    "GYRO_LIMIT",
    "NAME_PATTERN",
    "NAME_RULE",
    "QD_LIMIT",
    "Q_LIMIT",
    "T_LIMIT",
    "FrameBatch",
    "FrameError",
    "check_batch_stamps",
    "check_name",
    "check_names",
    "check_values",
]

#: What a robot, joint or IMU name may be: they end up in URLs, metric labels, log fields and file
#: names, so only characters that need no escaping anywhere. The one definition the API and every
#: ingest source check against.
NAME_PATTERN = r"^[A-Za-z0-9_.-]{1,64}$"
_NAME = re.compile(NAME_PATTERN)
NAME_RULE = "1-64 characters of A-Z a-z 0-9 _ . -"

# The value bounds every batch is held to (docs/security.md, "Input bounds"). They refuse what no sensor
# or clock produces, so that an absurd number (1e308) cannot reach an estimator that squares it, never
# what a real device does: each is a common full scale times a margin of 4 for scale errors, offsets
# and sensors with wider ranges.
#: |t| and |t_q|, s: 100 Julian years either side of the Unix epoch. Unix-time stamps (1.8e9 s in
#: 2027) and uptime clocks both fit; float64 resolves 0.5 us there, far below any sample period.
T_LIMIT = 100 * 365.25 * 86400.0
#: |acc| per axis, m/s²: 4 x 16 g, the widest range of the MPU-6050 class of IMU (9.80665 m/s² per g).
ACC_LIMIT = 4 * 16 * 9.80665
#: |gyro| per axis, rad/s: 4 x 2000 deg/s, the widest range of that class.
GYRO_LIMIT = 4 * 2000 * 3.141592653589793 / 180.0
#: |q|, rad (or m on a prismatic joint): a continuous joint (a wheel) turning at 10 rad/s for a day
#: stays below it, and float64 resolves 1e-10 rad there, far below a 24-bit encoder's count.
Q_LIMIT = 1e6
#: |qd|, rad/s (or m/s): about 95,000 rpm, beyond any joint and any motor shaft.
QD_LIMIT = 1e4
#: |channel|: an extra channel's value in its own unit (foot forces in N or a sensor's raw counts): a
#: 100 kN load cell, or 10^6 counts of a 20-bit converter, stays below it.
CHANNEL_LIMIT = 1e6
#: Each stream's bound and unit, as :meth:`FrameBatch.validate` checks them.
_LIMITS: dict[str, tuple[float, str]] = {
    "t": (T_LIMIT, "s"),
    "t_q": (T_LIMIT, "s"),
    "q": (Q_LIMIT, "rad"),
    "qd": (QD_LIMIT, "rad/s"),
    "acc": (ACC_LIMIT, "m/s²"),
    "gyro": (GYRO_LIMIT, "rad/s"),
    "channels": (CHANNEL_LIMIT, "(own unit)"),
}


class FrameError(ValueError):
    """A frame batch that breaks the contract (shapes, NaN/Inf, values out of bounds, time going
    backwards, names outside :data:`NAME_PATTERN`)."""


def _index(flat: int, shape: tuple[int, ...]) -> str:
    return ", ".join(str(int(i)) for i in np.unravel_index(flat, shape))


def check_values(name: str, v: np.ndarray) -> None:
    """Raise :class:`FrameError` naming the stream and the first sample that is NaN, infinite or
    beyond the stream's bound (:data:`T_LIMIT`, :data:`ACC_LIMIT`, ...).

    >>> check_values("acc", np.array([[[0.0, 0.0, 9.8]], [[0.0, np.nan, 9.8]]]))
    Traceback (most recent call last):
    ...
    service.frames.FrameError: acc contains NaN or Inf: first at [1, 0, 1]
    >>> check_values("gyro", np.array([[[0.0, 200.0, 0.0]]]))
    Traceback (most recent call last):
    ...
    service.frames.FrameError: gyro[0, 0, 1] = 200 rad/s is beyond the bound of ±139.6 rad/s
    """
    finite = np.isfinite(v)
    if not finite.all():
        raise FrameError(f"{name} contains NaN or Inf: first at [{_index(int(np.argmin(finite)), v.shape)}]")
    limit, unit = _LIMITS[name]
    over = np.abs(v) > limit
    if over.any():
        k = int(np.argmax(over))
        raise FrameError(
            f"{name}[{_index(k, v.shape)}] = {v.flat[k]:.6g} {unit} is beyond the bound of "
            f"±{limit:.4g} {unit}"
        )


def check_batch_stamps(t: np.ndarray, name: str = "t") -> None:
    """Raise :class:`FrameError` naming the first stamp of ``t`` that goes backwards or repeats.

    Within one batch both are refused: the device's clock lost track, and no ordering of the samples
    can be guessed safely. (Across batches the store allows overlaps: a later write wins.)

    >>> check_batch_stamps(np.array([0.0, 0.01, 0.01]), "t_q")
    Traceback (most recent call last):
    ...
    service.frames.FrameError: t_q has a duplicate stamp at index 2 (0.01 s)
    """
    if t.ndim != 1:
        raise FrameError(f"{name} must have shape (T,), got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise FrameError(f"{name} contains NaN or Inf")
    if t.shape[0] > 1:
        d = np.diff(t)
        bad = np.flatnonzero(d <= 0)
        if bad.size:
            i = int(bad[0])
            if d[i] < 0:
                raise FrameError(
                    f"{name} goes backwards at index {i + 1} ({t[i]:.6g} s -> {t[i + 1]:.6g} s); "
                    f"{name} must be strictly increasing within a batch"
                )
            raise FrameError(f"{name} has a duplicate stamp at index {i + 1} ({t[i]:.6g} s)")


def check_name(name: object, what: str = "name") -> None:
    """Raise :class:`FrameError` unless ``name`` is a string matching :data:`NAME_PATTERN`.

    >>> check_name("ur5e-1", "robot name")
    >>> try:
    ...     check_name("arm 2", "robot name")
    ... except FrameError as err:
    ...     print(err)
    robot name 'arm 2' is not allowed (names: 1-64 characters of A-Z a-z 0-9 _ . -)
    """
    if not isinstance(name, str) or _NAME.fullmatch(name) is None:
        shown = repr(name) if not isinstance(name, str) or len(name) <= 80 else repr(name[:80] + "...")
        raise FrameError(f"{what} {shown} is not allowed (names: {NAME_RULE})")


@functools.lru_cache(maxsize=4096)
def check_names(robot: str, joint_names: tuple[str, ...], imu_names: tuple[str, ...]) -> None:
    """:func:`check_name` for a batch's robot and parts. Cached: a stream repeats the same names batch
    after batch (only passing results are remembered; a failing call raises)."""
    check_name(robot, "robot name")
    for n in joint_names:
        check_name(n, "joint name")
    for n in imu_names:
        check_name(n, "IMU name")


@dataclass(frozen=True)
class FrameBatch:
    """``T`` consecutive samples of one robot (T may be 1).

    ``t`` (T,) device time in s (never arrival time); ``q`` (T,N) rad; ``acc`` (T,K,3) m/s² specific
    force and ``gyro`` (T,K,3) rad/s in each sensor frame. An IMU that fell silent is simply absent from
    ``imu_names``; a robot without encoders has N = 0.

    Multi-rate (``t_q`` given): ``t_q`` (T_q,) stamps the encoder stream on the encoders' own clock,
    ``q`` and the optional ``qd`` (rad/s) are (T_q,N) on it, and ``t`` stamps the IMU stream only.
    Single-clock batches may carry ``qd`` (T,N) on ``t``.

    ``channels`` (T,E), named by ``channel_names``, are extra scalar series on the IMU stamps ``t``
    (a walking robot's foot forces: the floating-base checks find its contact phases in them). The
    store keeps them with the window and reads them back as the recording's ``extra``.
    """

    robot: str
    t: np.ndarray
    joint_names: tuple[str, ...]
    q: np.ndarray
    imu_names: tuple[str, ...]
    acc: np.ndarray
    gyro: np.ndarray
    t_q: np.ndarray | None = None
    qd: np.ndarray | None = None
    channel_names: tuple[str, ...] = ()
    channels: np.ndarray | None = None

    @property
    def n_samples(self) -> int:
        """IMU samples (all samples in a single-clock batch): what the counters count."""
        return int(self.t.shape[0])

    @property
    def is_multirate(self) -> bool:
        """True when the encoders carry stamps of their own (``t_q``)."""
        return self.t_q is not None

    @property
    def encoder_t(self) -> np.ndarray:
        """The encoder stream's stamps: ``t_q`` when multi-rate, else ``t``."""
        return self.t if self.t_q is None else self.t_q

    @property
    def n_imu_samples(self) -> int:
        return self.n_samples * len(self.imu_names)

    def validate(self) -> None:
        """Raise :class:`FrameError` naming what is wrong."""
        if not self.robot or not isinstance(self.robot, str):
            raise FrameError("robot name must be a non-empty string")
        try:
            check_names(self.robot, tuple(self.joint_names), tuple(self.imu_names))
        except TypeError:  # an unhashable name
            raise FrameError("joint and IMU names must be non-empty strings") from None
        for n in self.channel_names:
            check_name(n, "channel name")
        if len(set(self.channel_names)) != len(self.channel_names):
            raise FrameError("channel_names must be unique")
        self._check_shapes()
        for name in ("t", "t_q", "q", "qd", "acc", "gyro", "channels"):
            v = getattr(self, name)
            if v is not None:
                check_values(name, v)
        check_batch_stamps(self.t, "t")
        if self.t_q is not None:
            check_batch_stamps(self.t_q, "t_q")

    def _check_shapes(self) -> None:
        """Raise :class:`FrameError` when an array's shape disagrees with the stamps and the names."""
        T, N, K = self.t.shape[0] if self.t.ndim == 1 else -1, len(self.joint_names), len(self.imu_names)
        if T < 1:
            raise FrameError(f"t must have shape (T,) with T >= 1, got {self.t.shape}")
        Tq, on = T, "t"
        if self.t_q is not None:
            if not isinstance(self.t_q, np.ndarray) or self.t_q.ndim != 1 or self.t_q.shape[0] < 1:
                raise FrameError(f"t_q must have shape (T_q,) with T_q >= 1, got {np.shape(self.t_q)}")
            Tq, on = self.t_q.shape[0], "t_q"
        if self.q.shape != (Tq, N):
            raise FrameError(f"q must have shape {(Tq, N)} (on {on}), got {self.q.shape}")
        if self.qd is not None and np.shape(self.qd) != (Tq, N):
            raise FrameError(f"qd must have shape {(Tq, N)} (on {on}), got {np.shape(self.qd)}")
        for name in ("acc", "gyro"):
            v = getattr(self, name)
            if v.shape != (T, K, 3):
                raise FrameError(f"{name} must have shape {(T, K, 3)}, got {v.shape}")
        E = len(self.channel_names)
        if (self.channels is None) != (E == 0) or (E and np.shape(self.channels) != (T, E)):
            raise FrameError(
                f"channels must have shape {(T, E)} (on t, one column per channel name), "
                f"got {None if self.channels is None else np.shape(self.channels)}"
            )
