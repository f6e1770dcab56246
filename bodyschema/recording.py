"""The in-memory recording: encoder and IMU time series of one robot.

This is the exchange format of docs/design.md, 'Recording', held as arrays. Reading and writing ``.npz``
files lives in :mod:`simulators.recording_io`; this module only validates and derives (pure).

Example
-------
>>> import numpy as np
>>> t = np.arange(5) * 0.01
>>> rec = Recording(t=t, joint_names=("j1",), q=np.zeros((5, 1)), imu_names=("imu0",),
...                 acc=np.zeros((5, 1, 3)), gyro=np.zeros((5, 1, 3)))
>>> rec.n_samples, rec.n_joints, rec.n_imus
(5, 1, 1)
>>> rec.derived().qd.shape
(5, 1)

A multi-rate recording (docs/recording-format.md) keeps the encoders on their own stamps ``t_q``:

>>> two = Recording(t=t, t_q=np.arange(12) * 0.004, joint_names=("j1",), q=np.zeros((12, 1)),
...                 imu_names=("imu0",), acc=np.zeros((5, 1, 3)), gyro=np.zeros((5, 1, 3)))
>>> two.is_multirate, two.n_samples, round(two.encoder_rate)
(True, 5, 250)
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from bodyschema.topology import Topology

__all__ = [
    "GRAVITY",
    "MIN_SAMPLES",
    "Recording",
    "RecordingError",
    "check_complete",
    "check_finite",
    "check_stamps",
    "find_gaps",
]

#: Standard world gravity (z up), m/s².
GRAVITY = np.array([0.0, 0.0, -9.81])

#: Fewest samples per stream a recording file may hold: ``qdd``, the second difference of ``q`` that the
#: estimators read, needs three encoder samples, and a rate (one median step) needs two IMU steps.
MIN_SAMPLES = 3


class RecordingError(ValueError):
    """A recording whose arrays do not fit its contract (docs/design.md, 'Recording'): shape, order,
    finiteness."""


def check_stamps(t: np.ndarray, name: str = "t") -> None:
    """Raise :class:`RecordingError` saying where time stamps are not finite and strictly increasing.

    Stamps that go backwards and duplicate stamps are refused, each with its own message naming the
    first offending index: both mean the recorder lost track of its clock (or two logs were
    concatenated), and no ordering of the samples can be guessed safely. ``load_recording(...,
    repair=True)`` drops exact duplicates, logged; nothing repairs stamps that go backwards.
    """
    t = np.asarray(t)
    if t.ndim == 1 and t.shape[0] == 0:
        raise RecordingError(f"{name} is empty (0 samples): a recording needs at least one")
    if t.ndim != 1:
        raise RecordingError(f"{name} must have shape (T,), got {t.shape}")
    check_finite(t, name)
    if t.shape[0] > 1:
        d = np.diff(t)
        back = np.flatnonzero(d < 0)
        if back.size:
            i = int(back[0])
            raise RecordingError(
                f"{name} goes backwards at index {i + 1} ({t[i]:.6g} s -> {t[i + 1]:.6g} s, "
                f"{back.size} time(s) in all)"
            )
        dup = np.flatnonzero(d == 0)
        if dup.size:
            i = int(dup[0])
            raise RecordingError(
                f"{name} has duplicate stamps at index {i + 1} ({t[i]:.6g} s, {dup.size} in all); "
                "load with repair=True to drop them"
            )


def check_finite(v: np.ndarray, name: str, t: np.ndarray | None = None, labels: tuple[str, ...] = ()) -> None:
    """Raise :class:`RecordingError` naming the first sample (index, stamp, channel) that is NaN or Inf.

    One line that says where to look in the source log: the first bad index along time, its stamp when
    ``t`` is given, the channel (``labels`` name the second axis: joints, IMUs) and how many in all.
    """
    v = np.asarray(v)
    bad = ~np.isfinite(v)
    if not bad.any():
        return
    i = int(np.flatnonzero(bad.reshape(bad.shape[0], -1).any(axis=1))[0]) if v.ndim else 0
    where = f"at index {i}"
    if t is not None and i < np.shape(t)[0] and np.isfinite(t[i]):
        where += f" (t = {float(t[i]):.6g} s)"
    if v.ndim >= 2:
        ch = int(np.flatnonzero(bad[i].reshape(bad.shape[1], -1).any(axis=1))[0])
        where += f", {labels[ch]!r}" if ch < len(labels) else f", channel {ch}"
    raise RecordingError(f"{name} contains NaN or Inf {where}; {int(bad.sum())} value(s) in all")


def check_complete(rec: Recording, min_samples: int = MIN_SAMPLES) -> None:
    """Refuse what a recording *file* must not hold, beyond what :class:`Recording` checks itself.

    ``Recording`` accepts NaN in ``acc``/``gyro`` (a store window keeps an IMU silent for part of it as
    NaN) and a single sample (a streamed chunk); a file handed to the estimators may hold neither: every
    stream finite, at least ``min_samples`` samples per stream (:data:`MIN_SAMPLES`). The first bad
    index is named.
    """
    for name, stamps in (("t", rec.t), ("t_q", rec.t_q)):
        if stamps is not None and stamps.shape[0] < min_samples:
            raise RecordingError(
                f"{name} has {stamps.shape[0]} sample(s): a recording needs at least {min_samples} per "
                "stream (qdd, the second difference of q, needs three)"
            )
    te = rec.encoder_t
    for name in ("q", "qd", "qdd"):
        v = getattr(rec, name)
        if v is not None:
            check_finite(v, name, te, rec.joint_names)
    for name in ("acc", "gyro"):
        check_finite(getattr(rec, name), name, rec.t, rec.imu_names)
    for name in ("ref_quat", "ref_pos"):
        v = getattr(rec, name)
        if v is not None:
            check_finite(v, name, rec.t)
    check_finite(rec.gravity, "gravity")


def find_gaps(t: np.ndarray, factor: float = 3.0) -> list[tuple[float, float]]:
    """(start, stop) of every interval between stamps longer than ``factor`` median periods.

    Gaps are allowed in a recording (a dropped serial frame, a paused logger); they are reported, not
    filled: :mod:`bodyschema.timing` interpolates across short ones and excludes long ones from fits.
    """
    t = np.asarray(t, dtype=float)
    if t.shape[0] < 3:
        return []
    d = np.diff(t)
    big = np.flatnonzero(d > factor * np.median(d))
    return [(float(t[i]), float(t[i + 1])) for i in big]


def _as_names(names: Any) -> tuple[str, ...]:
    return tuple(str(n) for n in np.asarray(names, dtype=object).reshape(-1))


@dataclass(frozen=True)
class Recording:
    """Encoder and IMU time series of one robot (docs/design.md, 'Recording').

    Shapes: ``t`` (T,), ``q``/``qd``/``qdd`` (T,N) rad, ``acc``/``gyro`` (T,K,3) in the sensor frame,
    or, in a multi-rate recording (docs/recording-format.md), ``q``/``qd``/``qdd`` (T_q,N) on their own
    stamps ``t_q`` (T_q,) while ``t`` stamps the IMU stream;
    ``acc`` as specific force (reads about +9.81 up at rest). ``truth_*`` are ground truth for tests and
    benchmarks; estimators never read them. ``extra`` carries optional arrays (e.g. ``excitation``)
    through a round trip untouched.
    """

    t: np.ndarray
    joint_names: tuple[str, ...]
    q: np.ndarray | None
    imu_names: tuple[str, ...]
    acc: np.ndarray
    gyro: np.ndarray
    gravity: np.ndarray = field(default_factory=lambda: GRAVITY.copy())
    qd: np.ndarray | None = None
    qdd: np.ndarray | None = None
    ref_quat: np.ndarray | None = None
    ref_pos: np.ndarray | None = None
    truth_joint_parent: tuple[str, ...] | None = None
    truth_imu_joint: tuple[str, ...] | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    t_q: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "joint_names", _as_names(self.joint_names))
        object.__setattr__(self, "imu_names", _as_names(self.imu_names))
        for name in ("truth_joint_parent", "truth_imu_joint"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _as_names(v))
        self.validate()

    # ------------------------------------------------------------------ sizes
    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_imus(self) -> int:
        return len(self.imu_names)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if self.n_samples > 1 else 0.0

    @property
    def sample_rate(self) -> float:
        """Median sample rate of the IMU stream (of the whole recording when single-clock), Hz."""
        if self.n_samples < 2:
            return 0.0
        return float(1.0 / np.median(np.diff(self.t)))

    @property
    def is_multirate(self) -> bool:
        """True when the encoders have their own stamps ``t_q`` (docs/recording-format.md)."""
        return self.t_q is not None

    @property
    def encoder_t(self) -> np.ndarray:
        """The encoder stream's stamps: ``t_q`` in a multi-rate recording, else ``t``."""
        return self.t if self.t_q is None else self.t_q

    @property
    def encoder_rate(self) -> float:
        """Median sample rate of the encoder stream, Hz."""
        te = self.encoder_t
        return 0.0 if te.shape[0] < 2 else float(1.0 / np.median(np.diff(te)))

    # ------------------------------------------------------------ validation
    def validate(self) -> None:
        """Raise :class:`RecordingError` naming the first field that breaks the contract."""
        T, Tq = self._validate_stamps()
        N, K = self.n_joints, self.n_imus
        self._validate_names(N, K)
        self._validate_streams(T, Tq, N, K)
        self._validate_extras(T, N, K)

    def _validate_stamps(self) -> tuple[int, int]:
        """Check ``t`` (and ``t_q`` with the overlap of the two streams); return (T, T_q)."""
        t = np.asarray(self.t)
        check_stamps(t, "t")
        T = t.shape[0]
        if self.t_q is None:
            return T, T
        t_q = np.asarray(self.t_q)
        check_stamps(t_q, "t_q")
        lo, hi = max(t[0], t_q[0]), min(t[-1], t_q[-1])
        if not hi > lo:
            raise RecordingError(
                f"the IMU stream ({t[0]:.6g}..{t[-1]:.6g} s) and the encoder stream "
                f"({t_q[0]:.6g}..{t_q[-1]:.6g} s) do not overlap in time"
            )
        return T, t_q.shape[0]

    def _validate_names(self, N: int, K: int) -> None:
        """Joint and IMU names must be unique (they key every per-joint and per-IMU result)."""
        for name, names, n in (("joint_names", self.joint_names, N), ("imu_names", self.imu_names, K)):
            if len(set(names)) != n:
                raise RecordingError(f"{name} must be unique")

    def _validate_streams(self, T: int, Tq: int, N: int, K: int) -> None:
        """Shapes and finiteness of the encoder arrays (on ``t_q`` when present) and IMU arrays."""
        for name in ("q", "qd", "qdd"):
            v = getattr(self, name)
            if v is None:
                continue
            if v.shape != (Tq, N):
                stamps = "t_q" if self.t_q is not None else "t"
                raise RecordingError(f"{name} must have shape {(Tq, N)} (on {stamps}), got {v.shape}")
            check_finite(v, name, self.encoder_t, self.joint_names)
        for name in ("acc", "gyro"):
            v = getattr(self, name)
            if v.shape != (T, K, 3):
                raise RecordingError(f"{name} must have shape {(T, K, 3)}, got {v.shape}")

    def _validate_extras(self, T: int, N: int, K: int) -> None:
        """Gravity, the motion source (``q`` or ``ref_quat``), the reference motion and ground truth."""
        if np.asarray(self.gravity).shape != (3,):
            raise RecordingError("gravity must have shape (3,)")
        if self.q is None and self.ref_quat is None:
            raise RecordingError("a recording needs joint positions q or a reference motion ref_quat")
        for name, shape in (("ref_quat", (T, 4)), ("ref_pos", (T, 3))):
            v = getattr(self, name)
            if v is not None and v.shape != shape:
                raise RecordingError(f"{name} must have shape {shape}, got {v.shape}")
        for name, n, per in (("truth_joint_parent", N, "joint"), ("truth_imu_joint", K, "IMU")):
            v = getattr(self, name)
            if v is not None and len(v) != n:
                raise RecordingError(f"{name} must have one entry per {per}")

    # -------------------------------------------------------------- derived
    def derived(self) -> Recording:
        """This recording with ``qd`` and ``qdd`` filled by central differences where absent.

        Central differences on the encoder stamps: fine for the simulator's synced output, not a
        band-limited derivative; :mod:`bodyschema.timing` has the one the fast estimator uses on
        multi-rate data.
        """
        if self.q is None or (self.qd is not None and self.qdd is not None):
            return self
        qd = self.qd if self.qd is not None else _gradient(self.q, self.encoder_t)
        qdd = self.qdd if self.qdd is not None else _gradient(qd, self.encoder_t)
        return replace(self, qd=qd, qdd=qdd)

    def window(self, start: float, stop: float) -> Recording:
        """The samples with ``start <= t < stop`` (all array fields sliced alike; in a multi-rate
        recording each stream by its own stamps)."""
        m = (self.t >= start) & (self.t < stop)
        if self.t_q is None:
            return self.select(m)
        mq = (self.t_q >= start) & (self.t_q < stop)
        return self._pick(m, mq)

    def select(self, index: np.ndarray | slice) -> Recording:
        """Samples picked by a boolean mask, index array or slice along time.

        In a multi-rate recording the index picks IMU samples; the encoder samples kept are those
        stamped within the span of the picked IMU stamps.
        """
        if self.t_q is None:
            return self._pick(index, index)
        ts = self.t[index]
        if ts.size == 0:
            raise RecordingError("the selection holds no IMU sample")
        mq = (self.t_q >= ts.min()) & (self.t_q <= ts.max())
        return self._pick(index, mq)

    def _pick(self, index: np.ndarray | slice, qindex: np.ndarray | slice) -> Recording:
        def pick(v: np.ndarray | None) -> np.ndarray | None:
            return None if v is None else v[index]

        def pickq(v: np.ndarray | None) -> np.ndarray | None:
            return None if v is None else v[qindex]

        extra = {k: (v[index] if v.shape[:1] == self.t.shape else v) for k, v in self.extra.items()}
        return replace(
            self,
            t=self.t[index],
            t_q=pickq(self.t_q),
            q=pickq(self.q),
            qd=pickq(self.qd),
            qdd=pickq(self.qdd),
            acc=self.acc[index],
            gyro=self.gyro[index],
            ref_quat=pick(self.ref_quat),
            ref_pos=pick(self.ref_pos),
            extra=extra,
        )

    def synced(self) -> Recording:
        """A single-clock copy: encoder positions (and velocities) interpolated at the IMU stamps.

        For consumers that need one clock. Cubic interpolation on the encoder stamps, IMU samples
        outside the encoder stream's span dropped; no skew or filter delay is corrected (the fast
        estimator estimates those itself, :mod:`bodyschema.timing`).
        """
        if self.t_q is None:
            return self
        from scipy.interpolate import CubicSpline

        m = (self.t >= self.t_q[0]) & (self.t <= self.t_q[-1])
        inside = self._pick(m, slice(None))
        ts = inside.t

        def interp(v: np.ndarray | None) -> np.ndarray | None:
            return None if v is None else CubicSpline(self.t_q, v, axis=0)(ts)

        return replace(inside, t_q=None, q=interp(self.q), qd=interp(self.qd), qdd=interp(self.qdd))

    @property
    def truth_parent_map(self) -> dict[str, str | None] | None:
        """Ground-truth joint parents as a dict (None = mounted on the base)."""
        if self.truth_joint_parent is None:
            return None
        return {j: (p or None) for j, p in zip(self.joint_names, self.truth_joint_parent, strict=True)}

    @property
    def truth_imu_map(self) -> dict[str, str | None] | None:
        """Ground-truth IMU -> joint map (None = on the base link)."""
        if self.truth_imu_joint is None:
            return None
        return {i: (j or None) for i, j in zip(self.imu_names, self.truth_imu_joint, strict=True)}

    @property
    def truth_dependency(self) -> np.ndarray | None:
        """Ground-truth dependency matrix (IMUs x joints): IMU k moves with joint j exactly when j lies
        on the path from k's joint to the base (paper Def. 4; what the estimators try to find)."""
        par, imu = self.truth_parent_map, self.truth_imu_map
        if par is None or imu is None:
            return None
        tree = Topology(joint_parent=par, imu_joint=imu)  # checks the truth is an out-tree
        col = {j: i for i, j in enumerate(self.joint_names)}
        D = np.zeros((self.n_imus, self.n_joints), dtype=bool)
        for k, name in enumerate(self.imu_names):
            if imu[name] is not None:
                D[k, [col[j] for j in tree.ancestors(imu[name])]] = True
        return D


def _gradient(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    if x.shape[0] < 2:
        return np.zeros_like(x)
    return np.gradient(x, t, axis=0)
