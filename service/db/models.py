"""The relational schema of the store (SQLAlchemy 2.0 declarative models).

The schema itself is created only by the Alembic migrations under ``migrations/``; Alembic's ``env.py``
reads :data:`Base.metadata` so autogenerate can compare the two (a test keeps them in step).

Frames are not stored one row per number: a :class:`Chunk` holds ``n`` consecutive samples of one robot
as raw little-endian float64 blobs (``t`` (n,), ``q`` (n,N), ``acc``/``gyro`` (n,K,3)) together with the
joint and IMU names it carries, indexed by ``(robot_id, t_start, t_end)`` so a window is one range scan.
A multi-rate chunk (encoders on a clock of their own, docs/recording-format.md) adds ``t_q`` (n_q,) and
keeps ``q`` (n_q,N) on it; ``t``/``acc``/``gyro`` are then the IMU stream. ``t_q``/``n_q`` are NULL in a
single-clock chunk; ``qd`` (joint velocities as the encoders reported them, on the encoder stamps) is
NULL when the encoders report none. ``t_start``/``t_end`` span both streams.
Each chunk belongs to one device clock epoch (``epoch``): a robot whose clock went back (a restart)
starts a new epoch, and its windows are read from the current one (``robots.epoch``, see
:mod:`service.store.frames`). All ``*_t`` columns are device time; ``wall_time``/``*_at``/``first_seen``
are wall-clock seconds since 1970 (Unix time).
"""

from __future__ import annotations

from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    Double,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

__all__ = [
    "Alert",
    "Base",
    "Baseline",
    "Chunk",
    "FloatingBaselineRow",
    "Heartbeat",
    "Imu",
    "Joint",
    "KinematicsRow",
    "NetworkWeightsRow",
    "Robot",
    "TopologyRow",
]

#: Constraint names are spelled out so migrations can refer to them on every backend.
NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

#: 64-bit ids on PostgreSQL; SQLite only auto-increments a plain INTEGER PRIMARY KEY (itself 64-bit).
BigId = BigInteger().with_variant(Integer(), "sqlite")


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map: ClassVar[dict[Any, Any]] = {dict[str, Any]: JSON, list[str]: JSON, float: Double}


def _robot_fk() -> Any:
    return mapped_column(ForeignKey("robots.id", ondelete="CASCADE"), nullable=False)


class Robot(Base):
    """A robot, registered the first time a frame of it arrives."""

    __tablename__ = "robots"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    first_seen: Mapped[float]
    last_frame_t: Mapped[float | None]
    #: The current device clock epoch (bumped when the robot's clock goes back) and the device time
    #: of its first frame (None before the first restart seen).
    epoch: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    epoch_start_t: Mapped[float | None]
    simulated: Mapped[bool] = mapped_column(Boolean, default=False)
    catalog: Mapped[str | None] = mapped_column(String(200))
    excitation: Mapped[dict[str, Any]] = mapped_column(default=dict)
    #: What the worker waits on for this robot, and its retrains' place in the training queue.
    waiting: Mapped[dict[str, Any] | None] = mapped_column(nullable=True)


class Joint(Base):
    """A joint encoder of a robot; ``position`` keeps first-seen order."""

    __tablename__ = "joints"
    __table_args__ = (UniqueConstraint("robot_id", "name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    robot_id: Mapped[int] = _robot_fk()
    name: Mapped[str] = mapped_column(String(200))
    position: Mapped[int]


class Imu(Base):
    """An IMU of a robot; ``last_t`` (device time) tells when it was last heard."""

    __tablename__ = "imus"
    __table_args__ = (UniqueConstraint("robot_id", "name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    robot_id: Mapped[int] = _robot_fk()
    name: Mapped[str] = mapped_column(String(200))
    position: Mapped[int]
    first_t: Mapped[float]
    last_t: Mapped[float]


class Chunk(Base):
    """``n`` consecutive samples of one robot as float64 blobs (see the module docstring)."""

    __tablename__ = "chunks"
    __table_args__ = (Index("ix_chunks_robot_time", "robot_id", "t_start", "t_end"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    robot_id: Mapped[int] = _robot_fk()
    t_start: Mapped[float]
    t_end: Mapped[float]
    n: Mapped[int]
    epoch: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    joint_names: Mapped[list[str]]
    imu_names: Mapped[list[str]]
    t: Mapped[bytes] = mapped_column(LargeBinary)
    q: Mapped[bytes] = mapped_column(LargeBinary)
    acc: Mapped[bytes] = mapped_column(LargeBinary)
    gyro: Mapped[bytes] = mapped_column(LargeBinary)
    n_q: Mapped[int | None]
    t_q: Mapped[bytes | None] = mapped_column(LargeBinary)
    qd: Mapped[bytes | None] = mapped_column(LargeBinary)
    #: extra channels on ``t`` (foot forces): their names, and ``n`` x channels float64 (or NULL)
    channel_names: Mapped[list[str] | None]
    channels: Mapped[bytes | None] = mapped_column(LargeBinary)


class TopologyRow(Base):
    """One learned topology (docs/design.md, 'Topology JSON') with when and from which window it came."""

    __tablename__ = "topologies"
    __table_args__ = (Index("ix_topologies_robot_wall", "robot_id", "wall_time"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    robot_id: Mapped[int] = _robot_fk()
    wall_time: Mapped[float]
    window_end_t: Mapped[float | None]
    method: Mapped[str] = mapped_column(String(64))
    topology: Mapped[dict[str, Any]]


class Baseline(Base):
    """A topology a robot is compared against; the newest row per robot is the current baseline, older
    rows are its history. ``source`` is "auto" (learned and repeated) or "operator" (set by hand)."""

    __tablename__ = "baselines"
    __table_args__ = (Index("ix_baselines_robot_id", "robot_id", "id"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    robot_id: Mapped[int] = _robot_fk()
    wall_time: Mapped[float]
    window_end_t: Mapped[float | None]
    method: Mapped[str] = mapped_column(String(64))
    source: Mapped[str] = mapped_column(String(16))
    topology: Mapped[dict[str, Any]]


class NetworkWeightsRow(Base):
    """A robot's trained sensor networks (``data``: an ``.npz`` of the arrays), to start the next
    training of the same method from. ``version`` counts per robot and method; ``baseline_id`` is the
    baseline that was current when they were trained (NULL: none yet): weights are only reused while
    it is (:mod:`service.store.weights`)."""

    __tablename__ = "network_weights"
    __table_args__ = (Index("ix_network_weights_robot_method", "robot_id", "method", "version"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    robot_id: Mapped[int] = _robot_fk()
    method: Mapped[str] = mapped_column(String(64))
    version: Mapped[int] = mapped_column(Integer)
    baseline_id: Mapped[int | None] = mapped_column(BigId)
    wall_time: Mapped[float]
    window_end_t: Mapped[float | None]
    imus: Mapped[list[str]]
    joints: Mapped[list[str]]
    data: Mapped[bytes] = mapped_column(LargeBinary)


class KinematicsRow(Base):
    """A robot's geometry (the kinematics JSON of docs/kinematics.md: joint axes, lever arms) as it was
    when ``baseline_id`` was current: the reference drift alerts compare against
    (:mod:`service.store.kinematics`)."""

    __tablename__ = "kinematics"
    __table_args__ = (Index("ix_kinematics_robot_baseline", "robot_id", "baseline_id"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    robot_id: Mapped[int] = _robot_fk()
    baseline_id: Mapped[int] = mapped_column(BigId)
    wall_time: Mapped[float]
    window_end_t: Mapped[float | None]
    data: Mapped[dict[str, Any]]


class FloatingBaselineRow(Base):
    """A floating-base robot's baseline: what :func:`bodyschema.floating_health.floating_baseline`
    learned (``data``, :mod:`bodyschema.floating_json`), the rule that took the robot as floating
    (``rule``) and the window it was learned on. The newest row per robot is the current one
    (:mod:`service.store.floating`)."""

    __tablename__ = "floating_baselines"
    __table_args__ = (Index("ix_floating_baselines_robot_id", "robot_id", "id"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    robot_id: Mapped[int] = _robot_fk()
    wall_time: Mapped[float]
    window_end_t: Mapped[float | None]
    rule: Mapped[str] = mapped_column(String(500))
    data: Mapped[dict[str, Any]]


class Alert(Base):
    """A damage alert on one part (``imu:<name>`` or ``joint:<name>``) with its life cycle."""

    __tablename__ = "alerts"
    __table_args__ = (Index("ix_alerts_robot_kind_part", "robot_id", "kind", "part"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    robot_id: Mapped[int] = _robot_fk()
    kind: Mapped[str] = mapped_column(String(64))
    part: Mapped[str] = mapped_column(String(210))
    imu: Mapped[str | None] = mapped_column(String(200))
    joint: Mapped[str | None] = mapped_column(String(200))
    state: Mapped[str] = mapped_column(String(16), index=True)
    acked: Mapped[bool] = mapped_column(Boolean, default=False)
    raised_at: Mapped[float]
    resolved_at: Mapped[float | None]
    updated_at: Mapped[float]
    finding: Mapped[dict[str, Any]]
    #: Whether the sensor networks confirmed it (None: not theirs to judge, or not judged yet; False:
    #: the fast screen's finding stands unconfirmed), and why it is in its state.
    confirmed: Mapped[bool | None] = mapped_column(Boolean, nullable=True)
    note: Mapped[str | None] = mapped_column(String(500), nullable=True)


class Heartbeat(Base):
    """Last sign of life of a service component (worker, ingest, API)."""

    __tablename__ = "heartbeats"

    component: Mapped[str] = mapped_column(String(200), primary_key=True)
    wall_time: Mapped[float]
