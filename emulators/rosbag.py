"""Write a recording as a ROS bag, as a robot's ROS drivers would have logged it.

Users replay our recordings in their own tools (rviz, Foxglove, PlotJuggler, rosbag play), and the
tests write real bags from simulated robots with it. Written with the ``rosbags`` library's writers
and typestores: ROS 2 (MCAP, the ROS 2 default since Iron, or sqlite3) or ROS 1 (``.bag``).

What goes in: one ``sensor_msgs/msg/Imu`` topic per IMU (``/imu/<name>``, ``header.frame_id`` = the IMU
name; no orientation estimate, ``orientation_covariance[0] = -1`` as REP 145 asks) and one
``sensor_msgs/msg/JointState`` topic (``/joint_states``) with every joint's ``position`` and, when the
recording has it, ``velocity``. Each stream keeps its own stamps (``header.stamp``; the bag's log time
is the same stamp), so a multi-rate recording stays multi-rate. Stamps are the recording's seconds in
integer nanoseconds (:func:`stamps_ns`) after an origin: :attr:`RosbagWriteOptions.origin_ns`, else the
recording's ``extra["stamp_origin_ns"]`` (what :func:`service.ingest.rosbag.read_rosbag` keeps, so a bag
read and written again has the same stamps), else 0; bag times cannot be negative, so a recording with
stamps before its origin (the simulator's encoder clock starts a little before 0) moves on by whole
seconds, logged.

Example
-------
>>> stamps_ns(np.array([0.0, 0.0025, 1.5]), 10**9).tolist()
[1000000000, 1002500000, 2500000000]
>>> imu_topic("imu-3.a")
'/imu/imu_3_a'
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from bodyschema.recording import Recording

__all__ = ["FORMATS", "MessageFactory", "RosbagWriteOptions", "imu_topic", "stamps_ns", "write_rosbag"]

log = logging.getLogger(__name__)

BagFormat = Literal["mcap", "sqlite3", "ros1"]
FORMATS: tuple[str, ...] = ("mcap", "sqlite3", "ros1")
IMU_TYPE = "sensor_msgs/msg/Imu"
JOINT_TYPE = "sensor_msgs/msg/JointState"
_NS = 1_000_000_000


@dataclass(frozen=True)
class RosbagWriteOptions:
    """How to write: bag ``format``, the joint-state topic, and the stamp origin (ns; None: the
    recording's ``stamp_origin_ns`` or 0)."""

    format: BagFormat = "mcap"
    joint_topic: str = "/joint_states"
    origin_ns: int | None = None

    def __post_init__(self) -> None:
        if self.format not in FORMATS:
            raise ValueError(f"bag format must be one of {', '.join(FORMATS)}, got {self.format!r}")
        if self.origin_ns is not None and self.origin_ns < 0:
            raise ValueError(f"origin_ns must not be negative, got {self.origin_ns}")


def stamps_ns(t: np.ndarray, origin_ns: int = 0) -> np.ndarray:
    """Seconds as integer nanoseconds after ``origin_ns`` (rounded to the nearest ns)."""
    return origin_ns + np.rint(np.asarray(t, dtype=np.float64) * _NS).astype(np.int64)


def imu_topic(name: str) -> str:
    """``/imu/<name>``, the name cut to a valid ROS topic token (letters, digits, ``_``)."""
    token = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return f"/imu/{token if token[:1].isalpha() else 'i' + token}"


def _origin(rec: Recording, options: RosbagWriteOptions) -> int:
    if options.origin_ns is not None:
        origin = int(options.origin_ns)
    elif "stamp_origin_ns" in rec.extra:
        origin = int(np.asarray(rec.extra["stamp_origin_ns"]))
    else:
        origin = 0
    first = min(float(rec.t[0]), float(rec.encoder_t[0]))
    if origin + first * _NS < 0:
        shift = int(np.ceil(-(origin + first * _NS) / _NS)) * _NS
        log.info("stamps start before the bag's zero: moved on by %d s", shift // _NS)
        origin += shift
    return origin


def _make(typestore: Typestore, msgtype: str, **kwargs: Any) -> Any:
    """A message of ``msgtype`` from the fields this typestore's definition has (ROS 1's Header has
    ``seq``, ROS 2's does not)."""
    cls = typestore.types[msgtype]
    names = {f.name for f in fields(cls)}
    return cls(**{k: v for k, v in kwargs.items() if k in names})


class MessageFactory:
    """Builds and serializes the two message types for one typestore."""

    def __init__(self, typestore: Typestore, serialize: Callable[[Any, str], Any]) -> None:
        self.ts, self._ser = typestore, serialize
        self.seq: dict[str, int] = {}
        self._cov_none = np.zeros(9)
        self._cov_none[0] = -1.0
        self._cov0 = np.zeros(9)

    def _header(self, topic: str, stamp: int, frame_id: str) -> Any:
        seq = self.seq[topic] = self.seq.get(topic, -1) + 1
        time = _make(self.ts, "builtin_interfaces/msg/Time", sec=stamp // _NS, nanosec=stamp % _NS)
        return _make(self.ts, "std_msgs/msg/Header", seq=seq, stamp=time, frame_id=frame_id)

    def imu(self, topic: str, stamp: int, frame_id: str, acc: np.ndarray, gyro: np.ndarray) -> bytes:
        v3 = self.ts.types["geometry_msgs/msg/Vector3"]
        msg = _make(
            self.ts,
            IMU_TYPE,
            header=self._header(topic, stamp, frame_id),
            orientation=self.ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=self._cov_none,
            angular_velocity=v3(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])),
            angular_velocity_covariance=self._cov0,
            linear_acceleration=v3(x=float(acc[0]), y=float(acc[1]), z=float(acc[2])),
            linear_acceleration_covariance=self._cov0,
        )
        return bytes(self._ser(msg, IMU_TYPE))

    def joints(self, topic: str, stamp: int, names: list[str], q: np.ndarray, qd: np.ndarray | None) -> bytes:
        msg = _make(
            self.ts,
            JOINT_TYPE,
            header=self._header(topic, stamp, ""),
            name=names,
            position=np.asarray(q, dtype=np.float64),
            velocity=np.asarray(qd, dtype=np.float64) if qd is not None else np.zeros(0),
            effort=np.zeros(0),
        )
        return bytes(self._ser(msg, JOINT_TYPE))


def _order(t_imu: np.ndarray, t_enc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(is_imu, index) of every sample of both streams in stamp order (encoders first on a tie)."""
    stamps = np.concatenate([t_enc, t_imu])
    kind = np.concatenate([np.zeros(t_enc.shape[0], bool), np.ones(t_imu.shape[0], bool)])
    index = np.concatenate([np.arange(t_enc.shape[0]), np.arange(t_imu.shape[0])])
    order = np.argsort(stamps, kind="stable")
    return kind[order], index[order]


def write_rosbag(
    rec: Recording, path: str | os.PathLike[str], options: RosbagWriteOptions | None = None
) -> int:
    """Write ``rec`` as a bag at ``path`` (a ROS 2 bag directory, or a ROS 1 ``.bag`` file, which must
    not exist yet); returns the number of messages written."""
    options = options or RosbagWriteOptions()
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists already; a bag is never overwritten")
    if rec.q is None:
        raise ValueError("the recording has no joint positions (q) to write as joint states")
    if options.format == "ros1" and path.suffix != ".bag":
        raise ValueError(f"a ROS 1 bag is a .bag file, got {path}")
    origin = _origin(rec, options)
    t_imu, t_enc = stamps_ns(rec.t, origin), stamps_ns(rec.encoder_t, origin)
    topics = [imu_topic(n) for n in rec.imu_names]
    if len(set(topics)) != len(topics):
        topics = [f"{t}_{k}" for k, t in enumerate(topics)]
    if options.format == "ros1":
        ts = get_typestore(Stores.ROS1_NOETIC)
        writer: Any = Writer1(path)
        serialize: Callable[[Any, str], Any] = ts.serialize_ros1
    else:
        ts = get_typestore(Stores.ROS2_HUMBLE)
        plugin = StoragePlugin.MCAP if options.format == "mcap" else StoragePlugin.SQLITE3
        writer = Writer2(path, version=Writer2.VERSION_LATEST, storage_plugin=plugin)
        serialize = ts.serialize_cdr
    msgs = MessageFactory(ts, serialize)
    names = list(rec.joint_names)
    n = 0
    with writer:
        joint_conn = writer.add_connection(options.joint_topic, JOINT_TYPE, typestore=ts)
        imu_conns = [writer.add_connection(tp, IMU_TYPE, typestore=ts) for tp in topics]
        for is_imu, i in zip(*_order(t_imu, t_enc), strict=True):
            if is_imu:
                stamp = int(t_imu[i])
                for k, conn in enumerate(imu_conns):
                    data = msgs.imu(conn.topic, stamp, rec.imu_names[k], rec.acc[i, k], rec.gyro[i, k])
                    writer.write(conn, stamp, data)
                n += len(imu_conns)
            else:
                stamp = int(t_enc[i])
                qd = rec.qd[i] if rec.qd is not None else None
                writer.write(joint_conn, stamp, msgs.joints(options.joint_topic, stamp, names, rec.q[i], qd))
                n += 1
    return n
