"""How frames are laid out in chunk rows: batches in, rows out, and rows back into a Recording.

Storing one row per sample would make a 60 s window of a 72-IMU robot at 100 Hz half a million rows;
instead consecutive batches of one robot with the same parts are coalesced into chunks of at most
``chunk_max_samples`` samples, each held as raw little-endian float64 blobs (see
:mod:`service.db.models`). This module is the pure part of that: checking batches, cutting and grouping
them into :class:`PendingChunk` rows, and merging rows read back into one
:class:`~bodyschema.recording.Recording` by device time. It knows numpy and the frame types, not the
database, so the layout is tested without one.

Example
-------
>>> import numpy as np
>>> b = FrameBatch("arm", np.arange(25) * 0.01, ("j1",), np.zeros((25, 1)), ("imu0",),
...                np.ones((25, 1, 3)), np.zeros((25, 1, 3)))
>>> [(c.robot, c.n) for c in build_chunks([b], max_samples=10)]
[('arm', 10), ('arm', 10), ('arm', 5)]
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bodyschema.recording import Recording
from service.frames import FrameBatch, FrameError

__all__ = ["PendingChunk", "assemble", "build_chunks", "check_batch"]

_F8 = np.dtype("<f8")


def _first(parts: list[np.ndarray]) -> float | None:
    for p in parts:
        if p.shape[0]:
            return float(p[0])
    return None


def _last(parts: list[np.ndarray]) -> float | None:
    for p in reversed(parts):
        if p.shape[0]:
            return float(p[-1])
    return None


@dataclass
class PendingChunk:
    """Consecutive samples of one robot with one joint set and one IMU set, before it becomes a row.

    A multi-rate chunk (``multirate``) keeps the encoder stream on its own stamps ``t_q``; either
    stream may be empty in one chunk (a long batch split by sample count), never both.
    """

    robot: str
    joint_names: tuple[str, ...]
    imu_names: tuple[str, ...]
    multirate: bool = False
    has_qd: bool = False
    channel_names: tuple[str, ...] = ()
    t: list[np.ndarray] = field(default_factory=list)
    t_q: list[np.ndarray] = field(default_factory=list)
    q: list[np.ndarray] = field(default_factory=list)
    qd: list[np.ndarray] = field(default_factory=list)
    acc: list[np.ndarray] = field(default_factory=list)
    gyro: list[np.ndarray] = field(default_factory=list)
    channels: list[np.ndarray] = field(default_factory=list)
    n: int = 0
    n_q: int = 0

    @property
    def imu_t_end(self) -> float | None:
        """Last IMU stamp (None when the chunk holds no IMU sample)."""
        return _last(self.t)

    @property
    def t_start(self) -> float:
        """First stamp of either stream: the chunk's extent covers both, so a range scan finds both."""
        return min(x for x in (_first(self.t), _first(self.t_q)) if x is not None)

    @property
    def t_end(self) -> float:
        return max(x for x in (_last(self.t), _last(self.t_q)) if x is not None)

    def accepts(self, b: FrameBatch, max_samples: int) -> bool:
        if not (
            b.joint_names == self.joint_names
            and b.imu_names == self.imu_names
            and b.is_multirate == self.multirate
            and (b.qd is not None) == self.has_qd
            and b.channel_names == self.channel_names
            and self.n + b.n_samples <= max_samples
        ):
            return False
        last = self.imu_t_end
        if last is not None and not float(b.t[0]) > last:
            return False
        if self.multirate:
            assert b.t_q is not None
            last_q = _last(self.t_q)
            if self.n_q + b.t_q.shape[0] > max_samples or (
                last_q is not None and not float(b.t_q[0]) > last_q
            ):
                return False
        return True

    def add(self, b: FrameBatch, sl: slice = slice(None), slq: slice | None = None) -> None:
        """Append samples ``sl`` of the IMU stream and ``slq`` of the encoder stream (default: ``sl``
        in a single-clock batch, everything in a multi-rate one)."""
        self.t.append(b.t[sl])
        self.acc.append(b.acc[sl])
        self.gyro.append(b.gyro[sl])
        if b.channels is not None:
            self.channels.append(b.channels[sl])
        self.n += int(b.t[sl].shape[0])
        if self.multirate:
            assert b.t_q is not None
            slq = slice(None) if slq is None else slq
            self.t_q.append(b.t_q[slq])
            self.n_q += int(b.t_q[slq].shape[0])
        else:
            slq = sl
        self.q.append(b.q[slq])
        if b.qd is not None:
            self.qd.append(b.qd[slq])

    def row(self, robot_id: int) -> dict[str, Any]:
        def blob(parts: list[np.ndarray]) -> bytes:
            arr = parts[0] if len(parts) == 1 else np.concatenate(parts)
            return np.ascontiguousarray(arr, dtype=_F8).tobytes()

        return {
            "robot_id": robot_id,
            "t_start": self.t_start,
            "t_end": self.t_end,
            "n": self.n,
            "joint_names": list(self.joint_names),
            "imu_names": list(self.imu_names),
            "t": blob(self.t),
            "q": blob(self.q),
            "acc": blob(self.acc),
            "gyro": blob(self.gyro),
            "n_q": self.n_q if self.multirate else None,
            "t_q": blob(self.t_q) if self.multirate else None,
            "qd": blob(self.qd) if self.has_qd else None,
            "channel_names": list(self.channel_names) if self.channel_names else None,
            "channels": blob(self.channels) if self.channel_names else None,
        }


@functools.lru_cache(maxsize=4096)
def _check_names(joint_names: tuple[str, ...], imu_names: tuple[str, ...]) -> None:
    """Unique, non-empty string names. Cached: a stream repeats the same name tuples batch after batch,
    and checking 72 names per 0.1 s batch was a tenth of the ingest time. (Only passing results are
    cached; a failing call raises and is not remembered.)"""
    if len(set(joint_names)) != len(joint_names):
        raise FrameError("joint_names must be unique")
    if len(set(imu_names)) != len(imu_names):
        raise FrameError("imu_names must be unique")
    if any(not isinstance(n, str) or not n for n in (*joint_names, *imu_names)):
        raise FrameError("joint and IMU names must be non-empty strings")


def check_batch(i: int, b: Any) -> None:
    """FrameBatch.validate plus what the store needs on top (numeric arrays, unique names)."""
    if not isinstance(b, FrameBatch):
        raise FrameError(f"batch {i}: expected a FrameBatch, got {type(b).__name__}")
    try:
        for name in ("t", "t_q", "q", "qd", "acc", "gyro", "channels"):
            v = getattr(b, name)
            if v is None and name in ("t_q", "qd", "channels"):
                continue
            if not isinstance(v, np.ndarray) or v.dtype.kind not in "fiu":
                raise FrameError(f"{name} must be a numeric numpy array")
        b.validate()
        try:
            _check_names(tuple(b.joint_names), tuple(b.imu_names))
        except TypeError:  # an unhashable name
            raise FrameError("joint and IMU names must be non-empty strings") from None
    except FrameError as err:
        raise FrameError(f"batch {i} (robot {getattr(b, 'robot', '?')!r}): {err}") from None


def _pieces(b: FrameBatch, max_samples: int) -> list[tuple[slice, slice | None]]:
    """Cut one batch into pieces of at most ``max_samples`` samples per stream.

    A multi-rate batch is cut at stamps: each cut lies at the first sample that would overflow either
    stream, so both streams of a piece cover the same stretch of time (one of them may be empty)."""
    if b.t_q is None:
        return [
            (slice(a, min(a + max_samples, b.n_samples)), None) for a in range(0, b.n_samples, max_samples)
        ]
    t, tq = b.t, b.t_q
    if t.shape[0] <= max_samples and tq.shape[0] <= max_samples:
        return [(slice(None), slice(None))]
    out: list[tuple[slice, slice | None]] = []
    i = j = 0
    while i < t.shape[0] or j < tq.shape[0]:
        cut = math.inf
        if i + max_samples < t.shape[0]:
            cut = float(t[i + max_samples])
        if j + max_samples < tq.shape[0]:
            cut = min(cut, float(tq[j + max_samples]))
        i2 = t.shape[0] if cut == math.inf else int(np.searchsorted(t, cut, side="left"))
        j2 = tq.shape[0] if cut == math.inf else int(np.searchsorted(tq, cut, side="left"))
        out.append((slice(i, i2), slice(j, j2)))
        i, j = i2, j2
    return out


def build_chunks(batches: Sequence[FrameBatch], max_samples: int) -> list[PendingChunk]:
    """Group batches into chunks: per robot, consecutive batches with the same names and channels, the
    same kind (single-clock or multi-rate, with or without ``qd``) and increasing time share a chunk of
    at most ``max_samples`` samples per stream (longer batches are split)."""
    done: list[PendingChunk] = []
    open_: dict[str, PendingChunk] = {}
    for b in batches:
        cur = open_.get(b.robot)
        if cur is not None and cur.accepts(b, max_samples):
            cur.add(b)
            continue
        if cur is not None:
            done.append(cur)
        pieces = _pieces(b, max_samples)
        for k, (sl, slq) in enumerate(pieces):
            cur = PendingChunk(
                b.robot, b.joint_names, b.imu_names, b.is_multirate, b.qd is not None, b.channel_names
            )
            cur.add(b, sl, slq)
            if k < len(pieces) - 1:
                done.append(cur)
        assert cur is not None
        open_[b.robot] = cur
    done.extend(open_.values())
    return done


def _decode(blob: bytes, shape: tuple[int, ...]) -> np.ndarray:
    return np.frombuffer(blob, dtype=_F8).reshape(shape)


@dataclass
class _Part:
    """One stream's samples of one chunk inside the window: ``arrays`` are (n, len(names), ...)."""

    names: tuple[str, ...]
    t: np.ndarray
    arrays: tuple[np.ndarray | None, ...]


def assemble(
    rows: Iterable[Any], start: float, end: float, order: dict[str, int], partial_imus: str
) -> Recording | None:
    """Merge chunk rows into one Recording over ``start < t <= end`` (each stream by its own stamps)."""
    imu_parts: list[_Part] = []
    enc_parts: list[_Part] = []
    chan_parts: list[_Part] = []
    multirate = False
    for n, n_q, jn, kn, t_blob, tq_blob, q_blob, qd_blob, acc_blob, gyro_blob, cn, c_blob in rows:
        n, jn, kn = int(n), tuple(jn), tuple(kn)
        t = _decode(t_blob, (n,))
        m = (t > start) & (t <= end)
        if m.any():
            sel = slice(None) if m.all() else m
            acc = _decode(acc_blob, (n, len(kn), 3))[sel]
            imu_parts.append(_Part(kn, t[sel], (acc, _decode(gyro_blob, (n, len(kn), 3))[sel])))
            if c_blob is not None:
                chan_parts.append(_Part(tuple(cn), t[sel], (_decode(c_blob, (n, len(cn)))[sel],)))
        if tq_blob is not None:
            multirate = True
            n_enc = int(n_q)
            te = _decode(tq_blob, (n_enc,))
            m = (te > start) & (te <= end)
        else:
            n_enc, te = n, t
        if not m.any():
            continue
        sel = slice(None) if m.all() else m
        qd = None if qd_blob is None else _decode(qd_blob, (n_enc, len(jn)))[sel]
        enc_parts.append(_Part(jn, te[sel], (_decode(q_blob, (n_enc, len(jn)))[sel], qd)))
    if not imu_parts or not enc_parts:
        return None
    t, imus, (acc, gyro) = _merge_stream(
        imu_parts, "imus", order, keep="all" if partial_imus == "drop" else "any"
    )
    te, joints, (q, qd) = _merge_stream(enc_parts, "joints", order, keep="all")
    extra = _channels(chan_parts, t, order)
    if not multirate:
        return Recording(t=t, joint_names=joints, q=q, qd=qd, imu_names=imus, acc=acc, gyro=gyro, extra=extra)
    if not min(t[-1], te[-1]) > max(t[0], te[0]):
        return None  # the two streams do not overlap in this window
    return Recording(
        t=t, t_q=te, joint_names=joints, q=q, qd=qd, imu_names=imus, acc=acc, gyro=gyro, extra=extra
    )


def _channels(parts: list[_Part], t: np.ndarray, order: dict[str, int]) -> dict[str, np.ndarray]:
    """The window's extra channels on its IMU stamps ``t``, as ``Recording.extra``. A channel heard
    on only part of the window is left out, as a joint is; so are all of them when some chunk of the
    window carries none (a source that stopped sending them): a foot force with a hole would read
    as a foot in the air."""
    if not parts:
        return {}
    tc, names, (v,) = _merge_stream(parts, "channels", order, keep="all")
    if v is None or tc.shape != t.shape or not np.array_equal(tc, t):
        return {}
    return {n: v[:, i] for i, n in enumerate(names)}


def _merge_stream(
    parts: list[_Part], table: str, order: dict[str, int], keep: str
) -> tuple[np.ndarray, tuple[str, ...], tuple[np.ndarray | None, ...]]:
    """One stream of the window from its chunk parts: stamps, names, arrays.

    The common case (one name set, parts in time order) is a concatenation. Otherwise the parts merge
    on the union of their stamps, later parts overwriting earlier ones at equal stamps; a name heard
    in only part of the window is left out (``keep="all"``) or kept with NaN where it was silent
    (``"any"``). An array that some part lacks (``qd``) is left out of the result.
    """
    n_arr = len(parts[0].arrays)
    present = [all(p.arrays[a] is not None for p in parts) for a in range(n_arr)]
    names0 = parts[0].names
    if all(p.names == names0 for p in parts):
        t = parts[0].t if len(parts) == 1 else np.concatenate([p.t for p in parts])
        if t.shape[0] == 1 or np.all(np.diff(t) > 0):
            arrays = tuple(
                (np.concatenate([p.arrays[a] for p in parts]) if len(parts) > 1 else parts[0].arrays[a])
                if present[a]
                else None
                for a in range(n_arr)
            )
            return t, names0, arrays
    t_all, inv = np.unique(np.concatenate([p.t for p in parts]), return_inverse=True)
    T = t_all.shape[0]
    names = sorted({x for p in parts for x in p.names}, key=lambda x: (order.get(f"{table}:{x}", 1 << 30), x))
    ix = {x: i for i, x in enumerate(names)}
    out: list[np.ndarray | None] = []
    for a in range(n_arr):
        if not present[a]:
            out.append(None)
            continue
        tail = next(p.arrays[a].shape[2:] for p in parts if p.arrays[a] is not None)  # type: ignore[union-attr]
        out.append(np.full((T, len(names), *tail), np.nan))
    heard = np.zeros((T, len(names)), dtype=bool)
    pos = 0
    for p in parts:
        rows_ix = inv[pos : pos + p.t.shape[0]]
        pos += p.t.shape[0]
        if not p.names:
            continue
        cols = [ix[x] for x in p.names]
        for a, arr in enumerate(out):
            if arr is not None:
                arr[np.ix_(rows_ix, cols)] = p.arrays[a]
        heard[np.ix_(rows_ix, cols)] = True
    kept = heard.all(axis=0) if keep == "all" else heard.any(axis=0)
    return (
        t_all,
        tuple(x for x, k in zip(names, kept, strict=True) if k),
        tuple(None if arr is None else arr[:, kept] for arr in out),
    )
