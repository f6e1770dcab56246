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
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML
from ruamel.yaml.error import YAMLError

from bodyschema.recording import Recording, RecordingError, check_stamps

__all__ = [
    "IMU_TYPE",
    "JOINT_TYPE",
    "BagSummary",
    "RosbagError",
    "RosbagOptions",
    "bag_topics",
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
    """Stamps (int64 ns) and ``width`` float64 values per sample, gathered in fixed-size blocks."""

    def __init__(self, width: int, rows: int) -> None:
        self.width, self.rows = width, rows
        self._stamps: list[np.ndarray] = []
        self._values: list[np.ndarray] = []
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
            self._stamps.append(self._st)
            self._values.append(self._va)
            self._new_block()

    def __len__(self) -> int:
        return self.rows * len(self._stamps) + self._n

    def take(self) -> tuple[np.ndarray, np.ndarray]:
        """Stamps and values as two arrays; the blocks are released (the series is empty after)."""
        st = np.concatenate([*self._stamps, self._st[: self._n]])
        va = np.concatenate([*self._values, self._va[: self._n]])
        self._stamps, self._values = [], []
        self._new_block()
        return st, va


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
    """Decoded messages in, numeric groups out; counts what it drops."""

    def __init__(self, rows: int) -> None:
        self.rows = rows
        self.imus: dict[tuple[str, str], _Group] = {}
        self.joints: dict[tuple[str, tuple[str, ...]], _Group] = {}
        self.dropped: dict[str, int] = {}
        self.messages = 0
        #: topic -> its place in the bag's connection list (the order parts are listed in)
        self.rank: dict[str, int] = {}

    def _drop(self, reason: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1

    def imu(self, topic: str, msg: Any) -> None:
        key = (topic, str(msg.header.frame_id))
        g = self.imus.get(key)
        if g is None:
            g = self.imus[key] = _Group(topic, (key[1],), _Series(6, self.rows))
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
            g = self.joints[key] = _Group(topic, names, _Series(2 * len(names), self.rows))
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


def _open(path: Path) -> AnyReader:
    if not path.exists():
        raise RosbagError(f"{path}: no such bag (a ROS 1 .bag file, or a ROS 2 bag directory or file)")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
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


def _collect(path: Path, options: RosbagOptions) -> tuple[_Collector, list[Connection], list[Connection]]:
    """Read the picked topics of the bag into numeric groups, one message at a time."""
    reader = _open(path)
    out = _Collector(options.chunk_rows)
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
    return out, imu_c, joint_c


def _clean(
    topic: str, stamps: np.ndarray, values: np.ndarray, dropped: dict[str, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Drop exact duplicate stamps (the first is kept); refuse stamps that go backwards."""
    dup = np.flatnonzero(np.diff(stamps) == 0) + 1
    if dup.size:
        dropped["duplicate_stamps"] = dropped.get("duplicate_stamps", 0) + int(dup.size)
        log.warning("%s: dropped %d message(s) whose stamp repeats the previous one", topic, dup.size)
        keep = np.ones(stamps.shape[0], dtype=bool)
        keep[dup] = False
        stamps, values = stamps[keep], values[keep]
    try:
        check_stamps(stamps.astype(np.float64) / _NS, "header.stamp")
    except RecordingError as err:
        raise RosbagError(f"topic {topic}: {err}") from None
    return stamps, values


def _on_common_stamps(
    streams: list[tuple[np.ndarray, np.ndarray]], what: str
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Stamps shared by every stream and each stream's values on them: the stamps as they are when all
    streams have the same, else those of the longest stream within the span all cover, others
    interpolated linearly."""
    ref_st = max(streams, key=lambda s: s[0].shape[0])[0]
    if all(np.array_equal(st, ref_st) for st, _ in streams):
        return ref_st, [va for _, va in streams]
    lo, hi = max(int(st[0]) for st, _ in streams), min(int(st[-1]) for st, _ in streams)
    st = ref_st[(ref_st >= lo) & (ref_st <= hi)]
    if st.shape[0] < 2:
        raise RosbagError(f"the {what} topics do not overlap in time")
    log.info("%s on different stamps: resampled onto %d common stamps", what, st.shape[0])
    x = (st - lo).astype(np.float64)
    out = []
    for s, va in streams:
        xs = (s - lo).astype(np.float64)
        out.append(np.column_stack([np.interp(x, xs, va[:, j]) for j in range(va.shape[1])]))
    return st, out


def _imu_arrays(c: _Collector) -> tuple[np.ndarray, list[str], np.ndarray, np.ndarray, dict[str, str]]:
    """IMU stamps (ns), names, (T, K, 3) specific force and angular rate, and name -> topic, in the bag's
    topic order (frame ids on one topic as first seen). Each group's blocks are released as soon as
    they are joined, so the peak stays near twice the numbers the recording holds."""
    groups = sorted(c.imus.values(), key=lambda g: c.rank[g.topic])
    frames = [g.names[0] for g in groups]
    names: list[str] = []
    for g in groups:
        frame = g.names[0]
        unique_frame = frame and frames.count(frame) == 1
        names.append(part_name(frame if unique_frame else f"{g.topic}/{frame}" if frame else g.topic))
    if len(set(names)) != len(names):
        raise RosbagError(f"IMU names collide after cleaning: {names}")
    streams = [_clean(g.topic, *g.series.take(), c.dropped) for g in groups]
    st, vals = _on_common_stamps(streams, "IMU")
    del streams
    acc = np.stack([v[:, :3] for v in vals], axis=1)
    gyro = np.stack([v[:, 3:] for v in vals], axis=1)
    return st, names, acc, gyro, {n: g.topic for n, g in zip(names, groups, strict=True)}


def _joint_arrays(c: _Collector) -> tuple[np.ndarray, list[str], np.ndarray, np.ndarray, dict[str, str]]:
    """Encoder stamps (ns), joint names, (T, N) positions and velocities (NaN where absent), name ->
    topic. Joints come in the order of their groups (most samples first), each group's in message order;
    a joint in several groups is taken from the one with the most samples."""
    owner: dict[str, _Group] = {}
    for g in sorted(c.joints.values(), key=lambda g: -len(g.series)):
        for n in g.names:
            owner.setdefault(n, g)
    used = list(dict.fromkeys(owner.values()))
    streams = [_clean(g.topic, *g.series.take(), c.dropped) for g in used]
    st, vals = _on_common_stamps(streams, "joint state")
    names: list[str] = []
    pos: list[np.ndarray] = []
    vel: list[np.ndarray] = []
    for g, va in zip(used, vals, strict=True):
        k = len(g.names)
        for i, n in enumerate(g.names):
            if owner[n] is g:
                names.append(n)
                pos.append(va[:, i])
                vel.append(va[:, k + i])
    clean = [part_name(n) for n in names]
    if len(set(clean)) != len(clean):
        raise RosbagError(f"joint names collide after cleaning: {names}")
    topics = {c: owner[n].topic for c, n in zip(clean, names, strict=True)}
    return st, clean, np.column_stack(pos), np.column_stack(vel), topics


def _origin(*stamps: np.ndarray) -> int:
    first = min(int(s[0]) for s in stamps)
    return 0 if first < WALL_CLOCK_NS else (first // _NS) * _NS


def read_rosbag(
    path: str | os.PathLike[str], options: RosbagOptions | None = None
) -> tuple[Recording, BagSummary]:
    """The recording held by the bag at ``path`` (see the module docstring) and what was read."""
    options = options or RosbagOptions()
    path = Path(path)
    c, imu_c, joint_c = _collect(path, options)
    if not c.imus or not c.joints:
        what = "IMU" if not c.imus else "joint-state"
        topics = imu_c if not c.imus else joint_c
        raise RosbagError(
            f"{path}: no usable {what} message on {', '.join(sorted({x.topic for x in topics}))} "
            f"(dropped: {c.dropped or 'none'})"
        )
    t_ns, imu_names, acc, gyro, imu_topics = _imu_arrays(c)
    tq_ns, joint_names, q, qd, joint_topics = _joint_arrays(c)
    origin = _origin(t_ns, tq_ns)
    t = (t_ns - origin).astype(np.float64) / _NS
    same = np.array_equal(t_ns, tq_ns)
    extra = {
        "stamp_origin_ns": np.array(origin, dtype=np.int64),
        "ros_topics": np.array(json.dumps({"imus": imu_topics, "joints": joint_topics})),
    }
    try:
        rec = Recording(
            t=t,
            t_q=None if same else (tq_ns - origin).astype(np.float64) / _NS,
            joint_names=tuple(joint_names),
            q=q,
            qd=qd if np.all(np.isfinite(qd)) else None,
            imu_names=tuple(imu_names),
            acc=acc,
            gyro=gyro,
            extra=extra,
        )
    except RecordingError as err:
        raise RosbagError(f"{path}: {err}") from None
    summary = BagSummary(
        imu_topics=dict(sorted({x.topic: x.msgtype for x in imu_c}.items())),
        joint_topics=dict(sorted({x.topic: x.msgtype for x in joint_c}.items())),
        messages=c.messages,
        dropped=dict(c.dropped),
    )
    return rec, summary
