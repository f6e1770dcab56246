"""Heartbeats: the last sign of life of each service component.

A long-running component (the worker, each cycle) writes one row under its name, overwritten each time,
so ``/readyz`` can tell a worker that stopped from one that has nothing to report. It is kept apart from
alerts because it says something about the service, not about a robot.
"""

from __future__ import annotations

from sqlalchemy import select

from service.db.models import Heartbeat
from service.store.schema import StoreBase

__all__ = ["HeartbeatsMixin"]


class HeartbeatsMixin(StoreBase):
    """Recording and reading when each component was last alive."""

    def heartbeat(self, component: str, wall_time: float) -> None:
        """Record that ``component`` was alive at ``wall_time``."""
        stmt = self._insert(Heartbeat).values(component=component, wall_time=float(wall_time))
        stmt = stmt.on_conflict_do_update(index_elements=["component"], set_={"wall_time": float(wall_time)})
        with self._writing() as s:
            s.execute(stmt)

    def last_heartbeat(self, component: str) -> float | None:
        """Wall time of ``component``'s last heartbeat; None when it never sent one."""
        with self._session() as s:
            return s.scalar(select(Heartbeat.wall_time).where(Heartbeat.component == component))
