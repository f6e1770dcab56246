"""Read a ROS bag (ROS 1 ``.bag``, ROS 2 sqlite3 or MCAP) into a recording (docs/recording-format.md).

Robotics teams keep their logs as bags, so a bag is read as it is, with the ``rosbags`` library (its
readers and typestores; no bag format is parsed here):

* every ``sensor_msgs/msg/Imu`` topic (or those named in :attr:`RosbagOptions.imu_topics`) gives IMUs,
  one per topic and ``header.frame_id``, named from the frame id (the topic when it is empty; names keep
  only ``A-Za-z0-9_.-``, others become ``_``, so they are valid part names for the service);
  ``linear_acceleration`` is the specific force (ROS reads about +9.81 m/s² up at rest, as we do) and
  ``angular_velocity`` the gyro;
* every ``sensor_msgs/msg/JointState`` topic (or those in :attr:`RosbagOptions.joint_topics`) gives
  encoders matched by joint name (cleaned alike), with ``position`` and, when every message has one,
  ``velocity``. A message without a position per name is dropped and counted.

**Stamps** are the messages' ``header.stamp`` (when the sensor sampled), never the bag's receive
times, and each stream keeps its own: when the encoders and the IMUs are stamped differently the result
is a multi-rate recording (``t`` for the IMUs, ``t_q`` for the encoders). IMUs whose topics carry
different stamps are resampled (linear) onto the stamps of the IMU with the most samples, within the
span all of them cover; joints published on several topics likewise. Identical stamps (one driver
publishing every IMU, or our own export) are taken exactly as they are. Stamps from a wall clock
(after 1e6 s) count from the whole second before the first one, kept as ``extra["stamp_origin_ns"]``,
so float seconds keep nanosecond resolution; small stamps (simulation time, time since boot) are kept
as they are. Exact duplicate stamps (a re-sent message) are dropped, counted in the summary; stamps
that go backwards are refused, naming the topic.

**Memory** is bounded by the numbers, not the messages: each message is decoded, its numbers copied
into fixed-size numeric chunks, and dropped.

Bad input gets a :class:`RosbagError` (a ``ValueError``) saying what the bag holds: a truncated or
unreadable bag, a topic asked for that is not there, a topic of another message type, a bag without
IMU or joint-state topics.

Example
-------
>>> opts = RosbagOptions(imu_topics=("/imu/data",))
>>> opts.imu_topics, opts.joint_topics
(('/imu/data',), ())
>>> part_name("/imu/data"), part_name("imu_link")
('imu_data', 'imu_link')
"""

from __future__ import annotations

import json
import logging
import os
import re
import sqlite3
import struct
import tempfile
from collections import Counter
from collections.abc import Collection, Generator, Iterator, Sequence
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection
from rosbags.rosbag1 import Reader as Ros1Reader
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag1.reader import Header, RecordType, read_bytes, read_uint32
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML
from ruamel.yaml.error import YAMLError

from bodyschema.recording import Recording, RecordingError, check_stamps
from simulators.recording_io import Blocks, save_recording

__all__ = [
    "IMU_TYPE",
    "JOINT_TYPE",
    "BagSummary",
    "RosbagError",
    "RosbagOptions",
    "bag_topics",
    "import_rosbag",
    "part_name",
    "read_rosbag",
]

log = logging.getLogger(__name__)

IMU_TYPE = "sensor_msgs/msg/Imu"
JOINT_TYPE = "sensor_msgs/msg/JointState"
#: Stamps below this (ns) are simulation time or time since boot and are kept as they are; above it they
#: are wall-clock stamps and count from a whole-second origin (float seconds keep ns resolution).
WALL_CLOCK_NS = 10**15
_NS = 1_000_000_000
#: What a truncated, corrupt or foreign file raises inside the readers.
_READ_ERRORS = (
    AnyReaderError,
    Ros1ReaderError,
    Ros2ReaderError,
    sqlite3.DatabaseError,
    struct.error,
    EOFError,
    UnicodeDecodeError,
)
#: ... while opening, and while decoding messages: headers, indexes and messages read from damaged bytes
#: fail in more ways than the readers name.
_OPEN_ERRORS = (*_READ_ERRORS, FileNotFoundError, ValueError, KeyError, IndexError)
_DECODE_ERRORS = (*_OPEN_ERRORS, OverflowError)


class RosbagError(ValueError):
    """A bag that cannot become a recording; the message says what the bag holds."""


@dataclass(frozen=True)
class RosbagOptions:
    """Which topics to read. Empty tuples mean every topic of the type; ``chunk_rows`` is the size of
    the numeric blocks samples are gathered in (memory grows by blocks, never by messages)."""

    imu_topics: tuple[str, ...] = ()
    joint_topics: tuple[str, ...] = ()
    chunk_rows: int = 4096

    def __post_init__(self) -> None:
        object.__setattr__(self, "imu_topics", tuple(self.imu_topics))
        object.__setattr__(self, "joint_topics", tuple(self.joint_topics))
        if self.chunk_rows < 1:
            raise ValueError(f"chunk_rows must be positive, got {self.chunk_rows}")


@dataclass(frozen=True)
class BagSummary:
    """What a read found: topics per stream, messages read, and what was dropped (by reason)."""

    imu_topics: dict[str, str]
    joint_topics: dict[str, str]
    messages: int
    dropped: dict[str, int] = field(default_factory=dict)


def part_name(text: str) -> str:
    """An IMU or joint name from a frame id or topic: characters outside ``A-Za-z0-9_.-`` become ``_``
    and leading ones are dropped, so the name is a valid part name for the service."""
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", text.strip().lstrip("/")).strip("_")
    return name[:64] or "unnamed"


class _Series:
    """Stamps (int64 ns) and ``width`` float64 values per sample, gathered in fixed-size blocks.

    The stamps stay in memory (8 bytes a sample, a few percent of a bag). The values do too, or, given
    a ``spool`` file, each full block is written there: then the values of any number of samples cost
    one block of memory, and :meth:`values` reads rows back.
    """

    def __init__(self, width: int, rows: int, spool: BinaryIO | None = None) -> None:
        self.width, self.rows, self._spool = width, rows, spool
        self._stamps: list[np.ndarray] = []
        self._values: list[np.ndarray] = []
        self._joined = np.empty((0, width))
        self._new_block()

    def _new_block(self) -> None:
        self._st = np.empty(self.rows, dtype=np.int64)
        self._va = np.empty((self.rows, self.width), dtype=np.float64)
        self._n = 0

    def append(self, stamp: int, values: Sequence[float] | np.ndarray) -> None:
        self._st[self._n] = stamp
        self._va[self._n] = values
        self._n += 1
        if self._n == self.rows:
            self._flush()

    def _flush(self) -> None:
        self._stamps.append(self._st[: self._n])
        if self._spool is None:
            self._values.append(self._va[: self._n])
        else:
            self._spool.write(self._va[: self._n].tobytes())
        self._new_block()

    def __len__(self) -> int:
        return sum(s.shape[0] for s in self._stamps) + self._n

    def finish(self) -> np.ndarray:
        """Every stamp, in arrival order; the values stay for :meth:`values`. Ends the appending."""
        if self._n:
            self._flush()
        stamps = np.concatenate(self._stamps) if self._stamps else np.empty(0, dtype=np.int64)
        self._stamps = []
        if self._spool is None:
            if self._values:
                self._joined = np.concatenate(self._values)
            self._values = []
        else:
            self._spool.flush()
        return stamps

    def values(self, lo: int, hi: int) -> np.ndarray:
        """Rows ``lo:hi`` of the values (after :meth:`finish`)."""
        if self._spool is None:
            return self._joined[lo:hi]
        size = self.width * 8
        self._spool.seek(lo * size)
        raw = self._spool.read((hi - lo) * size)
        return np.frombuffer(raw, dtype=np.float64).reshape(hi - lo, self.width)


@dataclass(eq=False)
class _Group:
    """One stream as it arrives: a topic with one frame id (IMU) or one list of joint names."""

    topic: str
    names: tuple[str, ...]
    series: _Series


def _stamp(msg: Any) -> int:
    s = msg.header.stamp
    return int(s.sec) * _NS + int(s.nanosec)


def _found(connections: Sequence[Connection]) -> str:
    """The topics and types of a bag, for error messages."""
    if not connections:
        return "the bag holds no topics"
    topics = sorted({(c.topic, c.msgtype) for c in connections})
    return "topics in the bag: " + ", ".join(f"{t} ({m})" for t, m in topics)


def _pick(
    connections: Sequence[Connection], wanted: tuple[str, ...], msgtype: str, what: str
) -> list[Connection]:
    """The connections of ``wanted`` topics (all of type ``msgtype`` when none named)."""
    if not wanted:
        picked = [c for c in connections if c.msgtype == msgtype]
        if not picked:
            raise RosbagError(f"no {msgtype} topic for the {what}; {_found(connections)}")
        return picked
    by_topic = {c.topic: c for c in connections}
    missing = [t for t in wanted if t not in by_topic]
    if missing:
        raise RosbagError(f"topic(s) {', '.join(missing)} not in the bag; {_found(connections)}")
    wrong = [f"{t} is {by_topic[t].msgtype}" for t in wanted if by_topic[t].msgtype != msgtype]
    if wrong:
        raise RosbagError(
            f"the {what} need {msgtype} topics, but {'; '.join(wrong)} (unknown message type for "
            f"{what}); {_found(connections)}"
        )
    return [c for c in connections if c.topic in wanted]


class _Collector:
    """Decoded messages in, numeric groups out; counts what it drops. Given a ``spool`` folder, the
    values go to unnamed temporary files there (gone when closed, or when the process dies)."""

    def __init__(self, rows: int, spool: Path | None = None) -> None:
        self.rows, self.spool = rows, spool
        self._files: list[BinaryIO] = []
        self.imus: dict[tuple[str, str], _Group] = {}
        self.joints: dict[tuple[str, tuple[str, ...]], _Group] = {}
        self.dropped: dict[str, int] = {}
        self.messages = 0
        #: topic -> its place in the bag's connection list (the order parts are listed in)
        self.rank: dict[str, int] = {}

    def __enter__(self) -> _Collector:
        return self

    def __exit__(self, *exc: object) -> None:
        for f in self._files:
            f.close()
        self._files = []

    def _series(self, width: int) -> _Series:
        if self.spool is None:
            return _Series(width, self.rows)
        self._files.append(tempfile.TemporaryFile(dir=self.spool, prefix=".bodyhealth-import-"))
        return _Series(width, self.rows, self._files[-1])

    def _drop(self, reason: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1

    def imu(self, topic: str, msg: Any) -> None:
        key = (topic, str(msg.header.frame_id))
        g = self.imus.get(key)
        if g is None:
            g = self.imus[key] = _Group(topic, (key[1],), self._series(6))
        a, w = msg.linear_acceleration, msg.angular_velocity
        g.series.append(_stamp(msg), (a.x, a.y, a.z, w.x, w.y, w.z))

    def joint_state(self, topic: str, msg: Any) -> None:
        names = tuple(str(n) for n in msg.name)
        pos, vel = np.asarray(msg.position, dtype=float), np.asarray(msg.velocity, dtype=float)
        if not names:
            self._drop("joint_states_without_names")
            return
        if pos.shape != (len(names),):
            self._drop("joint_states_without_positions")
            return
        if vel.shape != (len(names),):
            vel = np.full(len(names), np.nan)
        key = (topic, names)
        g = self.joints.get(key)
        if g is None:
            g = self.joints[key] = _Group(topic, names, self._series(2 * len(names)))
        g.series.append(_stamp(msg), np.concatenate([pos, vel]))


def _listed_topics(path: Path) -> str:
    """What a ROS 2 bag directory's ``metadata.yaml`` says it holds (its storage file may be the part
    that is damaged), for the error message; empty when there is none."""
    meta = path / "metadata.yaml"
    if not meta.is_file():
        return ""
    try:
        info = YAML(typ="safe").load(meta.read_text())["rosbag2_bagfile_information"]
        topics = sorted(
            (x["topic_metadata"]["name"], x["topic_metadata"]["type"], x["message_count"])
            for x in info["topics_with_message_count"]
        )
    except (YAMLError, KeyError, TypeError, OSError):
        return ""
    return "; metadata.yaml lists " + ", ".join(f"{t} ({m}, {n} messages)" for t, m, n in topics)


class _Ros1InFileOrder(Ros1Reader):
    """rosbags' ROS 1 reader, reading the messages in the order they are stored, without its index.

    rosbags keeps an index entry per message (a Python tuple, about 160 bytes: some 450 MB for a 1 GB
    bag) to merge the connections by receive time. A recording needs each stream in its own order
    only, which is the order a bag's chunks store them in, so this reader skips the per-message
    index and decompresses one chunk at a time: memory stays one chunk whatever the bag's size.
    """

    def read_index_data(self, pos: int, indexes: dict[int, list[Any]]) -> None:
        # an index data record: a 47-byte header (length at 0), then its data length at byte 51
        assert self.bio
        buf = read_bytes(self.bio, 55)
        (size,) = struct.unpack_from("<I", buf, 51)
        self.bio.seek(size, os.SEEK_CUR)

    def open(self) -> None:
        super().open()
        counts: Counter[int] = Counter()
        for info in self.chunk_infos:
            counts.update(info.connection_counts)
        self.connections = [Connection(*c[0:5], counts[c.id], *c[6:]) for c in self.connections]

    def messages(
        self, connections: Collection[Connection] = (), start: int | None = None, stop: int | None = None
    ) -> Generator[tuple[Connection, int, bytes], None, None]:
        self._check_open()
        assert self.bio
        by_id = {c.id: c for c in self.connections}
        wanted = {c.id for c in connections} if connections else set(by_id)
        for info in sorted(self.chunk_infos, key=lambda i: i.pos):
            if not wanted & info.connection_counts.keys():
                continue
            chunk = self.chunks[info.pos]
            self.bio.seek(chunk.datapos)
            raw = chunk.decompressor(read_bytes(self.bio, chunk.datasize))
            data, end = BytesIO(raw), len(raw)
            while data.tell() < end:
                header = Header.read(data)
                size = read_uint32(data)
                conn = header.get_uint32("conn") if header.get_uint8("op") == RecordType.MSGDATA else -1
                if conn not in wanted:
                    data.seek(size, os.SEEK_CUR)
                    continue
                time = header.get_time("time")
                if (start is not None and time < start) or (stop is not None and time >= stop):
                    data.seek(size, os.SEEK_CUR)
                    continue
                yield by_id[conn], time, read_bytes(data, size)


def _open(path: Path) -> AnyReader:
    if not path.exists():
        raise RosbagError(f"{path}: no such bag (a ROS 1 .bag file, or a ROS 2 bag directory or file)")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        if not reader.is2:
            reader.readers = [_Ros1InFileOrder(path)]
        reader.open()
    except _OPEN_ERRORS as err:
        raise RosbagError(
            f"{path}: cannot read the bag: it is truncated, corrupt or not a ROS bag ({err})"
            f"{_listed_topics(path)}"
        ) from None
    return reader


def bag_topics(path: str | os.PathLike[str]) -> dict[str, str]:
    """Topic -> message type of every topic in the bag at ``path``."""
    reader = _open(Path(path))
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()


def _decoded(
    reader: AnyReader, conns: list[Connection], path: Path, out: _Collector
) -> Iterator[tuple[Connection, Any]]:
    """Each message of ``conns`` decoded. Only the library's reading and decoding run under the
    ``except``: a failure there is a damaged bag, reported with what the bag holds."""
    messages = reader.messages(connections=conns)
    while True:
        try:
            item = next(messages, None)
            if item is None:
                return
            conn, _t, raw = item
            msg = reader.deserialize(raw, conn.msgtype)
        except _DECODE_ERRORS as err:
            raise RosbagError(
                f"{path}: the bag is truncated or corrupt after {out.messages} message(s) "
                f"({type(err).__name__}: {err}); {_found(reader.connections)}"
            ) from None
        yield conn, msg


def _collect(
    path: Path, options: RosbagOptions, out: _Collector
) -> tuple[list[Connection], list[Connection]]:
    """Read the picked topics of the bag into ``out``'s numeric groups, one message at a time."""
    reader = _open(path)
    try:
        conns = list(reader.connections)
        imu_c = _pick(conns, options.imu_topics, IMU_TYPE, "IMUs")
        joint_c = _pick(conns, options.joint_topics, JOINT_TYPE, "encoders")
        for i, conn in enumerate(conns):
            out.rank.setdefault(conn.topic, i)
        for conn, msg in _decoded(reader, [*imu_c, *joint_c], path, out):
            if conn.msgtype == IMU_TYPE:
                out.imu(conn.topic, msg)
            else:
                out.joint_state(conn.topic, msg)
            out.messages += 1
    finally:
        reader.close()
    return imu_c, joint_c


@dataclass(eq=False)
class _Stream:
    """One stream after cleaning: its stamps, and its rows read back through the raw rows kept."""

    topic: str
    series: _Series
    stamps: np.ndarray
    #: the raw row of each stamp; None when no sample was dropped
    kept: np.ndarray | None

    def rows(self, lo: int, hi: int) -> np.ndarray:
        if self.kept is None:
            return self.series.values(lo, hi)
        raw = self.kept[lo:hi]
        if raw.size == 0:
            return np.empty((0, self.series.width))
        return self.series.values(int(raw[0]), int(raw[-1]) + 1)[raw - raw[0]]


def _clean(group: _Group, dropped: dict[str, int]) -> _Stream:
    """Drop exact duplicate stamps (the first is kept); refuse stamps that go backwards."""
    stamps = group.series.finish()
    kept = None
    dup = np.flatnonzero(np.diff(stamps) == 0) + 1
    if dup.size:
        dropped["duplicate_stamps"] = dropped.get("duplicate_stamps", 0) + int(dup.size)
        log.warning("%s: dropped %d message(s) whose stamp repeats the previous one", group.topic, dup.size)
        keep = np.ones(stamps.shape[0], dtype=bool)
        keep[dup] = False
        kept, stamps = np.flatnonzero(keep), stamps[keep]
    try:
        check_stamps(stamps.astype(np.float64) / _NS, "header.stamp")
    except RecordingError as err:
        raise RosbagError(f"topic {group.topic}: {err}") from None
    return _Stream(group.topic, group.series, stamps, kept)


@dataclass(eq=False)
class _Aligned:
    """Streams on common stamps (:func:`_align`), their values produced block by block."""

    stamps: np.ndarray
    streams: list[_Stream]
    #: every stream has exactly these stamps (no interpolation)
    exact: bool
    #: the stamp the interpolation measures time from
    lo: int

    def rows(self, i0: int, i1: int) -> list[np.ndarray]:
        """Each stream's values on ``stamps[i0:i1]`` (``i0 < i1``): the same numbers whatever the
        blocks, since each is interpolated between the same two samples."""
        if self.exact:
            return [s.rows(i0, i1) for s in self.streams]
        x = (self.stamps[i0:i1] - self.lo).astype(np.float64)
        out = []
        for s in self.streams:
            a = max(int(np.searchsorted(s.stamps, self.stamps[i0], "right")) - 1, 0)
            b = min(int(np.searchsorted(s.stamps, self.stamps[i1 - 1], "left")) + 1, s.stamps.shape[0])
            xs = (s.stamps[a:b] - self.lo).astype(np.float64)
            va = s.rows(a, b)
            out.append(np.column_stack([np.interp(x, xs, va[:, j]) for j in range(va.shape[1])]))
        return out


def _align(streams: list[_Stream], what: str) -> _Aligned:
    """Stamps shared by every stream: the stamps as they are when all streams have the same, else
    those of the longest stream within the span all cover, the others interpolated linearly."""
    ref = max(streams, key=lambda s: s.stamps.shape[0]).stamps
    if all(np.array_equal(s.stamps, ref) for s in streams):
        return _Aligned(ref, streams, exact=True, lo=int(ref[0]))
    lo, hi = max(int(s.stamps[0]) for s in streams), min(int(s.stamps[-1]) for s in streams)
    st = ref[(ref >= lo) & (ref <= hi)]
    if st.shape[0] < 2:
        raise RosbagError(f"the {what} topics do not overlap in time")
    log.info("%s on different stamps: resampled onto %d common stamps", what, st.shape[0])
    return _Aligned(st, streams, exact=False, lo=lo)


@dataclass(eq=False)
class _Assembly:
    """What a bag holds, arranged as a recording: stamps, names and topics in memory, the numbers
    produced block by block."""

    imu_names: list[str]
    imu_topics: dict[str, str]
    imus: _Aligned
    joint_names: list[str]
    joint_topics: dict[str, str]
    joints: _Aligned
    #: per joint: (its stream, position column, velocity column)
    joint_cols: list[tuple[int, int, int]]

    def imu_blocks(self, rows: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """(specific force, angular rate), (n, K, 3) each, ``rows`` stamps at a time."""
        n = self.imus.stamps.shape[0]
        for i0 in range(0, n, rows):
            vals = self.imus.rows(i0, min(i0 + rows, n))
            yield np.stack([v[:, :3] for v in vals], axis=1), np.stack([v[:, 3:] for v in vals], axis=1)

    def joint_blocks(self, rows: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """(positions, velocities), (n, N) each (NaN where a velocity is absent), ``rows`` at a time."""
        n = self.joints.stamps.shape[0]
        for i0 in range(0, n, rows):
            vals = self.joints.rows(i0, min(i0 + rows, n))
            yield (
                np.column_stack([vals[s][:, p] for s, p, _ in self.joint_cols]),
                np.column_stack([vals[s][:, v] for s, _, v in self.joint_cols]),
            )


def _imu_side(c: _Collector) -> tuple[list[str], dict[str, str], _Aligned]:
    """IMU names, name -> topic and the aligned streams, in the bag's topic order (frame ids on one
    topic as first seen)."""
    groups = sorted(c.imus.values(), key=lambda g: c.rank[g.topic])
    frames = [g.names[0] for g in groups]
    names: list[str] = []
    for g in groups:
        frame = g.names[0]
        unique_frame = frame and frames.count(frame) == 1
        names.append(part_name(frame if unique_frame else f"{g.topic}/{frame}" if frame else g.topic))
    if len(set(names)) != len(names):
        raise RosbagError(f"IMU names collide after cleaning: {names}")
    aligned = _align([_clean(g, c.dropped) for g in groups], "IMU")
    return names, {n: g.topic for n, g in zip(names, groups, strict=True)}, aligned


def _joint_side(c: _Collector) -> tuple[list[str], dict[str, str], _Aligned, list[tuple[int, int, int]]]:
    """Joint names, name -> topic, the aligned streams and each joint's columns. Joints come in the
    order of their groups (most samples first), each group's in message order; a joint in several
    groups is taken from the one with the most samples."""
    owner: dict[str, _Group] = {}
    for g in sorted(c.joints.values(), key=lambda g: -len(g.series)):
        for n in g.names:
            owner.setdefault(n, g)
    used = list(dict.fromkeys(owner.values()))
    aligned = _align([_clean(g, c.dropped) for g in used], "joint state")
    names: list[str] = []
    cols: list[tuple[int, int, int]] = []
    for s, g in enumerate(used):
        k = len(g.names)
        for i, n in enumerate(g.names):
            if owner[n] is g:
                names.append(n)
                cols.append((s, i, k + i))
    clean = [part_name(n) for n in names]
    if len(set(clean)) != len(clean):
        raise RosbagError(f"joint names collide after cleaning: {names}")
    topics = {c: owner[n].topic for c, n in zip(clean, names, strict=True)}
    return clean, topics, aligned, cols


def _origin(*stamps: np.ndarray) -> int:
    first = min(int(s[0]) for s in stamps)
    return 0 if first < WALL_CLOCK_NS else (first // _NS) * _NS


def _assemble(path: Path, options: RosbagOptions, c: _Collector) -> tuple[_Assembly, BagSummary]:
    imu_c, joint_c = _collect(path, options, c)
    if not c.imus or not c.joints:
        what = "IMU" if not c.imus else "joint-state"
        topics = imu_c if not c.imus else joint_c
        raise RosbagError(
            f"{path}: no usable {what} message on {', '.join(sorted({x.topic for x in topics}))} "
            f"(dropped: {c.dropped or 'none'})"
        )
    asm = _Assembly(*_imu_side(c), *_joint_side(c))
    summary = BagSummary(
        imu_topics=dict(sorted({x.topic: x.msgtype for x in imu_c}.items())),
        joint_topics=dict(sorted({x.topic: x.msgtype for x in joint_c}.items())),
        messages=c.messages,
        dropped=dict(c.dropped),
    )
    return asm, summary


def _velocity(path: Path, blocks: Iterator[tuple[np.ndarray, np.ndarray]]) -> bool:
    """Whether every velocity is present; refuses positions that are not finite."""
    velocity = True
    for q, qd in blocks:
        if not np.all(np.isfinite(q)):
            raise RosbagError(f"{path}: q contains NaN or Inf")
        velocity = velocity and bool(np.all(np.isfinite(qd)))
    return velocity


def _recording(
    path: Path, asm: _Assembly, acc: np.ndarray, gyro: np.ndarray, q: np.ndarray, qd: np.ndarray | None
) -> Recording:
    t_ns, tq_ns = asm.imus.stamps, asm.joints.stamps
    origin = _origin(t_ns, tq_ns)
    same = np.array_equal(t_ns, tq_ns)
    topics = {"imus": asm.imu_topics, "joints": asm.joint_topics}
    try:
        return Recording(
            t=(t_ns - origin).astype(np.float64) / _NS,
            t_q=None if same else (tq_ns - origin).astype(np.float64) / _NS,
            joint_names=tuple(asm.joint_names),
            q=q,
            qd=qd,
            imu_names=tuple(asm.imu_names),
            acc=acc,
            gyro=gyro,
            extra={
                "stamp_origin_ns": np.array(origin, dtype=np.int64),
                "ros_topics": np.array(json.dumps(topics)),
            },
        )
    except RecordingError as err:
        raise RosbagError(f"{path}: {err}") from None


def read_rosbag(
    path: str | os.PathLike[str], options: RosbagOptions | None = None
) -> tuple[Recording, BagSummary]:
    """The recording held by the bag at ``path`` (see the module docstring) and what was read."""
    options = options or RosbagOptions()
    path = Path(path)
    asm, summary = _assemble(path, options, _Collector(options.chunk_rows))
    q, qd = next(asm.joint_blocks(asm.joints.stamps.shape[0]))
    velocity = _velocity(path, iter([(q, qd)]))
    acc, gyro = next(asm.imu_blocks(asm.imus.stamps.shape[0]))
    return _recording(path, asm, acc, gyro, q, qd if velocity else None), summary


def import_rosbag(
    path: str | os.PathLike[str], out: str | os.PathLike[str], options: RosbagOptions | None = None
) -> tuple[Recording, BagSummary]:
    """Write the recording held by the bag at ``path`` to ``out`` (.npz), in bounded memory.

    The same recording as :func:`read_rosbag` gives, byte for byte once loaded, but its numbers never
    sit in memory at once: they are spooled to unnamed temporary files beside ``out`` while the bag
    is read, and written to ``out`` block by block. What stays in memory are the stamps (8 bytes a
    sample). Returns the recording with its stamps and names, its sample arrays only placeholders of
    the right shape (read the file for the numbers), and what was read.
    """
    options = options or RosbagOptions()
    path, out = Path(path), Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows = options.chunk_rows
    with _Collector(rows, spool=out.parent) as c:
        asm, summary = _assemble(path, options, c)
        velocity = _velocity(path, asm.joint_blocks(rows))
        T, K = asm.imus.stamps.shape[0], len(asm.imu_names)
        imu_shape, joint_shape = (T, K, 3), (asm.joints.stamps.shape[0], len(asm.joint_names))
        zero = np.zeros(())
        rec = _recording(
            path,
            asm,
            np.broadcast_to(zero, imu_shape),
            np.broadcast_to(zero, imu_shape),
            np.broadcast_to(zero, joint_shape),
            np.broadcast_to(zero, joint_shape) if velocity else None,
        )
        blocks = {
            "acc": Blocks(lambda: (a for a, _ in asm.imu_blocks(rows))),
            "gyro": Blocks(lambda: (g for _, g in asm.imu_blocks(rows))),
            "q": Blocks(lambda: (q for q, _ in asm.joint_blocks(rows))),
        }
        if velocity:
            blocks["qd"] = Blocks(lambda: (qd for _, qd in asm.joint_blocks(rows)))
        save_recording(rec, out, blocks=blocks)
    return rec, summary
