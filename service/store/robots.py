"""The robot registry: robots, their joints and IMUs, registered the first time a frame names them.

Nobody declares a robot: the ingest writes frames and the store learns the robot and its parts from
them, keeping parts in first-seen order (the order windows come back in). Every other concern looks a
robot up by name here (:func:`robot_id`), so an unknown name fails the same way everywhere
(:class:`UnknownRobot`). Simulation flags, excitation estimates and what the worker waits on for the
robot (:meth:`RobotsMixin.set_waiting`) are written here too: they describe the robot, not one window
of it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import Row, Select, func, select, update
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session

from service.db.models import Imu, Joint, Robot
from service.frames import FrameError
from service.store.chunks import PendingChunk
from service.store.schema import ROBOT_IDS, StoreBase

__all__ = ["RegisteredRobot", "RobotInfo", "RobotLimitReached", "RobotsMixin", "UnknownRobot", "robot_id"]


class UnknownRobot(KeyError):
    """A robot name the store has never seen."""


class RobotLimitReached(FrameError):
    """A new robot was refused: the store already holds ``max_robots``. A :class:`FrameError`, so the
    ingest pipeline counts its frames as malformed (and the API answers 422) without stopping: retrying
    cannot help until an operator raises the cap, and robots already registered keep ingesting."""


@dataclass(frozen=True)
class RobotInfo:
    """What the store knows about one robot. ``silent_imus`` have not been heard for
    ``imu_silent_seconds`` of device time before ``last_frame_t``; ``first_seen`` is wall time.
    ``epoch`` counts the times the robot's device clock went back (restarts); ``epoch_start_t`` is
    the device time the current epoch began (None while it is the first). ``waiting`` is what the
    worker last said it waits on for the robot (:meth:`RobotsMixin.set_waiting`), ``{}`` before."""

    name: str
    joints: list[str]
    imus: list[str]
    silent_imus: list[str]
    first_seen: float
    last_frame_t: float | None
    simulated: bool
    catalog: str | None
    excitation: dict[str, float] = field(default_factory=dict)
    epoch: int = 0
    epoch_start_t: float | None = None
    waiting: dict[str, Any] = field(default_factory=dict)


@dataclass
class RegisteredRobot:
    """A registered robot's id and the parts committed for it (the write path's cache)."""

    id: int
    joints: set[str]
    imus: set[str]


def robot_id(s: Session, name: str) -> int:
    """The id of robot ``name``; raises :class:`UnknownRobot`.

    Remembered in the store's ids (:data:`~service.store.schema.ROBOT_IDS` of the session's info)
    once read: an id read here is committed, since only :meth:`RobotsMixin._register_robot` inserts
    robots and it looks its own up without this."""
    ids = s.info.get(ROBOT_IDS)
    rid = None if ids is None else ids.get(name)
    if rid is None:
        rid = _select_id(s, name)
        if rid is None:
            raise UnknownRobot(name)
        if ids is not None:
            ids[name] = rid
    return rid


#: The robot columns a :class:`RobotInfo` is made of.
_ROBOT_COLUMNS = (
    Robot.id,
    Robot.name,
    Robot.first_seen,
    Robot.last_frame_t,
    Robot.simulated,
    Robot.catalog,
    Robot.excitation,
    Robot.epoch,
    Robot.epoch_start_t,
    Robot.waiting,
)


def _select_id(s: Session, name: str) -> int | None:
    return s.scalar(select(Robot.id).where(Robot.name == name))


class RobotsMixin(StoreBase):
    """Registering robots and parts, and what the store knows about each robot."""

    def robots(self) -> list[RobotInfo]:
        """Every robot the store has seen, by name: three queries for the whole fleet (robots, joints,
        IMUs), not three per robot. The API's robot list asks this after every ingest commit, and robot
        by robot it was the largest cost of the served process at a hundred robots."""
        with self._session() as s:
            return self._infos(s, select(*_ROBOT_COLUMNS).order_by(Robot.name))

    def robot(self, name: str) -> RobotInfo | None:
        """One robot, or None when never seen."""
        with self._session() as s:
            infos = self._infos(s, select(*_ROBOT_COLUMNS).where(Robot.name == name))
            return infos[0] if infos else None

    def knows(self, name: str) -> bool:
        """Whether robot ``name`` was ever seen. Its id is remembered once read (:func:`robot_id`), so
        asking again runs no query: the read routes that only need to answer 404 for an unknown robot
        ask this rather than :meth:`robot` (three queries)."""
        with self._session() as s:
            try:
                robot_id(s, name)
            except UnknownRobot:
                return False
            return True

    def _infos(self, s: Session, robots_q: Select[Any]) -> list[RobotInfo]:
        """The robots ``robots_q`` selects (:data:`_ROBOT_COLUMNS`, in its order) with their parts, read
        with one query per table whatever their number."""
        rows = s.execute(robots_q).all()
        if not rows:
            return []
        ids = [r.id for r in rows]
        # one robot: its id in the WHERE; more: every part (the whole fleet, or close to it)
        joints_q = select(Joint.robot_id, Joint.name).order_by(Joint.robot_id, Joint.position, Joint.id)
        imus_q = select(Imu.robot_id, Imu.name, Imu.last_t).order_by(Imu.robot_id, Imu.position, Imu.id)
        if len(ids) == 1:
            joints_q = joints_q.where(Joint.robot_id == ids[0])
            imus_q = imus_q.where(Imu.robot_id == ids[0])
        joints: dict[int, list[str]] = {}
        for rid, name in s.execute(joints_q):
            joints.setdefault(rid, []).append(name)
        imus: dict[int, list[tuple[str, float]]] = {}
        for rid, name, last_t in s.execute(imus_q):
            imus.setdefault(rid, []).append((name, last_t))
        return [self._info(r, joints.get(r.id, []), imus.get(r.id, [])) for r in rows]

    def _info(self, r: Row[Any], joints: list[str], imus: list[tuple[str, float]]) -> RobotInfo:
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
            epoch=int(r.epoch or 0),
            epoch_start_t=r.epoch_start_t,
            waiting=dict(r.waiting or {}),
        )

    def mark_simulated(self, name: str, catalog: str) -> None:
        """Flag a robot as simulated (registering it if new) and record its catalog model."""
        if not name or not isinstance(name, str):
            raise ValueError("robot name must be a non-empty string")
        with self._write_lock:
            try:
                with self._writing() as s:
                    known = self._register_robot(s, name)
                    s.execute(
                        update(Robot).where(Robot.id == known.id).values(simulated=True, catalog=catalog)
                    )
            except (SQLAlchemyError, RobotLimitReached):
                self._known.pop(name, None)  # the registration may have rolled back with it
                raise

    def set_excitation(self, name: str, excitation: dict[str, float]) -> None:
        """Record how well each joint is excited (e.g. the worker's last estimate), 0..1 per joint."""
        clean = {str(k): float(v) for k, v in excitation.items()}
        if any(not math.isfinite(v) for v in clean.values()):
            raise ValueError("excitation values must be finite")
        with self._writing() as s:
            rid = robot_id(s, name)
            s.execute(update(Robot).where(Robot.id == rid).values(excitation=clean))

    def set_waiting(self, name: str, waiting: dict[str, Any]) -> None:
        """Record what the worker waits on for robot ``name`` (JSON: its waits, since when, and its
        retrains in the training queue), replacing what it said before. A row of its own per robot, in
        one short transaction that no worker lock guards: the status routes read it."""
        with self._writing() as s:
            rid = robot_id(s, name)
            s.execute(update(Robot).where(Robot.id == rid).values(waiting=dict(waiting)))

    def waiting(self, name: str | None = None) -> dict[str, dict[str, Any]]:
        """Every robot's :meth:`set_waiting` record (or only ``name``'s), by name (robots without one
        left out); one query of that column alone."""
        with self._session() as s:
            query = select(Robot.name, Robot.waiting).where(Robot.waiting.is_not(None))
            if name is not None:
                query = query.where(Robot.name == name)
            rows = s.execute(query).all()
            return {name: dict(w) for name, w in rows if w}

    # --------------------------------------------------------------------------- registering
    def _register_robot(self, s: Session, name: str) -> RegisteredRobot:
        """The robot's id and known parts, inserting it if new (safe against a concurrent process)."""
        known = self._known.get(name)
        if known is not None:
            return known
        rid = _select_id(s, name)
        if rid is None:
            self._check_robot_cap(s, name)
            s.execute(
                self._insert(Robot)
                .values(name=name, first_seen=time.time(), simulated=False, excitation={})
                .on_conflict_do_nothing(index_elements=["name"])
            )
            # not robot_id: the insert commits or rolls back with the caller's transaction
            rid = _select_id(s, name)
            if rid is None:
                raise UnknownRobot(name)
        joints = set(s.scalars(select(Joint.name).where(Joint.robot_id == rid)))
        imus = set(s.scalars(select(Imu.name).where(Imu.robot_id == rid)))
        known = self._known[name] = RegisteredRobot(rid, joints, imus)
        return known

    def _check_robot_cap(self, s: Session, name: str) -> None:
        """Refuse robot ``name`` (not registered yet) once ``max_robots`` are: every robot costs a
        worker estimate per cycle and rows forever, so an unbounded set of names (a misconfigured
        device, a typo in a stream of frames) must not grow without limit. Processes sharing one
        database may each admit one robot past the cap at the same moment; the count stays bounded."""
        count = int(s.scalar(select(func.count()).select_from(Robot)) or 0)
        if count >= self.max_robots:
            raise RobotLimitReached(
                f"robot {name!r} not registered: the store already holds {count} robots "
                f"(max_robots={self.max_robots})"
            )

    def _register_parts(self, s: Session, known: RegisteredRobot, ch: PendingChunk) -> None:
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
