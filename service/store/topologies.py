"""Learned topologies and baselines: what each robot's body looked like, and what it is compared against.

Every topology the worker learns is stored with its method, wall time and the device time its window
ended (the history the API and the dashboard show). Per robot and method the newest
``topology_history_keep`` stay; older ones stay only where the body changed (a row whose structure
differs from the one before it), so a robot whose body never changes keeps a bounded history.

A baseline is a topology promoted by the worker ("auto": the same body several cycles in a row) or by
an operator; the newest baseline row of a robot is the current one and older rows are its history, so a
baseline is never overwritten, and baselines are never thinned.

Approving a baseline (:meth:`TopologiesMixin.approve_baseline`) also ends the robot's open alerts: they
were differences to the old baseline. Both happen in one transaction, so no reader ever sees the new
baseline next to alerts against the old one, and a failure leaves both as they were.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from sqlalchemy import delete, func, insert, select
from sqlalchemy.orm import Session

from bodyschema.topology import Topology
from service.db.models import Baseline, Robot, TopologyRow
from service.store.alerts import resolve_open_alerts
from service.store.robots import robot_id
from service.store.schema import StoreBase

__all__ = ["BASELINE_SOURCES", "TopologiesMixin", "TopologyRecord"]

#: Who made a baseline: the worker (the same body learned repeatedly) or an operator.
BASELINE_SOURCES: tuple[str, ...] = ("auto", "operator")


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


class TopologiesMixin(StoreBase):
    """Keeping learned topologies and choosing baselines."""

    def save_topology(self, robot: str, topo: Topology, wall_time: float, window_end_t: float | None) -> int:
        """Keep a learned topology and thin the history behind it (one transaction); returns its id."""
        with self._session() as s, s.begin():
            rid = robot_id(s, robot)
            tid = int(
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
            _thin_history(s, rid, topo.method or "", self.topology_history_keep)
            return tid

    def last_lag(self, robot: str) -> float:
        """The IMU's lag behind the encoders (s) in ``robot``'s newest fast topology; 0 without one."""
        rec = self.latest_topology(robot, "fast")
        return 1e-3 * float(rec.topology.timing.get("lag_ms", 0.0)) if rec is not None else 0.0

    def latest_topology(self, robot: str, method: str | None = None) -> TopologyRecord | None:
        """The newest stored topology (of ``method`` when given)."""
        hist = self._topologies(robot, 1, method)
        return hist[0] if hist else None

    def topology_history(self, robot: str, limit: int = 50) -> list[TopologyRecord]:
        """Stored topologies, newest first."""
        return self._topologies(robot, limit, None)

    def _topologies(self, robot: str, limit: int, method: str | None) -> list[TopologyRecord]:
        with self._session() as s:
            rid = robot_id(s, robot)
            return [_record(r, robot) for r in _topology_rows(s, rid, limit, method)]

    def latest_topologies(self, method: str | None = None) -> dict[str, TopologyRecord]:
        """Every robot's newest stored topology (of ``method`` when given), by robot name; robots without
        one are left out. One query for the whole fleet, where :meth:`latest_topology` takes one per
        robot (the API's robot list asks it of every robot)."""
        newest = (
            func.row_number()
            .over(
                partition_by=TopologyRow.robot_id,
                order_by=(TopologyRow.wall_time.desc(), TopologyRow.id.desc()),
            )
            .label("newest")
        )
        ranked = select(TopologyRow.id, newest)
        if method is not None:
            ranked = ranked.where(TopologyRow.method == method)
        sub = ranked.subquery()
        q = (
            select(TopologyRow, Robot.name)
            .join(sub, sub.c.id == TopologyRow.id)
            .join(Robot, Robot.id == TopologyRow.robot_id)
            .where(sub.c.newest == 1)
        )
        with self._session() as s:
            return {name: _record(r, name) for r, name in s.execute(q).all()}

    def baselines(self) -> dict[str, TopologyRecord]:
        """Every robot's current baseline, by robot name (one query; :meth:`baseline` for one robot)."""
        current = select(func.max(Baseline.id)).group_by(Baseline.robot_id)
        q = (
            select(Baseline, Robot.name)
            .join(Robot, Robot.id == Baseline.robot_id)
            .where(Baseline.id.in_(current))
        )
        with self._session() as s:
            return {name: _baseline_record(r, name) for r, name in s.execute(q).all()}

    def set_baseline(
        self,
        robot: str,
        topo: Topology,
        source: str,
        *,
        wall_time: float | None = None,
        window_end_t: float | None = None,
    ) -> int:
        """Make ``topo`` the robot's baseline (the previous ones stay as history); returns its id."""
        _check_source(source)
        with self._session() as s, s.begin():
            rid = robot_id(s, robot)
            return _insert_baseline(s, rid, topo, source, wall_time, window_end_t)

    def baseline(self, robot: str) -> TopologyRecord | None:
        """The current baseline, or None when the robot has none yet."""
        with self._session() as s:
            rid = robot_id(s, robot)
            r = s.scalar(
                select(Baseline).where(Baseline.robot_id == rid).order_by(Baseline.id.desc()).limit(1)
            )
            return None if r is None else _baseline_record(r, robot)

    def approve_baseline(
        self,
        robot: str,
        topo: Topology | None = None,
        *,
        source: str = "operator",
        wall_time: float | None = None,
    ) -> TopologyRecord:
        """Make ``topo`` the robot's baseline and resolve its open alerts, in one transaction.

        ``topo`` defaults to the newest fast topology, or the newest of any method when no fast one was
        learned. ``wall_time`` (default: now) stamps both the baseline and the resolved alerts. Returns
        the new baseline; raises :class:`~service.store.UnknownRobot`, or ``LookupError`` naming the
        robot when it has no topology to approve.
        """
        _check_source(source)
        now = time.time() if wall_time is None else float(wall_time)
        with self._session() as s, s.begin():
            rid = robot_id(s, robot)
            if topo is None:
                newest = _topology_rows(s, rid, 1, "fast") or _topology_rows(s, rid, 1, None)
                if not newest:
                    raise LookupError(f"no topology learned for {robot!r} yet")
                topo = Topology.from_json(newest[0].topology)
            bid = _insert_baseline(s, rid, topo, source, now, None)
            resolve_open_alerts(s, rid, now)
            row = s.get(Baseline, bid)
            assert row is not None
            return _baseline_record(row, robot)


#: The parts of a stored topology that make it a different body; confidence, timing and excitation
#: change every cycle and do not.
_STRUCTURE_KEYS: tuple[str, ...] = ("joints", "imus", "unique", "insufficient_excitation")


def _same_body(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """True when two stored topology JSONs describe the same body (see :data:`_STRUCTURE_KEYS`)."""
    return all(a.get(k) == b.get(k) for k in _STRUCTURE_KEYS)


def _thin_history(s: Session, rid: int, method: str, keep: int) -> None:
    """Delete the topology that just fell out of the newest ``keep`` of this robot and method when it
    repeats its predecessor. The worker stores one topology per cycle, so an unchanged body would add
    a row every few seconds forever; what the history must answer is when the body changed, which the
    first row of each run of equal bodies (a change) says. Rows are looked at once, as they age past
    ``keep``, so each insert costs one indexed read of two rows; rows that aged past it before this
    limit was set (or lowered) stay."""
    q = (
        select(TopologyRow.id, TopologyRow.topology)
        .where(TopologyRow.robot_id == rid, TopologyRow.method == method)
        .order_by(TopologyRow.wall_time.desc(), TopologyRow.id.desc())
        .offset(keep)
        .limit(2)
    )
    rows = s.execute(q).all()
    if len(rows) == 2 and _same_body(rows[0].topology, rows[1].topology):
        s.execute(delete(TopologyRow).where(TopologyRow.id == rows[0].id))


def _topology_rows(s: Session, rid: int, limit: int, method: str | None) -> list[TopologyRow]:
    """A robot's stored topologies (of ``method`` when given), newest first."""
    q = select(TopologyRow).where(TopologyRow.robot_id == rid)
    if method is not None:
        q = q.where(TopologyRow.method == method)
    q = q.order_by(TopologyRow.wall_time.desc(), TopologyRow.id.desc()).limit(max(int(limit), 0))
    return list(s.scalars(q))


def _insert_baseline(
    s: Session,
    rid: int,
    topo: Topology,
    source: str,
    wall_time: float | None,
    window_end_t: float | None,
) -> int:
    """Add a baseline row in the caller's transaction; returns its id."""
    return int(
        s.scalar(
            insert(Baseline)
            .values(
                robot_id=rid,
                wall_time=time.time() if wall_time is None else float(wall_time),
                window_end_t=_opt_float(window_end_t),
                method=topo.method or "",
                source=source,
                topology=topo.to_json(),
            )
            .returning(Baseline.id)
        )
    )


def _record(r: TopologyRow, robot: str) -> TopologyRecord:
    return TopologyRecord(r.id, robot, r.wall_time, r.window_end_t, r.method, Topology.from_json(r.topology))


def _baseline_record(r: Baseline, robot: str) -> TopologyRecord:
    return TopologyRecord(
        r.id, robot, r.wall_time, r.window_end_t, r.method, Topology.from_json(r.topology), r.source
    )


def _check_source(source: str) -> None:
    if source not in BASELINE_SOURCES:
        raise ValueError(f"baseline source must be one of {BASELINE_SOURCES}, got {source!r}")


def _opt_float(v: float | None) -> float | None:
    return None if v is None else float(v)
