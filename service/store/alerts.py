"""Alerts: one row per damage alert on one part of a robot, with its life cycle.

An alert is raised on a part (``imu:<name>`` or ``joint:<name>``) by the worker's hysteresis
(:class:`service.alerts.AlertTracker`) and lives ``pending`` → ``active`` → ``resolved``; an operator may
acknowledge it at any point. At most one alert per ``(robot, kind, part)`` is open at a time, so the
worker can report the same finding cycle after cycle and the store updates it in place instead of
piling up rows. With the sensor networks on, an alert also says whether they confirmed it
(``confirmed``: True they did, False the fast screen's finding stands without them, None not theirs to
judge or not judged yet) and ``note`` says why it is in its state (waiting for confirmation since when,
withdrawn and why). :func:`resolve_open_alerts` works inside a caller's transaction, so approving a new
baseline can close the differences to the old one atomically (:mod:`service.store.topologies`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from sqlalchemy import select, update
from sqlalchemy.orm import Session

from service.db.models import Alert, Robot
from service.store.robots import robot_id
from service.store.schema import StoreBase, newest

__all__ = ["ALERT_STATES", "AlertRecord", "AlertsMixin", "UnknownAlert", "resolve_open_alerts"]

#: Life cycle of an alert: seen but not yet confirmed (hysteresis), raised, over.
ALERT_STATES: tuple[str, ...] = ("pending", "active", "resolved")


class UnknownAlert(KeyError):
    """An alert id that does not exist."""


@dataclass(frozen=True)
class AlertRecord:
    """One alert on a part; ``finding`` is the finding JSON (docs/design.md, 'Diff JSON') that raised
    or updated it."""

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
    confirmed: bool | None = None
    note: str = ""

    @property
    def is_open(self) -> bool:
        return self.state != "resolved"


def resolve_open_alerts(
    s: Session, rid: int, wall_time: float, note: str = "a new baseline was approved"
) -> int:
    """Resolve every open (pending or active) alert of robot ``rid`` at ``wall_time``, in the caller's
    transaction, saying why in ``note``; returns how many were open."""
    res = s.execute(
        update(Alert)
        .where(Alert.robot_id == rid, Alert.state != "resolved")
        .values(state="resolved", updated_at=wall_time, resolved_at=wall_time, note=note[:500] or None)
        .execution_options(synchronize_session=False)
    )
    return int(res.rowcount or 0)


class AlertsMixin(StoreBase):
    """Raising, updating, listing and acknowledging alerts."""

    def upsert_alert(
        self,
        robot: str,
        kind: str,
        part: str,
        finding_json: dict[str, Any],
        state: str,
        wall_time: float,
        *,
        confirmed: bool | None = None,
        note: str = "",
    ) -> AlertRecord:
        """Create or update the open alert of ``(robot, kind, part)``.

        An open (pending/active) alert is updated in place; ``state="resolved"`` closes it. When none is
        open a new one is raised, except that resolving with nothing open returns the last alert of that
        part unchanged (or records a resolved one if there never was any). ``confirmed`` and ``note``
        are written as given (module doc).
        """
        _check_state(state)
        imu, joint = _split_part(part)
        wall_time = float(wall_time)
        with self._writing() as s:
            rid = robot_id(s, robot)
            cond = (Alert.robot_id == rid) & (Alert.kind == kind) & (Alert.part == part)
            row = s.scalar(newest(Alert, cond, Alert.state != "resolved"))
            if row is None and state == "resolved":
                row = s.scalar(newest(Alert, cond))
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
                    confirmed=confirmed,
                    note=note[:500] or None,
                )
                s.add(row)
            else:
                row.state = state
                row.finding = dict(finding_json)
                row.updated_at = wall_time
                if confirmed is not None or state != "resolved":  # a resolved alert keeps its word
                    row.confirmed = confirmed
                row.note = note[:500] or None
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
        with self._session() as s:
            q = select(Alert, Robot.name).join(Robot, Robot.id == Alert.robot_id)
            if robot is not None:
                q = q.where(Alert.robot_id == robot_id(s, robot))
            if active is not None:
                q = q.where((Alert.state == "active") if active else (Alert.state != "active"))
            if state is not None:
                _check_state(state)
                q = q.where(Alert.state == state)
            q = q.order_by(Alert.updated_at.desc(), Alert.id.desc())
            if limit is not None:
                q = q.limit(int(limit))
            return [_alert_record(a, name) for a, name in s.execute(q).all()]

    _ALERT_FIELDS = frozenset(
        {"state", "acked", "finding", "raised_at", "resolved_at", "updated_at", "confirmed", "note"}
    )

    def update_alert(self, id: int, **fields: Any) -> AlertRecord:
        """Change fields of an alert (state, acked, finding, raised_at, resolved_at, updated_at,
        confirmed, note).
        ``updated_at`` defaults to now; resolving sets ``resolved_at`` unless given."""
        bad = set(fields) - self._ALERT_FIELDS
        if bad:
            raise ValueError(f"unknown alert fields {sorted(bad)}; allowed: {sorted(self._ALERT_FIELDS)}")
        if "state" in fields:
            _check_state(fields["state"])
        with self._writing() as s:
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
        confirmed=a.confirmed,
        note=a.note or "",
    )
