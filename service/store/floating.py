"""A floating-base robot's baseline: what its floating-base checks judge every later window against.

A walking robot's one IMU rides its base, so it has no topology baseline; the worker learns a floating
baseline instead (:mod:`service.monitor.floating`) from one long healthy window. It is kept here so a
restart judges on at once rather than waiting that much device time again (and learning the baseline
from windows that may already hold a fault). Like topology baselines, a row is never overwritten: the
newest row of a robot is its current floating baseline and older rows are its history (a robot whose
joints or IMUs changed learns a new one). ``data`` is :func:`bodyschema.floating_json.baseline_to_json`;
``rule`` says why the robot was taken as floating-base.

Example
-------
>>> import numpy as np
>>> from service.frames import FrameBatch
>>> from service.store import open_store
>>> store = open_store("sqlite://")
>>> store.write(FrameBatch("dog", np.arange(3.0), ("j1",), np.zeros((3, 1)), ("i1",),
...                        np.ones((3, 1, 3)), np.zeros((3, 1, 3))))
3
>>> store.floating_baseline("dog") is None
True
>>> _ = store.save_floating_baseline("dog", {"format": 1}, rule="foot forces", wall_time=5.0,
...                                  window_end_t=2.0)
>>> b = store.floating_baseline("dog")
>>> b.rule, b.wall_time, b.window_end_t, b.data
('foot forces', 5.0, 2.0, {'format': 1})
>>> fleet = store.floating_baselines()
>>> list(fleet), fleet["dog"].data is None
(['dog'], True)
>>> store.close()
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, insert, select

from service.db.models import FloatingBaselineRow, Robot
from service.store.robots import robot_id
from service.store.schema import StoreBase, newest

__all__ = ["FloatingMixin", "StoredFloating"]

#: Longest ``rule`` kept (the column's width); a longer sentence is cut.
_RULE_MAX = 500


@dataclass(frozen=True)
class StoredFloating:
    """A kept floating baseline of one robot; ``data`` is None when read without it (the fleet's
    list, which only asks whether and since when each robot has one)."""

    id: int
    robot: str
    wall_time: float
    window_end_t: float | None
    rule: str
    data: dict[str, Any] | None = None

    kind = "floating"


class FloatingMixin(StoreBase):
    """Keeping the floating-base robots' baselines."""

    def save_floating_baseline(
        self,
        robot: str,
        data: dict[str, Any],
        *,
        rule: str,
        wall_time: float,
        window_end_t: float | None = None,
    ) -> int:
        """Keep ``data`` as ``robot``'s current floating baseline; returns its id."""
        with self._writing() as s:
            rid = robot_id(s, robot)
            return int(
                s.scalar(
                    insert(FloatingBaselineRow)
                    .values(
                        robot_id=rid,
                        wall_time=float(wall_time),
                        window_end_t=None if window_end_t is None else float(window_end_t),
                        rule=rule[:_RULE_MAX],
                        data=data,
                    )
                    .returning(FloatingBaselineRow.id)
                )
            )

    def floating_baseline(self, robot: str) -> StoredFloating | None:
        """``robot``'s current floating baseline, None when it has none."""
        with self._session() as s:
            rid = robot_id(s, robot)
            r = s.scalar(newest(FloatingBaselineRow, FloatingBaselineRow.robot_id == rid))
            if r is None:
                return None
            return StoredFloating(
                int(r.id), robot, float(r.wall_time), r.window_end_t, str(r.rule), dict(r.data)
            )

    def floating_baselines(self) -> dict[str, StoredFloating]:
        """Every robot's current floating baseline without its data, by robot name (one query)."""
        F = FloatingBaselineRow
        current = select(func.max(F.id)).group_by(F.robot_id)
        q = (
            select(F.id, F.wall_time, F.window_end_t, F.rule, Robot.name)
            .join(Robot, Robot.id == F.robot_id)
            .where(F.id.in_(current))
        )
        with self._session() as s:
            return {
                name: StoredFloating(int(i), name, float(w), e, str(rule))
                for i, w, e, rule, name in s.execute(q)
            }
