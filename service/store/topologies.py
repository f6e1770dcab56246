"""Learned topologies and baselines: what each robot's body looked like, and what it is compared against.

Every topology the worker learns is stored with its method, wall time and the device time its window
ended (the history the API and the dashboard show). Per robot and method the newest
``topology_history_keep`` stay; older ones stay only where the body changed (a row whose structure
differs from the one before it), so a robot whose body never changes keeps a bounded history.

A baseline is a topology promoted by the worker ("auto": the same body several cycles in a row, and
the sensor networks' answer when they run; "fast-unconfirmed": the fast screen's body held for
``baseline_unconfirmed_cycles`` cycles while the networks were late) or by an operator; the newest
baseline row of a robot is the current one and older rows are its history, so a baseline is never
overwritten, and baselines are never thinned.

Approving a baseline (:meth:`TopologiesMixin.approve_baseline`) also ends the robot's open alerts: they
were differences to the old baseline. Both happen in one transaction, so no reader ever sees the new
baseline next to alerts against the old one, and a failure leaves both as they were. It takes no lock
of the worker's: the worker sees the new baseline's id in its next cycle and forgets what it tracked
against the old one.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from sqlalchemy import Select, delete, func, insert, select
from sqlalchemy.orm import Session

from bodyschema.topology import Topology
from service.db.models import Baseline, Robot, TopologyRow
from service.store.alerts import resolve_open_alerts
from service.store.robots import robot_id
from service.store.schema import StoreBase, newest

__all__ = ["BASELINE_SOURCES", "TopologiesMixin", "TopologyRecord"]

#: Parsed topology records a store keeps (:meth:`TopologiesMixin._parsed_records`): a fleet's newest
#: topologies of each method and its baselines several times over.
_PARSED_MAX = 8192
#: Ids per ``IN`` list (SQLite allows 32,766 bound parameters, older builds 999).
_IN_BATCH = 900

#: Who made a baseline: the worker (the same body learned repeatedly; "fast-unconfirmed" when the sensor
#: networks had not answered) or an operator.
BASELINE_SOURCES: tuple[str, ...] = ("auto", "operator", "fast-unconfirmed")


@dataclass(frozen=True)
class TopologyRecord:
    """A stored topology. ``source`` is set for baselines (one of :data:`BASELINE_SOURCES`)."""

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
        with self._writing() as s:
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
            select(*_heads(TopologyRow), Robot.name)
            .join(sub, sub.c.id == TopologyRow.id)
            .join(Robot, Robot.id == TopologyRow.robot_id)
            .where(sub.c.newest == 1)
        )
        with self._session() as s:
            return self._parsed_records(s, TopologyRow, q)

    def baselines(self) -> dict[str, TopologyRecord]:
        """Every robot's current baseline, by robot name (one query; :meth:`baseline` for one robot)."""
        current = select(func.max(Baseline.id)).group_by(Baseline.robot_id)
        q = (
            select(*_heads(Baseline), Baseline.source, Robot.name)
            .join(Robot, Robot.id == Baseline.robot_id)
            .where(Baseline.id.in_(current))
        )
        with self._session() as s:
            return self._parsed_records(s, Baseline, q)

    def _parsed_records(
        self, s: Session, table: type[TopologyRow] | type[Baseline], q: Select[Any]
    ) -> dict[str, TopologyRecord]:
        """The records of the rows ``q`` selects (their :func:`_heads`, ``source`` for baselines, and the
        robot's name), by robot name, each row's topology read and parsed once per store.

        A stored topology is never changed, only added or thinned away, so its parsed record is kept by
        (table, id, wall time): the wall time tells a row apart from a later one that took a freed id (a
        SQLite file replaced under the service). The fleet's statuses read every robot's newest
        topologies and baseline after each analysis commit, and parsing them all again was most of it.
        The topologies of the rows not kept yet are read in a second statement; a row thinned away in
        between (PostgreSQL's statements each see their own snapshot) sends the read round again.
        """
        kept = self._parsed_topologies
        for _ in range(3):
            heads = s.execute(q).all()
            keys = {r.id: (table.__tablename__, r.id, r.wall_time) for r in heads}
            missing = [i for i, key in keys.items() if key not in kept]
            parsed: dict[int, Topology] = {}
            for lo in range(0, len(missing), _IN_BATCH):
                ids = missing[lo : lo + _IN_BATCH]
                for rid, js in s.execute(select(table.id, table.topology).where(table.id.in_(ids))):
                    parsed[rid] = Topology.from_json(js)
            if len(parsed) < len(missing):
                continue
            out: dict[str, TopologyRecord] = {}
            for r in heads:
                rec = kept.get(keys[r.id])
                if rec is None:
                    source = getattr(r, "source", None)
                    rec = TopologyRecord(
                        r.id, r.name, r.wall_time, r.window_end_t, r.method, parsed[r.id], source
                    )
                    if len(kept) >= _PARSED_MAX:
                        kept.clear()  # bounded; refills on the next read
                    kept[keys[r.id]] = rec
                out[r.name] = rec
            return out
        raise RuntimeError(f"{table.__tablename__}: rows kept vanishing while read")

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
        with self._writing() as s:
            rid = robot_id(s, robot)
            return _insert_baseline(s, rid, topo, source, wall_time, window_end_t)

    def baseline(self, robot: str) -> TopologyRecord | None:
        """The current baseline, or None when the robot has none yet."""
        with self._session() as s:
            rid = robot_id(s, robot)
            r = s.scalar(newest(Baseline, Baseline.robot_id == rid))
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
        with self._writing() as s:
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


def _heads(table: type[TopologyRow] | type[Baseline]) -> tuple[Any, ...]:
    """The columns of a topology row but its topology: what tells whether its parse is kept."""
    return (table.id, table.wall_time, table.window_end_t, table.method)


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
