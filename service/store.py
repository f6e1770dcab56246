"""The windowed store: frames per robot kept for a retention window, plus topologies, baselines, alerts.

Frames arrive as :class:`~service.ingest.base.FrameBatch` and are kept by *device* time. Consecutive
batches of one robot are coalesced into chunks (one row per chunk holding float64 blobs, see
:mod:`service.db.models`), so a 60 s window of a 72-IMU robot is a handful of rows and reads back as
arrays in milliseconds. Robots, joints and IMUs register the first time they appear; each chunk records
which IMUs it carries, so an IMU may fall silent and come back. Everything else the service keeps
(learned topologies, baselines, alerts, heartbeats) lives here too, so one object is the whole data
layer. The schema is created and upgraded by the Alembic migrations only.

Thread-safe: one writer at a time (a lock), any number of readers. Several processes may share one
database (SQLite WAL or PostgreSQL).

Example
-------
>>> import numpy as np
>>> from service.ingest.base import FrameBatch
>>> store = Store("sqlite://")
>>> t = np.arange(10) * 0.01
>>> batch = FrameBatch("arm", t, ("j1",), np.zeros((10, 1)), ("imu0",), np.ones((10, 1, 3)),
...                    np.zeros((10, 1, 3)))
>>> store.write(batch)
10
>>> rec = store.read_window("arm", seconds=0.05)
>>> rec.n_samples, rec.imu_names, float(rec.t[-1])
(5, ('imu0',), 0.09)
>>> store.robot("arm").imus
['imu0']
>>> store.close()
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sqlalchemy import Engine, case, delete, func, insert, select, text, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from bodyschema.recording import Recording
from bodyschema.topology import Topology
from service.db import migrate
from service.db.engine import make_engine, normalize_url
from service.db.models import Alert, Baseline, Chunk, Heartbeat, Imu, Joint, Robot, TopologyRow
from service.ingest.base import FrameBatch, FrameError
from service.settings import Settings, get_settings

__all__ = [
    "ALERT_STATES",
    "AlertRecord",
    "RobotInfo",
    "Store",
    "TopologyRecord",
    "UnknownAlert",
    "UnknownRobot",
]

log = logging.getLogger(__name__)

#: Life cycle of an alert: seen but not yet confirmed (hysteresis), raised, over.
ALERT_STATES: tuple[str, ...] = ("pending", "active", "resolved")
BASELINE_SOURCES: tuple[str, ...] = ("auto", "operator")
_F8 = np.dtype("<f8")


class UnknownRobot(KeyError):
    """A robot name the store has never seen."""


class UnknownAlert(KeyError):
    """An alert id that does not exist."""


# ---------------------------------------------------------------------------------------------- records
@dataclass(frozen=True)
class RobotInfo:
    """What the store knows about one robot. ``silent_imus`` have not been heard for
    ``imu_silent_seconds`` of device time before ``last_frame_t``; ``first_seen`` is wall time."""

    name: str
    joints: list[str]
    imus: list[str]
    silent_imus: list[str]
    first_seen: float
    last_frame_t: float | None
    simulated: bool
    catalog: str | None
    excitation: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class TopologyRecord:
    """A stored topology. ``source`` is set for baselines ("auto" | "operator")."""

    id: int
    robot: str
    wall_time: float
    window_end_t: float | None
    method: str
    topology: Topology
    source: str | None = None


@dataclass(frozen=True)
class AlertRecord:
    """One alert on a part; ``finding`` is the finding JSON (docs/design.md §2) that raised or updated it."""

    id: int
    robot: str
    kind: str
    part: str
    imu: str | None
    joint: str | None
    state: str
    acked: bool
    raised_at: float
    resolved_at: float | None
    updated_at: float
    finding: dict[str, Any]

    @property
    def is_open(self) -> bool:
        return self.state != "resolved"


# ------------------------------------------------------------------------------------- chunk building
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
class _Chunk:
    """Consecutive samples of one robot with one joint set and one IMU set, before it becomes a row.

    A multi-rate chunk (``multirate``) keeps the encoder stream on its own stamps ``t_q``; either
    stream may be empty in one chunk (a long batch split by sample count), never both.
    """

    robot: str
    joint_names: tuple[str, ...]
    imu_names: tuple[str, ...]
    multirate: bool = False
    has_qd: bool = False
    t: list[np.ndarray] = field(default_factory=list)
    t_q: list[np.ndarray] = field(default_factory=list)
    q: list[np.ndarray] = field(default_factory=list)
    qd: list[np.ndarray] = field(default_factory=list)
    acc: list[np.ndarray] = field(default_factory=list)
    gyro: list[np.ndarray] = field(default_factory=list)
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


def _check_batch(i: int, b: Any) -> None:
    """FrameBatch.validate plus what the store needs on top (numeric arrays, unique names)."""
    if not isinstance(b, FrameBatch):
        raise FrameError(f"batch {i}: expected a FrameBatch, got {type(b).__name__}")
    try:
        for name in ("t", "t_q", "q", "qd", "acc", "gyro"):
            v = getattr(b, name)
            if v is None and name in ("t_q", "qd"):
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


def build_chunks(batches: Sequence[FrameBatch], max_samples: int) -> list[_Chunk]:
    """Group batches into chunks: per robot, consecutive batches with the same names, the same kind
    (single-clock or multi-rate, with or without ``qd``) and increasing time share a chunk of at most
    ``max_samples`` samples per stream (longer batches are split)."""
    done: list[_Chunk] = []
    open_: dict[str, _Chunk] = {}
    for b in batches:
        cur = open_.get(b.robot)
        if cur is not None and cur.accepts(b, max_samples):
            cur.add(b)
            continue
        if cur is not None:
            done.append(cur)
        pieces = _pieces(b, max_samples)
        for k, (sl, slq) in enumerate(pieces):
            cur = _Chunk(b.robot, b.joint_names, b.imu_names, b.is_multirate, b.qd is not None)
            cur.add(b, sl, slq)
            if k < len(pieces) - 1:
                done.append(cur)
        assert cur is not None
        open_[b.robot] = cur
    done.extend(open_.values())
    return done


# ---------------------------------------------------------------------------------------------- store
@dataclass
class _Known:
    id: int
    joints: set[str]
    imus: set[str]


class Store:
    """The service's data layer on one database (SQLite file, in-memory SQLite or PostgreSQL).

    Opening a store migrates the database to the newest schema (Alembic), never ``create_all``.
    ``url`` defaults to the settings' ``database_url``; retention, IMU silence and chunk size come from
    the settings unless given here.
    """

    def __init__(
        self,
        url: str | None = None,
        *,
        settings: Settings | None = None,
        retention_seconds: float | None = None,
        imu_silent_seconds: float | None = None,
        chunk_max_samples: int | None = None,
        migrate_schema: bool = True,
        engine_kwargs: dict[str, Any] | None = None,
    ) -> None:
        s = settings or get_settings()
        self.url = normalize_url(url or s.database_url)
        self.retention_seconds = float(retention_seconds or s.retention_seconds)
        self.imu_silent_seconds = float(imu_silent_seconds or s.imu_silent_seconds)
        self.chunk_max_samples = int(chunk_max_samples or s.chunk_max_samples)
        self.engine: Engine = make_engine(self.url, **(engine_kwargs or {}))
        self._sessions = sessionmaker(self.engine, expire_on_commit=False)
        self._write_lock = threading.RLock()
        self._known: dict[str, _Known] = {}
        if migrate_schema:
            migrate.upgrade(self.engine)

    # ------------------------------------------------------------------------------ plumbing
    @property
    def dialect(self) -> str:
        return self.engine.dialect.name

    def _insert(self, table: Any) -> Any:
        """An INSERT that understands ON CONFLICT on both backends."""
        return (postgresql.insert if self.dialect == "postgresql" else sqlite.insert)(table)

    def close(self) -> None:
        """Release every pooled connection."""
        self.engine.dispose()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Store({self.engine.url.render_as_string(hide_password=True)!r})"

    def ping(self) -> bool:
        """True when the database answers."""
        try:
            with self.engine.connect() as conn:
                return conn.execute(text("SELECT 1")).scalar() == 1
        except SQLAlchemyError:
            return False

    def _robot_id(self, s: Session, name: str) -> int:
        rid = s.scalar(select(Robot.id).where(Robot.name == name))
        if rid is None:
            raise UnknownRobot(name)
        return rid

    def _register_robot(self, s: Session, name: str) -> _Known:
        """The robot's id and known parts, inserting it if new (safe against a concurrent process)."""
        known = self._known.get(name)
        if known is not None:
            return known
        s.execute(
            self._insert(Robot)
            .values(name=name, first_seen=time.time(), simulated=False, excitation={})
            .on_conflict_do_nothing(index_elements=["name"])
        )
        rid = self._robot_id(s, name)
        joints = set(s.scalars(select(Joint.name).where(Joint.robot_id == rid)))
        imus = set(s.scalars(select(Imu.name).where(Imu.robot_id == rid)))
        known = self._known[name] = _Known(rid, joints, imus)
        return known

    def _register_parts(self, s: Session, known: _Known, ch: _Chunk) -> None:
        new_j = [j for j in ch.joint_names if j not in known.joints]
        if new_j:
            base = len(known.joints)
            s.execute(
                self._insert(Joint).on_conflict_do_nothing(index_elements=["robot_id", "name"]),
                [{"robot_id": known.id, "name": j, "position": base + k} for k, j in enumerate(new_j)],
            )
        new_i = [i for i in ch.imu_names if i not in known.imus]
        if new_i:
            base = len(known.imus)
            s.execute(
                self._insert(Imu).on_conflict_do_nothing(index_elements=["robot_id", "name"]),
                [
                    {
                        "robot_id": known.id,
                        "name": i,
                        "position": base + k,
                        "first_t": ch.t_start,
                        "last_t": ch.t_end,
                    }
                    for k, i in enumerate(new_i)
                ],
            )

    # ---------------------------------------------------------------------------- frames in
    def write(self, batch: FrameBatch) -> int:
        """Store one batch (one transaction); returns the samples stored."""
        return self.write_many([batch])

    def write_many(self, batches: Sequence[FrameBatch]) -> int:
        """Store batches in one transaction; returns the samples stored.

        Every batch is checked first: a bad one raises :class:`FrameError` naming it and nothing of the
        call is written (what earlier calls stored stays). Batches may come from several robots and in
        any order; time overlaps between batches are allowed (a read merges them, later writes win).
        """
        batches = list(batches)
        for i, b in enumerate(batches):
            _check_batch(i, b)
        if not batches:
            return 0
        chunks = build_chunks(batches, self.chunk_max_samples)
        with self._write_lock:
            try:
                self._write_chunks(chunks)
            except SQLAlchemyError:
                # The transaction rolled back: forget cached registrations it may have made.
                self._known.clear()
                raise
        return sum(c.n for c in chunks)

    def _write_chunks(self, chunks: list[_Chunk]) -> None:
        rows: list[dict[str, Any]] = []
        last_t: dict[int, float] = {}
        imu_last: dict[tuple[int, str], float] = {}
        pending: list[tuple[_Known, _Chunk]] = []
        with self._sessions() as s, s.begin():
            for ch in chunks:
                known = self._register_robot(s, ch.robot)
                self._register_parts(s, known, ch)
                pending.append((known, ch))
                rows.append(ch.row(known.id))
                last_t[known.id] = max(last_t.get(known.id, -math.inf), ch.t_end)
                imu_end = ch.imu_t_end
                if imu_end is None:
                    continue  # a piece of a split multi-rate batch holding encoder samples only
                for imu in ch.imu_names:
                    key = (known.id, imu)
                    imu_last[key] = max(imu_last.get(key, -math.inf), imu_end)
            s.execute(insert(Chunk), rows)
            for rid, t in last_t.items():
                s.execute(
                    update(Robot)
                    .where(Robot.id == rid)
                    .values(
                        last_frame_t=case(
                            (Robot.last_frame_t.is_(None), t),
                            (Robot.last_frame_t < t, t),
                            else_=Robot.last_frame_t,
                        )
                    )
                    .execution_options(synchronize_session=False)
                )
            if imu_last:
                s.connection().execute(
                    text(
                        "UPDATE imus SET last_t = CASE WHEN last_t < :t THEN :t ELSE last_t END "
                        "WHERE robot_id = :rid AND name = :name"
                    ),
                    [{"t": t, "rid": rid, "name": name} for (rid, name), t in imu_last.items()],
                )
        # Only after the commit: the cache must never claim parts a rolled-back transaction added.
        for known, ch in pending:
            known.joints.update(ch.joint_names)
            known.imus.update(ch.imu_names)

    # --------------------------------------------------------------------------- frames out
    def read_window(
        self, robot: str, seconds: float, end: float | None = None, *, partial_imus: str = "drop"
    ) -> Recording | None:
        """The latest ``seconds`` of device time: samples with ``end - seconds < t <= end``.

        ``end`` defaults to the robot's last frame. IMUs silent in the whole window are left out; an IMU
        heard in only part of it is left out too (``partial_imus="drop"``) or kept with NaN where it
        was silent (``"nan"``). Joints missing from part of the window are left out (``q`` is always
        finite). Returns None when the window holds no sample; raises :class:`UnknownRobot`.

        When a chunk of the window carries encoder stamps of its own, the result is a multi-rate
        recording (``t_q`` set, docs/recording-format.md): each stream is cut by its own stamps, and
        single-clock chunks in the same window join it with their encoder samples on their ``t``.
        ``qd`` comes back only when every chunk of the window has it. A multi-rate window whose
        encoder or IMU stream is empty, or whose two streams do not overlap, returns None too.
        """
        if not seconds > 0:
            raise ValueError(f"seconds must be positive, got {seconds}")
        if end is None:
            info_end = self._last_frame_t(robot)
            if info_end is None:
                return None
            end = info_end
        # A sample exactly ``seconds`` before ``end`` is out even when float rounding says otherwise
        # (0.09 - 0.05 < 0.04): a 100 Hz stream then gives exactly 100 * seconds samples.
        slack = max(1e-9, 16 * abs(float(np.spacing(end))))
        return self.read_between(robot, end - seconds + slack, end, partial_imus=partial_imus)

    def _last_frame_t(self, robot: str) -> float | None:
        with self._sessions() as s:
            row = s.execute(select(Robot.id, Robot.last_frame_t).where(Robot.name == robot)).first()
        if row is None:
            raise UnknownRobot(robot)
        return row.last_frame_t

    def read_between(
        self, robot: str, start: float, end: float, *, partial_imus: str = "drop"
    ) -> Recording | None:
        """Samples with ``start < t <= end``, each stream by its own stamps (see :meth:`read_window`;
        ±inf allowed)."""
        if partial_imus not in ("drop", "nan"):
            raise ValueError(f"partial_imus must be 'drop' or 'nan', got {partial_imus!r}")
        with self._sessions() as s:
            rid = self._robot_id(s, robot)
            q = select(
                Chunk.n,
                Chunk.n_q,
                Chunk.joint_names,
                Chunk.imu_names,
                Chunk.t,
                Chunk.t_q,
                Chunk.q,
                Chunk.qd,
                Chunk.acc,
                Chunk.gyro,
            )
            q = q.where(Chunk.robot_id == rid)
            if math.isfinite(end):
                q = q.where(Chunk.t_start <= end)
            if math.isfinite(start):
                q = q.where(Chunk.t_end > start)
            q = q.order_by(Chunk.t_start, Chunk.id)
            if self.dialect == "postgresql":
                rows = self._fetch_binary(s, q)
            else:
                rows = [tuple(r) for r in s.execute(q)]
            order = self._part_order(s, rid)
        if not rows:
            return None
        return _assemble(rows, start, end, order, partial_imus)

    @staticmethod
    def _fetch_binary(s: Session, q: Any) -> list[tuple[Any, ...]]:
        """Run ``q`` on psycopg's binary protocol: bytea then travels as raw bytes instead of hex text,
        which makes a 60 s window of a 72-IMU robot read about 4x faster."""
        compiled = q.compile(dialect=s.get_bind().dialect)
        dbapi_conn = s.connection().connection.driver_connection
        with dbapi_conn.cursor(binary=True) as cur:
            cur.execute(str(compiled), compiled.params)
            return [tuple(r) for r in cur.fetchall()]

    def _part_order(self, s: Session, rid: int) -> dict[str, int]:
        out: dict[str, int] = {}
        for model in (Joint, Imu):
            for name, pos in s.execute(select(model.name, model.position).where(model.robot_id == rid)):
                out[f"{model.__tablename__}:{name}"] = pos
        return out

    def sample_count(self, robot: str | None = None) -> int:
        """Samples currently kept (for one robot or all)."""
        with self._sessions() as s:
            q = select(func.coalesce(func.sum(Chunk.n), 0))
            if robot is not None:
                q = q.where(Chunk.robot_id == self._robot_id(s, robot))
            return int(s.scalar(q) or 0)

    def prune(self, now_t: float | None = None) -> int:
        """Drop chunks that ended more than ``retention_seconds`` before ``now_t`` (device time; default
        each robot's last frame). Whole chunks go, so up to one chunk more than the retention may stay.
        Returns the samples dropped."""
        dropped = 0
        with self._write_lock, self._sessions() as s, s.begin():
            for rid, last in s.execute(select(Robot.id, Robot.last_frame_t)).all():
                ref = now_t if now_t is not None else last
                if ref is None:
                    continue
                cutoff = ref - self.retention_seconds
                cond = (Chunk.robot_id == rid) & (Chunk.t_end < cutoff)
                n = s.scalar(select(func.coalesce(func.sum(Chunk.n), 0)).where(cond)) or 0
                if n:
                    s.execute(delete(Chunk).where(cond))
                    dropped += int(n)
        return dropped

    # ------------------------------------------------------------------------------- robots
    def robots(self) -> list[RobotInfo]:
        """Every robot the store has seen, by name."""
        with self._sessions() as s:
            return [self._info(s, r) for r in s.scalars(select(Robot).order_by(Robot.name))]

    def robot(self, name: str) -> RobotInfo | None:
        """One robot, or None when never seen."""
        with self._sessions() as s:
            r = s.scalar(select(Robot).where(Robot.name == name))
            return None if r is None else self._info(s, r)

    def _info(self, s: Session, r: Robot) -> RobotInfo:
        joints = list(
            s.scalars(select(Joint.name).where(Joint.robot_id == r.id).order_by(Joint.position, Joint.id))
        )
        imus = s.execute(
            select(Imu.name, Imu.last_t).where(Imu.robot_id == r.id).order_by(Imu.position, Imu.id)
        ).all()
        silent = []
        if r.last_frame_t is not None:
            silent = [n for n, lt in imus if lt < r.last_frame_t - self.imu_silent_seconds]
        return RobotInfo(
            name=r.name,
            joints=joints,
            imus=[n for n, _ in imus],
            silent_imus=silent,
            first_seen=r.first_seen,
            last_frame_t=r.last_frame_t,
            simulated=bool(r.simulated),
            catalog=r.catalog,
            excitation={str(k): float(v) for k, v in (r.excitation or {}).items()},
        )

    def mark_simulated(self, name: str, catalog: str) -> None:
        """Flag a robot as simulated (registering it if new) and record its catalog model."""
        if not name or not isinstance(name, str):
            raise ValueError("robot name must be a non-empty string")
        with self._write_lock:
            try:
                with self._sessions() as s, s.begin():
                    known = self._register_robot(s, name)
                    s.execute(
                        update(Robot).where(Robot.id == known.id).values(simulated=True, catalog=catalog)
                    )
            except SQLAlchemyError:
                self._known.pop(name, None)  # the registration may have rolled back with it
                raise

    def set_excitation(self, name: str, excitation: dict[str, float]) -> None:
        """Record how well each joint is excited (e.g. the worker's last estimate), 0..1 per joint."""
        clean = {str(k): float(v) for k, v in excitation.items()}
        if any(not math.isfinite(v) for v in clean.values()):
            raise ValueError("excitation values must be finite")
        with self._sessions() as s, s.begin():
            rid = self._robot_id(s, name)
            s.execute(update(Robot).where(Robot.id == rid).values(excitation=clean))

    # --------------------------------------------------------------------------- topologies
    def save_topology(self, robot: str, topo: Topology, wall_time: float, window_end_t: float | None) -> int:
        """Keep a learned topology; returns its id."""
        with self._sessions() as s, s.begin():
            rid = self._robot_id(s, robot)
            return int(
                s.scalar(
                    insert(TopologyRow)
                    .values(
                        robot_id=rid,
                        wall_time=float(wall_time),
                        window_end_t=_opt_float(window_end_t),
                        method=topo.method or "",
                        topology=topo.to_json(),
                    )
                    .returning(TopologyRow.id)
                )
            )

    def latest_topology(self, robot: str, method: str | None = None) -> TopologyRecord | None:
        """The newest stored topology (of ``method`` when given)."""
        hist = self._topologies(robot, 1, method)
        return hist[0] if hist else None

    def topology_history(self, robot: str, limit: int = 50) -> list[TopologyRecord]:
        """Stored topologies, newest first."""
        return self._topologies(robot, limit, None)

    def _topologies(self, robot: str, limit: int, method: str | None) -> list[TopologyRecord]:
        with self._sessions() as s:
            rid = self._robot_id(s, robot)
            q = select(TopologyRow).where(TopologyRow.robot_id == rid)
            if method is not None:
                q = q.where(TopologyRow.method == method)
            q = q.order_by(TopologyRow.wall_time.desc(), TopologyRow.id.desc()).limit(max(int(limit), 0))
            return [
                TopologyRecord(
                    r.id, robot, r.wall_time, r.window_end_t, r.method, Topology.from_json(r.topology)
                )
                for r in s.scalars(q)
            ]

    def set_baseline(
        self,
        robot: str,
        topo: Topology,
        source: str,
        *,
        wall_time: float | None = None,
        window_end_t: float | None = None,
    ) -> None:
        """Make ``topo`` the robot's baseline (the previous ones stay as history)."""
        if source not in BASELINE_SOURCES:
            raise ValueError(f"baseline source must be one of {BASELINE_SOURCES}, got {source!r}")
        with self._sessions() as s, s.begin():
            rid = self._robot_id(s, robot)
            s.execute(
                insert(Baseline).values(
                    robot_id=rid,
                    wall_time=time.time() if wall_time is None else float(wall_time),
                    window_end_t=_opt_float(window_end_t),
                    method=topo.method or "",
                    source=source,
                    topology=topo.to_json(),
                )
            )

    def baseline(self, robot: str) -> TopologyRecord | None:
        """The current baseline, or None when the robot has none yet."""
        with self._sessions() as s:
            rid = self._robot_id(s, robot)
            r = s.scalar(
                select(Baseline).where(Baseline.robot_id == rid).order_by(Baseline.id.desc()).limit(1)
            )
            if r is None:
                return None
            return TopologyRecord(
                r.id, robot, r.wall_time, r.window_end_t, r.method, Topology.from_json(r.topology), r.source
            )

    # ------------------------------------------------------------------------------- alerts
    def upsert_alert(
        self, robot: str, kind: str, part: str, finding_json: dict[str, Any], state: str, wall_time: float
    ) -> AlertRecord:
        """Create or update the open alert of ``(robot, kind, part)``.

        An open (pending/active) alert is updated in place; ``state="resolved"`` closes it. When none is
        open a new one is raised, except that resolving with nothing open returns the last alert of that
        part unchanged (or records a resolved one if there never was any).
        """
        _check_state(state)
        imu, joint = _split_part(part)
        wall_time = float(wall_time)
        with self._sessions() as s, s.begin():
            rid = self._robot_id(s, robot)
            cond = (Alert.robot_id == rid) & (Alert.kind == kind) & (Alert.part == part)
            row = s.scalar(
                select(Alert).where(cond, Alert.state != "resolved").order_by(Alert.id.desc()).limit(1)
            )
            if row is None and state == "resolved":
                row = s.scalar(select(Alert).where(cond).order_by(Alert.id.desc()).limit(1))
                if row is not None:
                    return _alert_record(row, robot)
            if row is None:
                row = Alert(
                    robot_id=rid,
                    kind=kind,
                    part=part,
                    imu=imu,
                    joint=joint,
                    state=state,
                    acked=False,
                    raised_at=wall_time,
                    updated_at=wall_time,
                    finding=dict(finding_json),
                    resolved_at=wall_time if state == "resolved" else None,
                )
                s.add(row)
            else:
                row.state = state
                row.finding = dict(finding_json)
                row.updated_at = wall_time
                if state == "resolved":
                    row.resolved_at = wall_time
            s.flush()
            return _alert_record(row, robot)

    def alerts(
        self,
        robot: str | None = None,
        active: bool | None = None,
        *,
        state: str | None = None,
        limit: int | None = None,
    ) -> list[AlertRecord]:
        """Alerts, newest first. ``active=True``: state "active" only; ``active=False``: everything else
        (pending and resolved); ``state`` filters on one state."""
        with self._sessions() as s:
            q = select(Alert, Robot.name).join(Robot, Robot.id == Alert.robot_id)
            if robot is not None:
                q = q.where(Alert.robot_id == self._robot_id(s, robot))
            if active is not None:
                q = q.where((Alert.state == "active") if active else (Alert.state != "active"))
            if state is not None:
                _check_state(state)
                q = q.where(Alert.state == state)
            q = q.order_by(Alert.updated_at.desc(), Alert.id.desc())
            if limit is not None:
                q = q.limit(int(limit))
            return [_alert_record(a, name) for a, name in s.execute(q).all()]

    _ALERT_FIELDS = frozenset({"state", "acked", "finding", "raised_at", "resolved_at", "updated_at"})

    def update_alert(self, id: int, **fields: Any) -> AlertRecord:
        """Change fields of an alert (state, acked, finding, raised_at, resolved_at, updated_at).
        ``updated_at`` defaults to now; resolving sets ``resolved_at`` unless given."""
        bad = set(fields) - self._ALERT_FIELDS
        if bad:
            raise ValueError(f"unknown alert fields {sorted(bad)}; allowed: {sorted(self._ALERT_FIELDS)}")
        if "state" in fields:
            _check_state(fields["state"])
        with self._sessions() as s, s.begin():
            row = s.get(Alert, int(id))
            if row is None:
                raise UnknownAlert(id)
            fields.setdefault("updated_at", time.time())
            if fields.get("state") == "resolved" and row.state != "resolved":
                fields.setdefault("resolved_at", fields["updated_at"])
            for k, v in fields.items():
                setattr(row, k, bool(v) if k == "acked" else dict(v) if k == "finding" else v)
            s.flush()
            name = s.scalar(select(Robot.name).where(Robot.id == row.robot_id))
            return _alert_record(row, name or "")

    def ack_alert(self, id: int) -> AlertRecord | None:
        """Mark an alert as acknowledged by an operator; None when there is no such alert."""
        try:
            return self.update_alert(id, acked=True)
        except UnknownAlert:
            return None

    # --------------------------------------------------------------------------- heartbeats
    def heartbeat(self, component: str, wall_time: float) -> None:
        """Record that ``component`` was alive at ``wall_time``."""
        stmt = self._insert(Heartbeat).values(component=component, wall_time=float(wall_time))
        stmt = stmt.on_conflict_do_update(index_elements=["component"], set_={"wall_time": float(wall_time)})
        with self._sessions() as s, s.begin():
            s.execute(stmt)

    def last_heartbeat(self, component: str) -> float | None:
        with self._sessions() as s:
            return s.scalar(select(Heartbeat.wall_time).where(Heartbeat.component == component))


# -------------------------------------------------------------------------------------------- helpers
def _opt_float(v: float | None) -> float | None:
    return None if v is None else float(v)


def _check_state(state: str) -> None:
    if state not in ALERT_STATES:
        raise ValueError(f"alert state must be one of {ALERT_STATES}, got {state!r}")


def _split_part(part: str) -> tuple[str | None, str | None]:
    kind, sep, name = part.partition(":")
    if not sep or not name or kind not in ("imu", "joint"):
        raise ValueError(f"alert part must be 'imu:<name>' or 'joint:<name>', got {part!r}")
    return (name, None) if kind == "imu" else (None, name)


def _alert_record(a: Alert, robot: str) -> AlertRecord:
    return AlertRecord(
        id=int(a.id),
        robot=robot,
        kind=a.kind,
        part=a.part,
        imu=a.imu,
        joint=a.joint,
        state=a.state,
        acked=bool(a.acked),
        raised_at=a.raised_at,
        resolved_at=a.resolved_at,
        updated_at=a.updated_at,
        finding=dict(a.finding or {}),
    )


def _decode(blob: bytes, shape: tuple[int, ...]) -> np.ndarray:
    return np.frombuffer(blob, dtype=_F8).reshape(shape)


@dataclass
class _Part:
    """One stream's samples of one chunk inside the window: ``arrays`` are (n, len(names), ...)."""

    names: tuple[str, ...]
    t: np.ndarray
    arrays: tuple[np.ndarray | None, ...]


def _assemble(
    rows: Iterable[Any], start: float, end: float, order: dict[str, int], partial_imus: str
) -> Recording | None:
    """Merge chunk rows into one Recording over ``start < t <= end`` (each stream by its own stamps)."""
    imu_parts: list[_Part] = []
    enc_parts: list[_Part] = []
    multirate = False
    for n, n_q, jn, kn, t_blob, tq_blob, q_blob, qd_blob, acc_blob, gyro_blob in rows:
        n, jn, kn = int(n), tuple(jn), tuple(kn)
        t = _decode(t_blob, (n,))
        m = (t > start) & (t <= end)
        if m.any():
            sel = slice(None) if m.all() else m
            acc = _decode(acc_blob, (n, len(kn), 3))[sel]
            imu_parts.append(_Part(kn, t[sel], (acc, _decode(gyro_blob, (n, len(kn), 3))[sel])))
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
    if not multirate:
        return Recording(t=t, joint_names=joints, q=q, qd=qd, imu_names=imus, acc=acc, gyro=gyro)
    if not min(t[-1], te[-1]) > max(t[0], te[0]):
        return None  # the two streams do not overlap in this window
    return Recording(t=t, t_q=te, joint_names=joints, q=q, qd=qd, imu_names=imus, acc=acc, gyro=gyro)


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
