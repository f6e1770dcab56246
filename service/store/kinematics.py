"""A robot's geometry baseline: the joint axes and IMU lever arms its drift alerts compare against.

The worker estimates a robot's kinematics (:func:`bodyschema.kinematics.estimate_kinematics`) once its
topology baseline stands and a window shows that same body; that estimate is kept here, tied to the
topology baseline that was current (``baseline_id``), and later estimates are compared with it
(:func:`bodyschema.kinematic_drift.kinematic_findings`). The newest later estimate is kept too
(``latest=True``), replacing the one before it, so a robot holds at most two rows per baseline: what its
geometry was and what it is now (the API serves both, ``GET /api/v1/robots/{robot}/kinematics``). A new
topology baseline is a new body: its geometry is learned afresh, and the rows of older baselines stay as
their history. The first row also carries the lever arms of the estimates after it until its pool is
full, the newest those of the latest estimates (``lever_arm_pool``, :mod:`bodyschema.lever_pool`), which
slides are judged on. Kept as the kinematics JSON (docs/kinematics.md), read back with
:meth:`bodyschema.kinematics.Kinematics.from_json`.

Example
-------
>>> import numpy as np
>>> from service.frames import FrameBatch
>>> from service.store import open_store
>>> store = open_store("sqlite://")
>>> store.write(FrameBatch("arm", np.arange(3.0), ("j1",), np.zeros((3, 1)), ("i1",),
...                        np.ones((3, 1, 3)), np.zeros((3, 1, 3))))
3
>>> store.save_kinematics("arm", 7, {"imus": {}}, wall_time=1.0, window_end_t=2.0) > 0
True
>>> store.kinematics_baseline("arm", 7).data, store.kinematics_baseline("arm", 8) is None
({'imus': {}}, True)
>>> store.update_kinematics(store.kinematics_baseline("arm", 7).id, {"imus": {}, "pooled": 2})
>>> store.kinematics_baseline("arm", 7).data["pooled"]
2
>>> for n in (1, 2):
...     _ = store.save_kinematics("arm", 7, {"imus": {}, "n": n}, wall_time=2.0 + n, latest=True)
>>> store.kinematics_latest("arm", 7).data["n"], store.kinematics_latest("arm").data["n"]
(2, 2)
>>> store.close()
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import Select, delete, insert, select, update

from service.db.models import KinematicsRow
from service.store.robots import robot_id
from service.store.schema import StoreBase, newest

__all__ = ["KinematicsMixin", "StoredKinematics"]


@dataclass(frozen=True)
class StoredKinematics:
    """A kept geometry estimate of one robot under one topology baseline."""

    id: int
    robot: str
    baseline_id: int
    wall_time: float
    window_end_t: float | None
    data: dict[str, Any]


class KinematicsMixin(StoreBase):
    """Keeping the robots' geometry baselines."""

    def save_kinematics(
        self,
        robot: str,
        baseline_id: int,
        data: dict[str, Any],
        *,
        wall_time: float,
        window_end_t: float | None = None,
        latest: bool = False,
    ) -> int:
        """Keep ``data`` (a kinematics JSON) as ``robot``'s geometry under ``baseline_id``; returns its id.

        The first row under a baseline is its geometry baseline. With ``latest``, the row replaces every
        later one under that baseline (never the first): the newest estimate, kept to be served."""
        with self._writing() as s:
            rid = robot_id(s, robot)
            if latest:
                first = s.scalar(_rows(rid, baseline_id).with_only_columns(KinematicsRow.id).limit(1))
                if first is not None:
                    s.execute(
                        delete(KinematicsRow).where(
                            KinematicsRow.robot_id == rid,
                            KinematicsRow.baseline_id == int(baseline_id),
                            KinematicsRow.id != first,
                        )
                    )
            return int(
                s.scalar(
                    insert(KinematicsRow)
                    .values(
                        robot_id=rid,
                        baseline_id=int(baseline_id),
                        wall_time=float(wall_time),
                        window_end_t=None if window_end_t is None else float(window_end_t),
                        data=data,
                    )
                    .returning(KinematicsRow.id)
                )
            )

    def update_kinematics(
        self,
        kinematics_id: int,
        data: dict[str, Any],
        *,
        wall_time: float | None = None,
        window_end_t: float | None = None,
    ) -> None:
        """Replace the JSON of the kept geometry ``kinematics_id``: the geometry baseline's pool of lever
        arms grows with the estimates after it (:mod:`bodyschema.lever_pool`) until it is full. With
        ``wall_time`` (and ``window_end_t``) the row is another estimate, kept in its place."""
        values: dict[str, Any] = {"data": data}
        if wall_time is not None:
            values.update(wall_time=float(wall_time), window_end_t=window_end_t)
        with self._writing() as s:
            s.execute(update(KinematicsRow).where(KinematicsRow.id == int(kinematics_id)).values(**values))

    def kinematics_baseline(self, robot: str, baseline_id: int) -> StoredKinematics | None:
        """The geometry kept for ``robot`` under ``baseline_id`` (the first kept), None before one is."""
        with self._session() as s:
            rid = robot_id(s, robot)
            r = s.scalar(_rows(rid, baseline_id).limit(1))
        return None if r is None else _stored(robot, r)

    def kinematics_latest(self, robot: str, baseline_id: int | None = None) -> StoredKinematics | None:
        """The newest geometry kept for ``robot`` (under ``baseline_id`` when given), None if none is."""
        with self._session() as s:
            rid = robot_id(s, robot)
            under = () if baseline_id is None else (KinematicsRow.baseline_id == int(baseline_id),)
            r = s.scalar(newest(KinematicsRow, KinematicsRow.robot_id == rid, *under))
        return None if r is None else _stored(robot, r)


def _rows(rid: int, baseline_id: int) -> Select[tuple[KinematicsRow]]:
    """A robot's rows under one baseline, oldest first."""
    return (
        select(KinematicsRow)
        .where(KinematicsRow.robot_id == rid, KinematicsRow.baseline_id == int(baseline_id))
        .order_by(KinematicsRow.id)
    )


def _stored(robot: str, r: KinematicsRow) -> StoredKinematics:
    return StoredKinematics(
        id=int(r.id),
        robot=robot,
        baseline_id=int(r.baseline_id),
        wall_time=float(r.wall_time),
        window_end_t=r.window_end_t,
        data=dict(r.data),
    )
